//! Camera node: fills a loaned shared-memory frame (zero copy) at `fps` from its
//! [`FrameSource`]: the synthetic renderer of the plant's true q (`PlantState`), or frames
//! recorded from a camera (`source = "recorded"`). Optionally records what it sends.

use crate::{CameraConfig, CameraError, FrameSource, RecordedFrames, Recorder, SyntheticCamera};
use bowden_interfaces::{services, PlantState, RgbdFrameHeader};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
use bowden_runtime::ports::{FrameOutput, Input};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use serde::Deserialize;
use std::path::PathBuf;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Where frames come from: `synthetic` (the renderer, the default) or `recorded` (the
    /// directory `frames`, in the layout `bowden` records: index.json + colour and 16-bit
    /// depth PNGs).
    #[serde(default)]
    source: SourceKind,
    /// `source = "recorded"`: the recording directory (relative to the pipeline file).
    #[serde(default)]
    frames: Option<PathBuf>,
    /// `source = "recorded"`: start again at the first frame after the last (else the camera
    /// stops sending, and reports itself degraded).
    #[serde(default)]
    loop_frames: bool,
    /// Also write every frame sent to this directory, in the same layout (a recording a later
    /// run can replay with `source = "recorded"`).
    #[serde(default)]
    record_to: Option<PathBuf>,
    /// Camera file (configs/camera.toml layout); the shipped D435-like camera when absent.
    #[serde(default)]
    config: Option<PathBuf>,
    /// Marker geometry (configs/markers.toml layout); the shipped one when absent.
    #[serde(default)]
    markers: Option<PathBuf>,
    /// Frame rate, frames per (simulated, in lockstep) second.
    #[serde(default = "thirty")]
    fps: f64,
    /// No stale truth: the synthetic camera renders a plant state only while it is at most
    /// this old (on the run's clock); an older one means the robot stopped reporting, and the
    /// camera sends no frame rather than the last pose again.
    #[serde(default = "hundred")]
    max_state_age_ms: f64,
    /// A plant state outside the robot's joint ranges by more than this is a fault, not a
    /// pose: it is rejected (counted) and nothing is rendered until a plausible one arrives.
    #[serde(default = "ten")]
    range_margin_deg: f64,
}

fn hundred() -> f64 {
    100.0
}

fn ten() -> f64 {
    10.0
}

#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum SourceKind {
    #[default]
    Synthetic,
    Recorded,
}

fn thirty() -> f64 {
    30.0
}

struct CameraStage {
    robot: bowden_kinematics::Robot,
    max_state_age_ns: u64,
    range_margin_deg: f64,
    /// `t_origin_ns` of the state in `q`.
    state_t_ns: u64,
    /// Frame slots skipped because the newest state was too old.
    stale_skips: u64,
    /// The last frame slot was skipped as stale.
    stale: bool,
    source: Box<dyn FrameSource>,
    recorder: Option<Recorder>,
    input: Input<PlantState>,
    out: FrameOutput,
    frame_period_ns: u64,
    next_frame_ns: Option<u64>,
    q: Option<[f64; 5]>,
    state_tick: u64,
    frames: u64,
    rejected: u64,
    render_errors: u64,
    record_errors: u64,
    first_error: Option<String>,
    /// The last robot-side fault seen (`bowden_interfaces::fault` code).
    last_fault: u32,
}

/// The `camera` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "camera",
    summary: "the synthetic RGBD camera: true joint angles → colour + depth frames",
    inputs: &[InputDecl::new(services::PLANT_STATE, Read::Tick, 4)],
    outputs: &[services::RGBD_FRAME],
    schedule: Schedule::PERIODIC,
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    if !(p.fps.is_finite() && p.fps > 0.0 && p.fps <= 1000.0) {
        return Err(env.error(format!("params.fps must be in (0, 1000], got {}", p.fps)));
    }
    let robot = bowden_kinematics::Robot::load_or_paper(env.robot_file().as_deref()).map_err(|e| env.error(e))?;
    let cfg = match &p.config {
        Some(f) => CameraConfig::load(env.resolve(f)).map_err(|e| env.error(e))?,
        None => CameraConfig::paper_default(),
    };
    let markers = match &p.markers {
        Some(f) => MarkerGeometry::load(env.resolve(f)).map_err(|e| env.error(e))?,
        None => MarkerGeometry::paper_default(),
    };
    for (name, v) in [
        ("max_state_age_ms", p.max_state_age_ms),
        ("range_margin_deg", p.range_margin_deg),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(env.error(format!("params.{name} must be a non-negative number, got {v}")));
        }
    }
    let source: Box<dyn FrameSource> = match p.source {
        SourceKind::Synthetic => Box::new(SyntheticCamera::new(
            robot.clone(),
            markers,
            cfg,
            env.pipeline.runtime.seed,
        )),
        SourceKind::Recorded => {
            let dir = p
                .frames
                .as_ref()
                .ok_or_else(|| env.error("params.frames: `source = \"recorded\"` needs the recording directory"))?;
            let rec = RecordedFrames::open(env.resolve(dir), p.loop_frames).map_err(|e| env.error(e))?;
            if rec.is_empty() {
                return Err(env.error(format!("params.frames: {} holds no frames", dir.display())));
            }
            Box::new(rec)
        }
    };
    let len = source.payload_len();
    let recorder = match &p.record_to {
        Some(dir) => Some(Recorder::create(env.resolve(dir), source.stream()).map_err(|e| env.error(e))?),
        None => None,
    };
    Ok(Box::new(CameraStage {
        out: env.frame_output(services::RGBD_FRAME, len)?,
        input: env.input(services::PLANT_STATE)?,
        robot,
        max_state_age_ns: (p.max_state_age_ms * 1e6) as u64,
        range_margin_deg: p.range_margin_deg,
        state_t_ns: 0,
        stale_skips: 0,
        stale: false,
        source,
        recorder,
        frame_period_ns: (1e9 / p.fps) as u64,
        next_frame_ns: None,
        q: None,
        state_tick: 0,
        frames: 0,
        rejected: 0,
        render_errors: 0,
        record_errors: 0,
        first_error: None,
        last_fault: bowden_interfaces::fault::NONE,
    }))
}

impl Stage for CameraStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        if let Some(s) = self.input.next(cx) {
            let finite = bowden_interfaces::finite_joints::<5>(&s.q_phy_deg, s.n_joints);
            let plausible = finite.filter(|q| self.robot.check_plausible(q, self.range_margin_deg).is_ok());
            match plausible {
                Some(q) => {
                    self.q = Some(q);
                    self.state_tick = s.header.tick;
                    self.state_t_ns = s.header.t_origin_ns;
                }
                None => {
                    // Never render the last good pose as if the robot still were there.
                    self.rejected += 1;
                    self.q = None;
                    self.last_fault = if finite.is_some() {
                        bowden_interfaces::fault::STATE_IMPLAUSIBLE
                    } else {
                        bowden_interfaces::fault::STATE_NOT_FINITE
                    };
                }
            }
        }
        let t = cx.clock_ns();
        if self.next_frame_ns.is_some_and(|n| t < n) {
            return Ok(StepReport::IDLE);
        }
        let stale =
            self.source.needs_state() && self.q.is_some() && t.saturating_sub(self.state_t_ns) > self.max_state_age_ns;
        if (self.source.needs_state() && self.q.is_none()) || !self.source.has_frame(self.frames) {
            return Ok(StepReport::IDLE);
        }
        // The next exposure on the frame grid; after a stall, rejoin it rather than burst.
        let next = self.next_frame_ns.unwrap_or(t) + self.frame_period_ns;
        self.next_frame_ns = Some(if next <= t { t + self.frame_period_ns } else { next });
        self.stale = stale;
        if stale {
            // The robot stopped reporting: this exposure is skipped, not filled with the past.
            self.stale_skips += 1;
            self.last_fault = bowden_interfaces::fault::STATE_STALE;
            return Ok(StepReport::IDLE);
        }
        let tick = cx.out_tick(self.state_tick);
        let len = self.source.payload_len();
        let (source, frames, q) = (&mut self.source, self.frames, self.q);
        let recorder = &mut self.recorder;
        let mut record_error = None;
        let sent = self.out.publish_with(tick, t, len, |h: &mut RgbdFrameHeader, buf| {
            source.fill(frames, q.as_ref(), h, buf)?;
            if let Some(rec) = recorder.as_mut() {
                let mut stamped = *h;
                stamped.header = bowden_interfaces::SampleHeader {
                    seq: frames,
                    tick,
                    t_origin_ns: t,
                };
                stamped.payload_len = len as u64;
                // A failed write (full disk) loses the recording, never the frame.
                record_error = rec.record_payload(&stamped, buf).err();
            }
            Ok::<(), CameraError>(())
        })?;
        if let Some(e) = record_error {
            self.record_errors += 1;
            self.first_error.get_or_insert_with(|| e.to_string());
        }
        match sent {
            Ok(_) => {
                self.frames += 1;
                Ok(StepReport::published(t))
            }
            Err(e) => {
                self.render_errors += 1;
                self.first_error.get_or_insert_with(|| e.to_string());
                Ok(StepReport::IDLE)
            }
        }
    }

    fn counters(&self) -> StageCounters {
        StageCounters {
            rejected: self.rejected,
            // A frame slot skipped on a stale robot state is a fault of the robot side.
            faults: self.render_errors + self.record_errors + self.stale_skips,
            last_fault: self.last_fault,
            degraded: (self.source.needs_state() && self.q.is_none())
                || self.stale
                || !self.source.has_frame(self.frames),
            ..Default::default()
        }
    }

    fn summary(&self) -> Vec<String> {
        let mut v = vec![format!(
            "camera: {} frames ({}), rejected plant states {}, frames not sent on a stale state {}, render errors {}",
            self.frames,
            self.source.name(),
            self.rejected,
            self.stale_skips,
            self.render_errors
        )];
        if let Some(r) = &self.recorder {
            v.push(format!(
                "camera: recorded {} frames to {} (write errors {})",
                r.len(),
                r.dir().display(),
                self.record_errors
            ));
        }
        if let Some(e) = &self.first_error {
            v.push(format!("camera: first error: {e}"));
        }
        v
    }

    fn finish(&mut self) -> Result<(), StageError> {
        if let Some(r) = self.recorder.as_ref() {
            r.write_index().map_err(|e| StageError::Fatal {
                stage: "camera".into(),
                message: e.to_string(),
            })?;
        }
        Ok(())
    }
}
