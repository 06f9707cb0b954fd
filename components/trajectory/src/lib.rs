//! Command trajectories for the manipulator.
//!
//! - [`dataset`]: the paper's dataset commands, eq. (16) (§IV-B): random joint configurations
//!   inside the joint limits joined by straight segments sampled every 3·√5 in joint space.
//!
//! - [`task_space`]: the unseen test trajectories of §V (random, circle, zigzag) from
//!   `configs/trajectories/*.toml`, through IK into joint space at the model step.

pub mod dataset;
pub mod node;
pub mod task_space;

pub use dataset::{
    dataset_commands, excitation_commands, interpolate_eq16, random_configurations, Excitation, ExcitationError,
    ExcitationKind, DATASET_STEP_DEG, PAPER_DATASET_COMMANDS, PAPER_DATASET_CONFIGS,
};
