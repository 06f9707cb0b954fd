//! The crate's integration tests, one binary: each module is one former test file.
//! (One binary per crate links once instead of once per file; see docs/architecture.md.)

mod dataset;
mod decimation;
mod kernels_vs_candle;
mod kernels_vs_reference;
mod onnx;
mod plots;
mod portable;
mod reference;
mod train;
