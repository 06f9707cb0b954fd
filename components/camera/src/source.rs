//! Where the camera node's frames come from: the sensor half of the hardware interface (as
//! ros2_control's `SensorInterface`), chosen by name in the pipeline file
//! (`[node.params] source = "synthetic" | "recorded"`). The node keeps the frame grid, the
//! stamps and the shared-memory frame; a source only fills one frame's payload.

use crate::{CameraError, ReplaySource, StreamInfo, SyntheticCamera};
use bowden_interfaces::RgbdFrameHeader;

/// A producer of RGBD frames for the camera node.
pub trait FrameSource {
    /// For logs and errors.
    fn name(&self) -> &str;

    /// What every frame shares: size, intrinsics, depth unit.
    fn stream(&self) -> StreamInfo;

    /// Bytes of every frame's payload (RGB8 plane, then the little-endian u16 depth plane).
    fn payload_len(&self) -> usize {
        self.stream().pixels() * 5
    }

    /// Does a frame show the robot's current state, i.e. does it need the true joint angles?
    fn needs_state(&self) -> bool;

    /// Is there a frame number `n` (a recording ends)?
    fn has_frame(&self, n: u64) -> bool;

    /// Writes frame number `n` (0, 1, … in publishing order) into `payload` and its stream
    /// fields (size, intrinsics, depth unit) into `header`; the node stamps seq, tick and
    /// time. `q_deg` is the robot's state when [`Self::needs_state`].
    fn fill(
        &mut self,
        n: u64,
        q_deg: Option<&[f64; 5]>,
        header: &mut RgbdFrameHeader,
        payload: &mut [u8],
    ) -> Result<(), CameraError>;
}

impl FrameSource for SyntheticCamera {
    fn name(&self) -> &str {
        "synthetic"
    }

    fn stream(&self) -> StreamInfo {
        self.stream_info()
    }

    fn needs_state(&self) -> bool {
        true
    }

    fn has_frame(&self, _n: u64) -> bool {
        true
    }

    fn fill(
        &mut self,
        n: u64,
        q_deg: Option<&[f64; 5]>,
        header: &mut RgbdFrameHeader,
        payload: &mut [u8],
    ) -> Result<(), CameraError> {
        let q = q_deg.ok_or(CameraError::NonFiniteJoint {
            joint: 1,
            value_deg: f64::NAN,
        })?;
        *header = self.header(n, 0, 0);
        self.render_into_payload(q, n, payload)
    }
}

/// Frames recorded from a camera (a directory in the [`crate::record`] layout: `index.json`,
/// colour and 16-bit depth PNGs), played back in order: frame `n` of the run is frame `n` of
/// the recording (or `n mod len` when looping). Decoding a PNG allocates: a camera runs at its
/// frame rate, off the 1 kHz control chain.
pub struct RecordedFrames {
    replay: ReplaySource,
    looping: bool,
}

impl RecordedFrames {
    /// Opens the recording in `dir` (validated: the index and every file it lists).
    pub fn open(dir: impl AsRef<std::path::Path>, looping: bool) -> Result<Self, CameraError> {
        Ok(Self {
            replay: ReplaySource::open(dir)?,
            looping,
        })
    }

    pub fn len(&self) -> usize {
        self.replay.len()
    }

    pub fn is_empty(&self) -> bool {
        self.replay.is_empty()
    }

    fn index(&self, n: u64) -> usize {
        let len = self.replay.len().max(1) as u64;
        (if self.looping { n % len } else { n }) as usize
    }
}

impl FrameSource for RecordedFrames {
    fn name(&self) -> &str {
        "recorded"
    }

    fn stream(&self) -> StreamInfo {
        *self.replay.stream()
    }

    fn needs_state(&self) -> bool {
        false
    }

    fn has_frame(&self, n: u64) -> bool {
        !self.replay.is_empty() && (self.looping || n < self.replay.len() as u64)
    }

    fn fill(
        &mut self,
        n: u64,
        _q_deg: Option<&[f64; 5]>,
        header: &mut RgbdFrameHeader,
        payload: &mut [u8],
    ) -> Result<(), CameraError> {
        let i = self.index(n);
        *header = self.replay.read_into_payload(i, payload)?;
        Ok(())
    }
}
