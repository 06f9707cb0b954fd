//! bowden-compensator: hysteresis compensation of a cable-driven continuum manipulator with
//! learned forward/inverse models (Park et al., RA-L 2024, Algorithm 1 and §IV-D), bounded in
//! time and allocation-free in the control loop.
//!
//! - The ONNX model contract (names, metadata keys, allowed values) it loads against is
//!   [`bowden_interfaces::model`], shared with the model writer (`bowden-learning`).
//! - [`Model`]: loads a contract-following ONNX file with tract-onnx, checks it (shape,
//!   metadata, finite weights), recognises FNN / LSTM / TCN / TCN-LSTM graphs (PyTorch's
//!   exports included) and verifies the exact incremental evaluator against tract.
//! - [`IncrementalNet`]: per window, the first L−1 columns once; per trial, the last column
//!   only; forward-mode Jacobian in the same pass.
//! - [`paper_refine`] (Algorithm 1 exactly) and [`newton_refine`] (Levenberg–Marquardt on the
//!   exact Jacobian), generic over [`WindowModel`].
//! - [`Compensator`]: histories sampled at the model's step, modes, budget, limits:
//!   `Compensator::from_config(&ControllerConfig, &Robot)?.step(&q_desired_deg, &mut out)`.
//! - [`Feedback`]: the vision feedback (`[feedback]`): a bounded, leaky, anti-windup
//!   integrator of the error between the desired angles when a frame was taken and the
//!   estimator's measurement, with marker-loss fallback to the feed-forward alone.
//! - [`swap`]: hot model swap, models loaded and checked on a loader thread, exchanged by
//!   value at a cycle boundary.
//! - [`offline`] and [`bench`]: the `bowden compensate` and `bowden bench compensate` engines.

// Numeric kernels index several parallel arrays with one loop variable; iterator chains over
// four zipped slices would read worse.
#![allow(clippy::needless_range_loop)]

pub mod bench;
pub mod compensator;
pub mod config;
pub mod dither;
pub mod feedback;
pub mod history;
pub mod model;
pub mod net;
pub mod node;
pub mod offline;
pub mod prefix;
mod recognise;
pub mod refine;
pub mod swap;

pub use compensator::{Chosen, Compensator, CompensatorError, PreparedModels, SafetyCounts, StepError, StepOutput};
pub use config::{ConfigError, ControllerConfig, EvaluatorChoice, Mode, SafetyConfig};
pub use dither::{Dither, DitherConfig};
pub use feedback::{ApplyTo, Feedback, FeedbackConfig, FeedbackCounts, Observation};
pub use history::{History, HistoryRule};
pub use model::{Evaluator, LoadOptions, Model, ModelError, TractEvaluator};
pub use net::{IncrementalNet, Net, NetSummary};
pub use prefix::{PrefixSync, PrefixWorkerOptions};
pub use refine::{newton_refine, paper_refine, NewtonParams, PaperParams, RefineResult, StopReason, WindowModel};
pub use swap::{Loaded, LoaderSettings, ModelLoader, SwapError};
