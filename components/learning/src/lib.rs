//! `bowden-learning`: datasets, the paper's four hysteresis models (FNN, LSTM, TCN,
//! TCN-LSTM; Park et al. 2024 §IV-C), their training with hand-written fused kernels
//! (checked against candle's autograd), ONNX export following docs/architecture.md §5, and the
//! sequence-length sweep (their Fig. 10).
//!
//! - [`dataset`]: the CSV + manifest format, import of external CSV / `.npy` logs.
//! - [`windows`]: input/target by direction, 80/20 split by contiguous blocks,
//!   normalisation, left zero padding.
//! - [`arch`]: architectures, eq. (20), parameter layout and init.
//! - [`kernels`]: fused forward/backward; [`candle_ref`]: the same models in candle.
//! - [`train`]: Adam, batches, best epoch, early stopping; [`report`]: `bowden train`.
//! - [`onnx`]: export / import / tract runner; [`sweep`]: `bowden sweep`.

pub mod adam;
pub mod arch;
pub mod bench;
#[cfg(feature = "candle")]
pub mod candle_ref;
pub mod dataset;
pub mod helper;
pub mod kernels;
pub mod npy;
pub mod onnx;
pub mod report;
pub mod score;
pub mod spacing;
pub mod support;
pub mod sweep;
pub mod synthetic;
pub mod train;
pub mod windows;

pub use arch::{tcn_num_blocks, Architecture, Direction, ModelSpec, TcnBlock};
pub use dataset::{AngleUnit, Dataset, DatasetError, ImportOptions, Manifest};
pub use kernels::Precision;
pub use onnx::{ModelFile, OnnxError, TractModel};
pub use report::{train_to_files, LearnError, TrainReport};
pub use support::DataSupport;
pub use train::{
    fine_tune, mean_residual_deg, rmse_deg, rmse_per_joint_deg, train, Backend, TrainConfig, TrainError, TrainOutcome,
};
pub use windows::{PhySource, SplitConfig, WindowSet};
