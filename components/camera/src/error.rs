//! The one error type of the camera crate: every variant names what was wrong and where.

use std::path::PathBuf;

/// Why a camera operation could not be done.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    // The I/O cause is part of the message (not a `source`), so a one-line report that
    // prints the chain does not repeat it.
    #[error("{path}: cannot read: {cause}")]
    Read { path: PathBuf, cause: std::io::Error },
    #[error("{path}: cannot write: {cause}")]
    Write { path: PathBuf, cause: std::io::Error },
    /// A camera, robot or marker file that cannot be used, or a bad argument (origin "<bench>").
    #[error(transparent)]
    Config(#[from] bowden_interfaces::config::ConfigError),
    #[error("q{joint} = {value_deg} deg is not a finite number")]
    NonFiniteJoint { joint: usize, value_deg: f64 },
    #[error("{buffer} buffer has {got} elements, expected {expected} for a {width}x{height} frame")]
    BufferSize {
        buffer: &'static str,
        expected: usize,
        got: usize,
        width: u32,
        height: u32,
    },
    #[error("{path}: {problem}")]
    Image { path: PathBuf, problem: String },
    #[error("{path}: {problem}")]
    Index { path: PathBuf, problem: String },
    #[error("frame {index} is out of range: the recording {path} has {len} frames")]
    FrameOutOfRange { path: PathBuf, index: usize, len: usize },
}
