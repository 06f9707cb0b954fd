//! `bowden-studies`: studies that run bowden exactly as a user would, over many robots, and
//! report what they found. The orchestration lives here so the command line only parses.
//!
//! - [`transfer`]: `bowden bench transfer`, the shipped recipe on units it never saw.

pub mod transfer;
