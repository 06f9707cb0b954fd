//! bowden-adapt: online adaptation to cable slack (docs/architecture.md, "Online adaptation").
//!
//! The paper closes with what it could not do: "prolonged use may result in cable slackening,
//! which is not captured in the training data … we are considering updating the model by
//! fine-tuning it from a pre-trained model with a small number of additional datasets". This
//! crate is that update, as the `adapt` pipeline node runs it beside the real-time chain:
//!
//! 1. [`Adapter::push`] gathers (command, vision estimate) rows while the robot works: one per
//!    valid camera estimate, paired with the command in force when the frame was taken (rows
//!    closer than `min_step_deg` to the previous one are skipped: a robot standing still
//!    teaches nothing and would crowd the window).
//! 2. Every `check_every_rows` new rows, [`Adapter::job`] takes the newest `window_rows` rows
//!    and [`Job::run`] measures the forward model in use on them (the newest `holdout_fraction`,
//!    which no training touches). Stale = that error above `stale_factor` × the reference (the
//!    error measured on the first full window, or after the last swap) and above
//!    `stale_min_deg`.
//! 3. When stale, both models are fine-tuned from the ones in use (the shipped ones at first)
//!    on the older part of the window (its own last part for early stopping), keeping the
//!    models' normalisation, and validated on the held-out newest rows. A direction whose
//!    fine-tuned model is not better there by `min_gain` keeps its model; when neither is
//!    better, nothing is published. Accepted models are written as a new generation directory
//!    (written under a temporary name and renamed: never seen half-written) and announced as a
//!    `ModelUpdate` with their hashes; the compensator swaps them in off its cycle.
//! 4. [`Adapter::apply`] takes the result; every decision is appended to `adapt.jsonl` and the
//!    state (generation, reference, models in use, swap log, the gathered rows) is saved to
//!    `state.json` and `rows.csv`, so a restarted node goes on where it stopped.
//!
//! Everything is deterministic for a given seed and input sequence (fine-tuning is seeded and
//! its results do not depend on the thread count), so lockstep runs reproduce byte for byte.

mod adapter;
mod config;

pub use adapter::{AdaptError, Adapter, CheckRecord, Decision, Job, JobResult, Row, RowError, SwapRecord};
pub use config::AdaptConfig;
pub mod node;
