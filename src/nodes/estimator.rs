//! Estimator node: RGBD frame (read in place in shared memory) → `bowden_estimator::Estimator`
//! → `MarkerSet` + `JointEstimate`. The motor command is the IK start, as in the paper.

use bowden_estimator::{Estimator, EstimatorConfig};
use bowden_interfaces::{services, JointEstimate, MarkerSet, MotorCommand};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_runtime::ports::{FrameInput, Input, Output};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use serde::Deserialize;
use std::path::PathBuf;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Markers file with [geometry], [hsv] and [estimator] (configs/markers.toml layout).
    #[serde(default)]
    markers: Option<PathBuf>,
}

struct EstimatorStage {
    est: Estimator,
    frames: FrameInput,
    hints: Input<MotorCommand>,
    markers_out: Output<MarkerSet>,
    joints_out: Output<JointEstimate>,
    hint: Option<[f64; 5]>,
    bad_frames: u64,
    invalid: u64,
    estimates: u64,
}

pub fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    let robot = super::robot(env)?;
    let (geometry, cfg) = match &p.markers {
        Some(f) => {
            let path = super::resolve(env, f);
            (
                MarkerGeometry::load(&path).map_err(|e| env.error(e))?,
                EstimatorConfig::load(&path).map_err(|e| env.error(e))?,
            )
        }
        None => (MarkerGeometry::paper_default(), EstimatorConfig::paper_default()),
    };
    Ok(Box::new(EstimatorStage {
        est: Estimator::new(robot, geometry, cfg),
        frames: env.ports.frame_input(services::RGBD_FRAME, 2)?,
        hints: env.ports.input(services::MOTOR_COMMAND, 8)?,
        markers_out: env.ports.output(services::MARKER_SET)?,
        joints_out: env.ports.output(services::JOINT_ESTIMATE)?,
        hint: None,
        bad_frames: 0,
        invalid: 0,
        estimates: 0,
    }))
}

impl Stage for EstimatorStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        if let Some(m) = self.hints.take(cx.lockstep, cx.tick) {
            if let Some(q) = super::joints5(&m.q_cmd_deg, 5) {
                self.hint = Some(q);
            }
        }
        let Some(frame) = self.frames.take(cx.lockstep, cx.tick) else {
            return Ok(StepReport::IDLE);
        };
        let h = *frame.user_header();
        let mut markers = MarkerSet::default();
        let mut joints = JointEstimate::default();
        // A bad frame still yields (all-invalid) outputs: consumers never see stale data.
        if self
            .est
            .estimate_payload(&h, frame.payload(), self.hint, &mut markers, &mut joints)
            .is_err()
        {
            self.bad_frames += 1;
        }
        drop(frame);
        if joints.quality == JointEstimate::QUALITY_INVALID {
            self.invalid += 1;
        }
        self.estimates += 1;
        self.markers_out.publish(h.header.tick, h.header.t_origin_ns, markers)?;
        self.joints_out.publish(h.header.tick, h.header.t_origin_ns, joints)?;
        Ok(StepReport::published(h.header.t_origin_ns))
    }

    fn counters(&self) -> StageCounters {
        StageCounters {
            rejected: self.bad_frames,
            faults: 0,
            degraded: false,
            estop: false,
        }
    }

    fn summary(&self) -> Vec<String> {
        vec![format!(
            "estimator: {} frames, {} without a usable estimate, {} rejected as malformed",
            self.estimates, self.invalid, self.bad_frames
        )]
    }
}
