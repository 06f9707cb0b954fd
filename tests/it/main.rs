//! The crate's integration tests, one binary: each module is one former test file.
//! (One binary per crate links once instead of once per file; see docs/architecture.md.)

mod cli_support;
mod runtime_support;

mod adapt;
mod adapt_logic;
mod anywhere_cli;
#[cfg(feature = "bridge")]
mod bridge;
mod camera_render_cli;
mod cli_conventions;
mod cli_kinematics;
mod collect_cli;
mod compensator_cli;
mod compensator_speed;
mod drives;
mod estimator_cli;
mod evaluate_session;
mod evaluate_short;
mod fail_safe;
mod feedback_eval;
mod feedback_lockstep;
mod hygiene;
mod learning_cli;
mod learning_compensator;
mod no_stale_truth;
mod pipeline_config;
mod plant_cli;
mod python_client;
mod recorded_frames;
mod runtime_alloc;
mod runtime_faults;
mod runtime_pipeline;
mod safe_refinement;
mod shipped_configs;
mod sweep_shard;
mod trajectory_play_cli;
mod transfer_cli;
