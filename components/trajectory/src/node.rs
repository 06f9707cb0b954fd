//! Trajectory node: publishes q_desired (`JointTarget`) each cycle, from the paper's eq. (16)
//! dataset commands (`bowden_trajectory`) or a CSV file, each command held `pause_s`.

use bowden_interfaces::{services, JointTarget};
use bowden_runtime::node::{NodeKind, Schedule};
use bowden_runtime::ports::Output;
use bowden_runtime::stage::{Stage, StageBuildError, StageEnv, StageError, StepCx, StepReport};
use bowden_tables::{Location, ReadOptions, Table, TableError};
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Debug, Deserialize)]
#[serde(tag = "source", rename_all = "lowercase", deny_unknown_fields)]
enum Params {
    /// Eq. (16): `samples` random configurations within the limits, joined by straight
    /// segments sampled every 3·√5 deg; each command held `pause_s` (0.5 s in the paper).
    Dataset {
        samples: usize,
        #[serde(default = "half_second")]
        pause_s: f64,
        #[serde(default = "yes")]
        repeat: bool,
    },
    /// One command per line, `q1,q2,q3,q4,q5` in degrees (`#` comments, an optional header).
    Csv {
        file: PathBuf,
        #[serde(default = "half_second")]
        pause_s: f64,
        #[serde(default = "yes")]
        repeat: bool,
    },
}

fn half_second() -> f64 {
    0.5
}
fn yes() -> bool {
    true
}

/// Reads a CSV of joint commands, five values a row (q1..q5, degrees), with an optional header
/// line before the first; errors name the file, line and column.
pub fn read_csv(path: &Path) -> Result<Vec<[f64; 5]>, TableError> {
    let opts = ReadOptions {
        header: false,
        comments: true,
        ignore_case: false,
    };
    let table = Table::read(path, opts)?;
    // A header line (q1,q2,...) is allowed before the first command: a first row without a
    // single number in it.
    let first_is_header = table
        .rows
        .first()
        .is_some_and(|r| r.fields.iter().all(|f| f.parse::<f64>().is_err()));
    let skip = usize::from(first_is_header);
    let mut out = Vec::with_capacity(table.rows.len());
    for r in skip..table.rows.len() {
        let fields = &table.rows[r].fields;
        if fields.len() != 5 {
            return Err(TableError::Malformed {
                at: Location {
                    path: path.to_path_buf(),
                    line: table.rows[r].line,
                    column: None,
                },
                what: format!("{} values, expected 5 (q1..q5)", fields.len()),
            });
        }
        let mut q = [0.0; 5];
        for (j, v) in q.iter_mut().enumerate() {
            *v = table.finite(r, j)?;
        }
        out.push(q);
    }
    if out.is_empty() {
        return Err(TableError::Empty {
            path: path.to_path_buf(),
            what: "no commands".into(),
        });
    }
    Ok(out)
}

struct TrajectoryStage {
    commands: Vec<[f64; 5]>,
    hold_ns: u64,
    repeat: bool,
    out: Output<JointTarget>,
}

/// The `trajectory` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "trajectory",
    summary: "the targets q_desired: the dataset commands of eq. (16) or a CSV path",
    inputs: &[],
    outputs: &[services::JOINT_TARGET],
    schedule: Schedule {
        deadline_us: Some(200),
        ..Schedule::PERIODIC
    },
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    let robot = bowden_kinematics::Robot::load_or_paper(env.robot_file().as_deref()).map_err(|e| env.error(e))?;
    let (commands, pause_s, repeat) = match p {
        Params::Dataset {
            samples,
            pause_s,
            repeat,
        } => {
            if samples < 2 {
                return Err(env.error("params.samples: at least 2 configurations"));
            }
            let c = crate::dataset_commands(&robot, samples, env.pipeline.runtime.seed);
            (c, pause_s, repeat)
        }
        Params::Csv { file, pause_s, repeat } => {
            let c = read_csv(&env.resolve(&file)).map_err(|e| env.error(e.to_string()))?;
            for (i, q) in c.iter().enumerate() {
                robot
                    .check_limits(q)
                    .map_err(|e| env.error(format!("params.file command {}: {e}", i + 1)))?;
            }
            (c, pause_s, repeat)
        }
    };
    if !(pause_s.is_finite() && pause_s > 0.0) {
        return Err(env.error(format!("params.pause_s must be positive, got {pause_s}")));
    }
    Ok(Box::new(TrajectoryStage {
        commands,
        hold_ns: (pause_s * 1e9) as u64,
        repeat,
        out: env.output(services::JOINT_TARGET)?,
    }))
}

impl Stage for TrajectoryStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        let t_ns = cx.tick().saturating_mul(cx.dt_ns());
        let n = self.commands.len() as u64;
        let mut idx = t_ns / self.hold_ns.max(1);
        let mut flags = 0;
        if idx >= n {
            if self.repeat {
                idx %= n;
            } else {
                idx = n - 1;
                flags |= JointTarget::FLAG_LAST;
            }
        }
        let mut target = JointTarget {
            n_joints: 5,
            flags,
            ..Default::default()
        };
        target.q_desired_deg[..5].copy_from_slice(&self.commands[idx as usize]);
        // The target comes into existence now: the wake-up time (real time; the wake-up's
        // lateness after the release is the scheduler's, reported as this stage's response
        // time) or the tick's simulated time (lockstep).
        let origin = cx.t_now_ns();
        self.out.publish(cx.tick(), origin, target)?;
        Ok(StepReport::published(origin))
    }
}
