//! bowden's sample types: the fixed-layout payloads exchanged between processes over
//! iceoryx2 shared memory, and the names of the services that carry them; and ([`model`]) the
//! contract of the ONNX model files that tools exchange (what `bowden train` writes and the
//! compensator loads); and ([`config`]) the error every configuration loader returns.
//!
//! Every type here is `#[repr(C)]` plain data without pointers, so a C, C++ or Python
//! iceoryx2 client can mirror it byte for byte (see `LAYOUT.md` beside this crate, and
//! the compile-time size/alignment assertions at the bottom of this file).
//!
//! Conventions:
//! - every sample starts with a [`SampleHeader`]: `seq` (per publisher, from 0), `tick`
//!   (the scheduler tick the sample belongs to; equals the lockstep step), and
//!   `t_origin_ns`, the monotonic time in ns at which the information originated (the
//!   target's creation for commands, the exposure for frames). Latency of any stage is
//!   `now - t_origin_ns`; in lockstep mode the clock is simulated and the same on every run.
//! - angles are degrees (`_deg`), lengths millimetres (`_mm`), times nanoseconds (`_ns`).
//! - arrays are sized for the largest robot bowden supports ([`MAX_JOINTS`],
//!   [`MAX_CABLES`]); `n_joints` / `n_cables` say how many entries are in use, the rest
//!   are zero.
//! - all `f64`, little-endian (the only byte order bowden runs on).

#![forbid(unsafe_code)]

use iceoryx2::prelude::ZeroCopySend;

pub mod config;
pub mod model;
pub mod services;

/// Largest number of cable-driven joints a sample can carry (the paper's robot has 5).
pub const MAX_JOINTS: usize = 8;
/// Largest number of cables a motor command can carry (the paper's robot has 10).
pub const MAX_CABLES: usize = 16;
/// Number of fiducial marker spheres (paper §IV-A: 3 on the base, 2 on each jaw).
pub const N_MARKERS: usize = 7;

/// Marker indices in every [`MarkerSet`], in the paper's notation.
pub mod marker {
    /// Large red base sphere r0.
    pub const BASE_R0: usize = 0;
    /// Large red base sphere r1.
    pub const BASE_R1: usize = 1;
    /// Large blue base sphere b0.
    pub const BASE_B0: usize = 2;
    /// Small red sphere r2 on the left jaw (forceps 1).
    pub const LEFT_R2: usize = 3;
    /// Small blue sphere b1 on the left jaw (forceps 1).
    pub const LEFT_B1: usize = 4;
    /// Small yellow sphere y0 on the right jaw (forceps 2).
    pub const RIGHT_Y0: usize = 5;
    /// Small green sphere g0 on the right jaw (forceps 2).
    pub const RIGHT_G0: usize = 6;
    /// Names in index order, for reports.
    pub const NAMES: [&str; super::N_MARKERS] = ["r0", "r1", "b0", "r2", "b1", "y0", "g0"];
}

/// Common first field of every sample.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("bowden::SampleHeader")]
#[repr(C)]
pub struct SampleHeader {
    /// Sequence number of this publisher's samples, from 0.
    pub seq: u64,
    /// Scheduler tick this sample belongs to (lockstep step, or real-time cycle index).
    pub tick: u64,
    /// Monotonic time at which the information originated, ns.
    pub t_origin_ns: u64,
}

/// Operating mode of the compensator that produced a [`JointCommand`].
#[repr(u32)]
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[strum(serialize_all = "lowercase")]
pub enum CompensationMode {
    /// Pass-through: q_cmd = q_desired (the paper's uncalibrated controller).
    Uncalibrated = 0,
    /// Algorithm 1 of the paper exactly.
    Paper = 1,
    /// Damped Gauss–Newton on the forward model (bowden's refinement).
    Newton = 2,
}

impl CompensationMode {
    /// Decodes the `mode` field of a [`JointCommand`].
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            0 => Some(Self::Uncalibrated),
            1 => Some(Self::Paper),
            2 => Some(Self::Newton),
            _ => None,
        }
    }
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

/// Desired joint configuration q_desired(t): trajectory → compensator.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::JointTarget")]
#[repr(C)]
pub struct JointTarget {
    pub header: SampleHeader,
    pub n_joints: u32,
    /// Bit 0: last target of the trajectory (the sender stops after it).
    pub flags: u32,
    pub q_desired_deg: [f64; MAX_JOINTS],
}

impl JointTarget {
    /// Flag bit: this is the trajectory's last target.
    pub const FLAG_LAST: u32 = 1;

    /// The target `q_desired_deg` (at most [`MAX_JOINTS`] joints; extra ones are ignored),
    /// header left for the publisher to stamp.
    pub fn from_deg(q_desired_deg: &[f64]) -> Self {
        let n = q_desired_deg.len().min(MAX_JOINTS);
        let mut t = Self {
            n_joints: n as u32,
            ..Default::default()
        };
        t.q_desired_deg[..n].copy_from_slice(&q_desired_deg[..n]);
        t
    }
}

/// Joint command q_cmd(t) the compensator sends: compensator → actuator.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::JointCommand")]
#[repr(C)]
pub struct JointCommand {
    /// `t_origin_ns` is copied from the target, so actuate-time minus it is end-to-end latency.
    pub header: SampleHeader,
    pub n_joints: u32,
    /// [`CompensationMode`] as u32.
    pub mode: u32,
    /// Calibrated command (what the actuator drives).
    pub q_cmd_deg: [f64; MAX_JOINTS],
    /// The target it was computed for.
    pub q_desired_deg: [f64; MAX_JOINTS],
    /// Forward-model prediction of the physical angles at q_cmd (NaN-free; zero when uncalibrated).
    pub q_predicted_deg: [f64; MAX_JOINTS],
    /// Refinement iterations used.
    pub iterations: u32,
    /// Why refinement stopped: 0 none, 1 threshold, 2 max iterations, 3 time budget.
    pub stop_reason: u32,
    /// Time spent computing this command, ns (0 in lockstep mode, which must be reproducible).
    pub compute_ns: u64,
}

/// Cable displacement command Δw for every cable: actuator → plant (or motor driver).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::MotorCommand")]
#[repr(C)]
pub struct MotorCommand {
    pub header: SampleHeader,
    pub n_cables: u32,
    /// Bit 0 e-stop latched, bit 1 holding last safe command (stale input), bit 2 clamped.
    pub flags: u32,
    /// Cable displacement at the motor end, mm (eq. 5 with decoupling), + = pulled.
    pub cable_disp_mm: [f64; MAX_CABLES],
    /// The joint command these displacements encode, for logs and HIL drivers.
    pub q_cmd_deg: [f64; MAX_JOINTS],
}

impl MotorCommand {
    pub const FLAG_ESTOP: u32 = 1;
    pub const FLAG_HOLD: u32 = 2;
    pub const FLAG_CLAMPED: u32 = 4;
    /// Holding because the robot's reported state could not be trusted (with `FLAG_HOLD`).
    pub const FLAG_FAULT: u32 = 8;
}

/// Ground truth of the simulated plant (simulation only): plant → camera, recorder, evaluator.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::PlantState")]
#[repr(C)]
pub struct PlantState {
    pub header: SampleHeader,
    pub n_joints: u32,
    pub n_cables: u32,
    /// Simulated time, ns.
    pub t_sim_ns: u64,
    /// True physical joint angles.
    pub q_phy_deg: [f64; MAX_JOINTS],
    /// Joint command the plant is currently driven with (decoded from cables).
    pub q_cmd_deg: [f64; MAX_JOINTS],
    /// Cable displacement at the distal (hinge) end after sheath friction and stretch, mm.
    pub cable_tip_mm: [f64; MAX_CABLES],
}

/// Header of an RGBD frame. The payload is a `[u8]` slice: `width*height*3` bytes of RGB8
/// (row-major, top-left first) followed by `width*height` little-endian `u16` depths in
/// millimetres (0 = no depth).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::RgbdFrameHeader")]
#[repr(C)]
pub struct RgbdFrameHeader {
    pub header: SampleHeader,
    pub width: u32,
    pub height: u32,
    /// Pinhole intrinsics in pixels.
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Millimetres per depth unit (1.0 for the D435 default).
    pub depth_unit_mm: f64,
    /// Byte offset of the depth plane in the payload (= width*height*3).
    pub depth_offset: u64,
    /// Total payload length in bytes.
    pub payload_len: u64,
}

impl RgbdFrameHeader {
    /// Payload bytes a `width`×`height` frame needs.
    pub const fn payload_len_for(width: u32, height: u32) -> usize {
        let px = width as usize * height as usize;
        px * 3 + px * 2
    }
}

/// Fitted sphere centres of the 7 markers in the camera frame: estimator → recorder.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::MarkerSet")]
#[repr(C)]
pub struct MarkerSet {
    pub header: SampleHeader,
    /// Sequence number of the frame they were fitted on.
    pub frame_seq: u64,
    /// Centres in the camera frame, mm, indexed by [`marker`].
    pub centre_cam_mm: [[f64; 3]; N_MARKERS],
    /// RMS distance of inliers to the fitted sphere surface, mm.
    pub residual_mm: [f64; N_MARKERS],
    /// Inlier point count of each fit.
    pub inliers: [u32; N_MARKERS],
    /// Bit i set: marker i was found and fitted with enough inliers.
    pub valid_mask: u32,
}

/// Physical joint configuration estimated from markers: estimator → collect/evaluate.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::JointEstimate")]
#[repr(C)]
pub struct JointEstimate {
    pub header: SampleHeader,
    pub frame_seq: u64,
    pub n_joints: u32,
    /// See the `QUALITY_*` constants.
    pub quality: u32,
    /// Estimated q_phy. Only meaningful where `joint_valid_mask` has the bit set.
    pub q_phy_deg: [f64; MAX_JOINTS],
    pub joint_valid_mask: u32,
    /// IK iterations used.
    pub ik_iterations: u32,
    /// End-effector position in the robot base frame, mm.
    pub ee_pos_base_mm: [f64; 3],
    /// End-effector orientation in the base frame as a unit quaternion (w, x, y, z).
    pub ee_quat_base_wxyz: [f64; 4],
    /// Residual of IK at the solution: position mm and orientation deg.
    pub ik_residual_pos_mm: f64,
    pub ik_residual_rot_deg: f64,
}

impl JointEstimate {
    /// All joints estimated.
    pub const QUALITY_VALID: u32 = 0;
    /// Some joints estimated (`joint_valid_mask` says which).
    pub const QUALITY_PARTIAL: u32 = 1;
    /// Nothing usable (markers missing, IK failed, bad frame).
    pub const QUALITY_INVALID: u32 = 2;
}

/// Health of one node: every node → launcher, recorder.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("bowden::ComponentStatus")]
#[repr(C)]
pub struct ComponentStatus {
    pub header: SampleHeader,
    /// Node name, NUL-padded UTF-8.
    pub node_name: [u8; 32],
    /// 0 starting, 1 running, 2 degraded (faults counted), 3 stopped, 4 e-stop, 5 safe hold
    /// after a fault (latched until it clears as configured or a person releases it).
    pub state: u32,
    /// The last fault this stage detected ([`fault`] codes, 0 = none): with the state, what a
    /// supervisor reports and classifies.
    pub last_fault: u32,
    pub cycles: u64,
    pub deadline_misses: u64,
    /// Samples rejected as invalid (NaN, out of range, wrong size).
    pub rejected_samples: u64,
    /// Watchdog faults (stale inputs).
    pub faults: u64,
    /// Cycle latency percentiles over the run so far, ns.
    pub latency_p50_ns: u64,
    pub latency_p99_ns: u64,
    pub latency_p999_ns: u64,
    pub latency_max_ns: u64,
}

impl ComponentStatus {
    /// Writes `name` into the fixed-size field (truncated to 32 bytes).
    pub fn set_name(&mut self, name: &str) {
        self.node_name = [0; 32];
        let n = name.len().min(32);
        self.node_name[..n].copy_from_slice(&name.as_bytes()[..n]);
    }
    /// The node name as text.
    pub fn name(&self) -> &str {
        let end = self.node_name.iter().position(|&b| b == 0).unwrap_or(32);
        core::str::from_utf8(&self.node_name[..end]).unwrap_or("<non-utf8>")
    }
}

/// Fault codes of [`ComponentStatus::last_fault`]: what a stage detected, by class. The robot
/// side (`STATE_*`) is the state a driver or plant process reports; `INPUT_*` is a stage's own
/// inputs.
pub mod fault {
    pub const NONE: u32 = 0;
    /// A command input went stale (the actuator's watchdog).
    pub const INPUT_STALE: u32 = 1;
    /// The robot reported a joint angle that is NaN or infinite.
    pub const STATE_NOT_FINITE: u32 = 2;
    /// The robot reported a joint angle outside its ranges widened by the margin.
    pub const STATE_IMPLAUSIBLE: u32 = 3;
    /// The robot's state is older than the configured bound (a silent or hung driver).
    pub const STATE_STALE: u32 = 4;
    /// Robot states went missing: a gap in the publisher's sequence numbers.
    pub const STATE_GAP: u32 = 5;
    /// The robot's state has another joint count than the robot file.
    pub const STATE_JOINT_COUNT: u32 = 6;

    /// A short name for reports (`"?"` for a code this build does not know).
    pub fn name(code: u32) -> &'static str {
        match code {
            NONE => "none",
            INPUT_STALE => "command input stale",
            STATE_NOT_FINITE => "robot state not finite",
            STATE_IMPLAUSIBLE => "robot state out of range",
            STATE_STALE => "robot state stale",
            STATE_GAP => "robot states missing (sequence gap)",
            STATE_JOINT_COUNT => "robot state joint count",
            _ => "?",
        }
    }
}

/// Safety command to the actuator (e-stop latch and release).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("bowden::SafetyCommand")]
#[repr(C)]
pub struct SafetyCommand {
    pub header: SampleHeader,
    /// 1 = e-stop (latch: hold the last safe command), 2 = release.
    pub command: u32,
    pub _pad: u32,
}

impl SafetyCommand {
    pub const ESTOP: u32 = 1;
    pub const RELEASE: u32 = 2;
}

/// Lockstep clock tick published by the launcher: every node handles tick k once its
/// inputs for k are there.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
#[type_name("bowden::ClockTick")]
#[repr(C)]
pub struct ClockTick {
    pub header: SampleHeader,
    /// Simulated time of this tick, ns.
    pub t_sim_ns: u64,
    /// Simulated time step, ns.
    pub dt_ns: u64,
    /// 1 on the final tick: nodes finish and exit.
    pub shutdown: u32,
    pub _pad: u32,
}

/// New model weights are ready: `adapt` → compensator (docs/architecture.md, "Online
/// adaptation"). The weights themselves are ONNX files on disk (`dir/fwd.onnx`,
/// `dir/inv.onnx`); the sample names them and carries their FNV-1a 64 hashes, so a file that
/// changed or was cut short after the announcement is refused rather than loaded.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bowden::ModelUpdate")]
#[repr(C)]
pub struct ModelUpdate {
    pub header: SampleHeader,
    /// Generation of the adapted models, from 1 (each accepted fine-tune adds one).
    pub generation: u64,
    /// FNV-1a 64 of `dir/fwd.onnx` and `dir/inv.onnx`; 0 = that model is not part of the update.
    pub fwd_hash: u64,
    pub inv_hash: u64,
    /// Validation RMSE on held-out recent data of the models in use and of the new ones, deg
    /// (NaN where a direction is not part of the update).
    pub fwd_val_before_deg: f64,
    pub fwd_val_after_deg: f64,
    pub inv_val_before_deg: f64,
    pub inv_val_after_deg: f64,
    /// Absolute directory of the generation's files, NUL-padded UTF-8.
    pub dir: [u8; 256],
}

impl Default for ModelUpdate {
    fn default() -> Self {
        Self {
            header: SampleHeader::default(),
            generation: 0,
            fwd_hash: 0,
            inv_hash: 0,
            fwd_val_before_deg: f64::NAN,
            fwd_val_after_deg: f64::NAN,
            inv_val_before_deg: f64::NAN,
            inv_val_after_deg: f64::NAN,
            dir: [0; 256],
        }
    }
}

impl ModelUpdate {
    /// Writes `dir`; `false` (and nothing written) when it does not fit in 255 bytes.
    pub fn set_dir(&mut self, dir: &str) -> bool {
        if dir.len() > 255 {
            return false;
        }
        self.dir = [0; 256];
        self.dir[..dir.len()].copy_from_slice(dir.as_bytes());
        true
    }
    /// The directory as text; `None` if it is not UTF-8.
    pub fn dir(&self) -> Option<&str> {
        let end = self.dir.iter().position(|&b| b == 0).unwrap_or(256);
        core::str::from_utf8(&self.dir[..end]).ok()
    }
}

/// FNV-1a 64-bit hash of `bytes`: a stable content hash (the [`ModelUpdate`] file check).
pub fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

/// Checks that every used entry of an angle array is finite.
pub fn all_finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// The first `N` entries of a sample's joint array, if the sample says it has exactly `N`
/// joints (`n`) and they are all finite; `None` otherwise (a malformed sample).
pub fn finite_joints<const N: usize>(v: &[f64], n: u32) -> Option<[f64; N]> {
    if n as usize != N || v.len() < N {
        return None;
    }
    let q: [f64; N] = core::array::from_fn(|j| v[j]);
    all_finite(&q).then_some(q)
}

// Layout contract: a change here is a breaking change for every non-Rust client.
const _: () = {
    use core::mem::{align_of, size_of};
    assert!(size_of::<SampleHeader>() == 24 && align_of::<SampleHeader>() == 8);
    assert!(size_of::<JointTarget>() == 96 && align_of::<JointTarget>() == 8);
    assert!(size_of::<JointCommand>() == 240 && align_of::<JointCommand>() == 8);
    assert!(size_of::<MotorCommand>() == 224 && align_of::<MotorCommand>() == 8);
    assert!(size_of::<PlantState>() == 296 && align_of::<PlantState>() == 8);
    assert!(size_of::<RgbdFrameHeader>() == 88 && align_of::<RgbdFrameHeader>() == 8);
    assert!(size_of::<MarkerSet>() == 288 && align_of::<MarkerSet>() == 8);
    assert!(size_of::<JointEstimate>() == 184 && align_of::<JointEstimate>() == 8);
    assert!(size_of::<ComponentStatus>() == 128 && align_of::<ComponentStatus>() == 8);
    assert!(size_of::<SafetyCommand>() == 32 && align_of::<SafetyCommand>() == 8);
    assert!(size_of::<ClockTick>() == 48 && align_of::<ClockTick>() == 8);
    assert!(size_of::<ModelUpdate>() == 336 && align_of::<ModelUpdate>() == 8);
};
