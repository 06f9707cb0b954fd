//! bowden's runtime: what turns the component crates into a real-time framework of independent
//! OS processes exchanging the `bowden-interfaces` samples over iceoryx2 shared memory.
//!
//! - [`ports`]: typed iceoryx2 publishers/subscribers with one QoS table, a per-deployment
//!   shared-memory prefix and service namespace, zero-copy RGBD frames;
//! - [`node`]: the node contract (declared ports and their [`node::Read`] policies);
//! - [`stage`] and [`executor`]: the [`stage::Stage`] abstraction and the scheduler of one process,
//!   in **lockstep** (simulated clock, bit-for-bit reproducible) or **real time** (absolute
//!   deadlines, SCHED_FIFO, latency histograms, deadline-miss counts);
//! - [`rt`]: SCHED_FIFO, CPU affinity and mlockall with graceful fallback;
//! - [`alloc`]: a counting global allocator that contains iceoryx2's per-loan allocation in a
//!   pre-faulted pool;
//! - [`launch`] and [`session`]: the supervisor and the launcher (`bowden run`), and
//!   [`session::LockstepSession`] for library callers that step a multi-process pipeline;
//! - [`record`] and [`replay`]: fixed-layout logs with an index, and their replay;
//! - [`safety`]: the e-stop protocol (send, confirm) any tool speaks to a running pipeline;
//! - [`cleanup`]: stale-resource removal after crashed or killed processes;
//! - [`config`]: the pipeline configuration.

pub mod alloc;
pub mod bench;
pub mod cleanup;
pub mod config;
pub mod executor;
pub mod faultbench;
pub mod launch;
pub mod node;
pub mod ports;
pub mod record;
pub mod replay;
pub mod rt;
pub mod safety;
pub mod session;
pub mod stage;
pub mod stats;
pub mod sys;

pub use config::{Mode, Overrides, PipelineConfig};
pub use executor::{run_process, ProcessOptions, ProcessReport};
pub use node::Read;
pub use ports::{Input, IpcSettings, Message, Output, PortContext};
pub use session::{LockstepSession, RealtimeSession, SessionOptions, TickOutputs};
pub use stage::{Stage, StageEnv, StepCx, StepReport};
