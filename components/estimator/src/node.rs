//! Estimator node: RGBD frame (read in place in shared memory) → `bowden_estimator::Estimator`
//! → `MarkerSet` + `JointEstimate`. The motor command is the IK start, as in the paper.

use crate::{Estimator, EstimatorConfig};
use bowden_interfaces::{services, JointEstimate, MarkerSet, MotorCommand};
use bowden_kinematics::markers::MarkerGeometry;
use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
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

/// The `estimator` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "estimator",
    summary: "RGBD frames → marker positions and joint estimates (HSV, RANSAC, frames, IK)",
    inputs: &[
        InputDecl::new(services::RGBD_FRAME, Read::Tick, 2),
        InputDecl::new(services::MOTOR_COMMAND, Read::Hint, 8),
    ],
    outputs: &[services::MARKER_SET, services::JOINT_ESTIMATE],
    schedule: Schedule::EVENT,
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    let robot = bowden_kinematics::Robot::load_or_paper(env.robot_file().as_deref()).map_err(|e| env.error(e))?;
    let (geometry, cfg) = match &p.markers {
        Some(f) => {
            let path = env.resolve(f);
            (
                MarkerGeometry::load(&path).map_err(|e| env.error(e))?,
                EstimatorConfig::load(&path).map_err(|e| env.error(e))?,
            )
        }
        None => (MarkerGeometry::paper_default(), EstimatorConfig::paper_default()),
    };
    Ok(Box::new(EstimatorStage {
        est: Estimator::new(robot, geometry, cfg),
        frames: env.frame_input(services::RGBD_FRAME)?,
        hints: env.input(services::MOTOR_COMMAND)?,
        markers_out: env.output(services::MARKER_SET)?,
        joints_out: env.output(services::JOINT_ESTIMATE)?,
        hint: None,
        bad_frames: 0,
        invalid: 0,
        estimates: 0,
    }))
}

impl Stage for EstimatorStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        if let Some(m) = self.hints.next(cx) {
            if let Some(q) = bowden_interfaces::finite_joints::<5>(&m.q_cmd_deg, 5) {
                self.hint = Some(q);
            }
        }
        let Some(frame) = self.frames.next(cx) else {
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
            ..Default::default()
        }
    }

    fn summary(&self) -> Vec<String> {
        vec![format!(
            "estimator: {} frames, {} without a usable estimate, {} rejected as malformed",
            self.estimates, self.invalid, self.bad_frames
        )]
    }
}
