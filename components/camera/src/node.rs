//! Camera node: renders the plant's true q (`PlantState`) with `bowden_camera::SyntheticCamera`
//! straight into a loaned shared-memory frame (zero copy) at `fps`.

use crate::{CameraConfig, SyntheticCamera};
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
    /// Camera file (configs/camera.toml layout); the shipped D435-like camera when absent.
    #[serde(default)]
    config: Option<PathBuf>,
    /// Marker geometry (configs/markers.toml layout); the shipped one when absent.
    #[serde(default)]
    markers: Option<PathBuf>,
    /// Frame rate, frames per (simulated, in lockstep) second.
    #[serde(default = "thirty")]
    fps: f64,
}

fn thirty() -> f64 {
    30.0
}

struct CameraStage {
    cam: SyntheticCamera,
    input: Input<PlantState>,
    out: FrameOutput,
    frame_period_ns: u64,
    next_frame_ns: Option<u64>,
    q: Option<[f64; 5]>,
    state_tick: u64,
    frames: u64,
    rejected: u64,
    render_errors: u64,
}

/// The `camera` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "camera",
    summary: "the synthetic RGBD camera: true joint angles → colour + depth frames",
    inputs: &[InputDecl::new(services::PLANT_STATE, Read::Tick, 4)],
    outputs: &[services::RGBD_FRAME],
    schedule: Schedule {
        periodic: true,
        period_us: None,
        wake_timeout_us: None,
        deadline_us: None,
    },
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
    let cam = SyntheticCamera::new(robot, markers, cfg, env.pipeline.runtime.seed);
    let len = cam.payload_len();
    Ok(Box::new(CameraStage {
        out: env.frame_output(services::RGBD_FRAME, len)?,
        input: env.input(services::PLANT_STATE)?,
        cam,
        frame_period_ns: (1e9 / p.fps) as u64,
        next_frame_ns: None,
        q: None,
        state_tick: 0,
        frames: 0,
        rejected: 0,
        render_errors: 0,
    }))
}

impl Stage for CameraStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        if let Some(s) = self.input.next(cx) {
            match bowden_interfaces::finite_joints::<5>(&s.q_phy_deg, s.n_joints) {
                Some(q) => {
                    self.q = Some(q);
                    self.state_tick = s.header.tick;
                }
                None => self.rejected += 1,
            }
        }
        let t = cx.clock_ns();
        if self.next_frame_ns.is_some_and(|n| t < n) {
            return Ok(StepReport::IDLE);
        }
        let Some(q) = self.q else { return Ok(StepReport::IDLE) };
        // The next exposure on the frame grid; after a stall, rejoin it rather than burst.
        let next = self.next_frame_ns.unwrap_or(t) + self.frame_period_ns;
        self.next_frame_ns = Some(if next <= t { t + self.frame_period_ns } else { next });
        let tick = cx.out_tick(self.state_tick);
        let len = self.cam.payload_len();
        let (cam, frames) = (&mut self.cam, self.frames);
        let sent = self.out.publish_with(tick, t, len, |h: &mut RgbdFrameHeader, buf| {
            *h = cam.header(frames, tick, t);
            cam.render_into_payload(&q, frames, buf)
        })?;
        match sent {
            Ok(_) => {
                self.frames += 1;
                Ok(StepReport::published(t))
            }
            Err(_) => {
                self.render_errors += 1;
                Ok(StepReport::IDLE)
            }
        }
    }

    fn counters(&self) -> StageCounters {
        StageCounters {
            rejected: self.rejected,
            faults: self.render_errors,
            degraded: self.q.is_none(),
            estop: false,
        }
    }

    fn summary(&self) -> Vec<String> {
        vec![format!(
            "camera: {} frames of {}x{}, rejected plant states {}, render errors {}",
            self.frames,
            self.cam.width(),
            self.cam.height(),
            self.rejected,
            self.render_errors
        )]
    }
}
