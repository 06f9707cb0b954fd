//! Plant node: `MotorCommand` → `bowden_plant::Plant` (the simulated tendon-sheath manipulator)
//! → `PlantState`, the ground truth the camera renders. Steps every activation by
//! [`StepCx::time_step_ns`], holding the last valid command.

use crate::{Plant, PlantConfig};
use bowden_interfaces::{services, MotorCommand, PlantState};
use bowden_kinematics::N_CABLES;
use bowden_runtime::node::{InputDecl, NodeKind, Read, Schedule};
use bowden_runtime::ports::{Input, Output};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use serde::Deserialize;
use std::path::PathBuf;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Plant file (configs/plant.toml layout); the shipped one when absent.
    #[serde(default)]
    config: Option<PathBuf>,
    /// Simulate this manufactured unit instead of the plant file's `variation.unit`: a number,
    /// or "run-seed" for the unit the run's seed picks (a controller tried on other units of
    /// the same design than the one it was trained on: `bowden evaluate --units per-repeat`).
    #[serde(default)]
    unit: Option<UnitChoice>,
    /// Fault injection: the simulated robot misbehaves from `after_s` seconds of its own
    /// time on, to try how the pipeline detects and reacts (off by default).
    #[serde(default)]
    fault: Option<FaultParams>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
struct FaultParams {
    kind: FaultKind,
    after_s: f64,
}

/// What a faulty robot does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum FaultKind {
    /// Reports NaN joint angles (a broken encoder or a diverged model).
    Nan,
    /// Reports joint angles far outside the robot's ranges (±900°).
    OutOfRange,
    /// Stops reporting, the process still alive (a stuck driver).
    Silent,
}

#[derive(Debug, Deserialize)]
#[serde(
    untagged,
    expecting = "expected a unit number (a non-negative integer) or \"run-seed\""
)]
enum UnitChoice {
    Number(u64),
    Named(UnitName),
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum UnitName {
    RunSeed,
}

struct PlantStage {
    plant: Plant,
    input: Input<MotorCommand>,
    out: Output<PlantState>,
    w_mm: [f64; N_CABLES],
    last_tick: u64,
    t_prev_ns: Option<u64>,
    rejected: u64,
    step_errors: u64,
    first_error: Option<String>,
    fault: Option<(FaultKind, u64)>,
    faulty_states: u64,
}

/// The `plant` node kind: its declared ports and schedule (see `bowden_runtime::node`).
pub const KIND: NodeKind = NodeKind {
    kind: "plant",
    summary: "the simulated tendon-sheath manipulator: motor setpoints → true joint angles",
    inputs: &[InputDecl::new(services::MOTOR_COMMAND, Read::Tick, 4)],
    outputs: &[services::PLANT_STATE],
    schedule: Schedule::PERIODIC,
    ports_from_params: None,
    lockstep_refusal: None,
    build,
};

fn build(env: &StageEnv<'_>) -> Result<Box<dyn Stage>, StageBuildError> {
    let p: Params = env.params()?;
    if let Some(f) = p.fault {
        if !(f.after_s.is_finite() && f.after_s >= 0.0) {
            return Err(env.error(format!(
                "params.fault.after_s must be a non-negative number, got {}",
                f.after_s
            )));
        }
    }
    let robot = bowden_kinematics::Robot::load_or_paper(env.robot_file().as_deref()).map_err(|e| env.error(e))?;
    let cfg = match &p.config {
        Some(f) => PlantConfig::load(env.resolve(f)).map_err(|e| env.error(e))?,
        None => PlantConfig::paper_default(),
    };
    let run_seed = env.pipeline.runtime.seed;
    let unit = match p.unit {
        Some(UnitChoice::Number(u)) => u,
        Some(UnitChoice::Named(UnitName::RunSeed)) => run_seed,
        None => cfg.variation.unit_for_run(run_seed),
    };
    let plant = Plant::try_new(&robot, &cfg, unit).map_err(|e| env.error(e))?;
    // Before the first command the drive holds the straight pose.
    let w_mm = robot.cables().displacements_mm(&[0.0; 5]);
    Ok(Box::new(PlantStage {
        plant,
        input: env.input(services::MOTOR_COMMAND)?,
        out: env.output(services::PLANT_STATE)?,
        w_mm,
        last_tick: 0,
        t_prev_ns: None,
        rejected: 0,
        step_errors: 0,
        first_error: None,
        fault: p.fault.map(|f| (f.kind, (f.after_s * 1e9) as u64)),
        faulty_states: 0,
    }))
}

impl Stage for PlantStage {
    fn step(&mut self, cx: &StepCx) -> Result<StepReport, StageError> {
        if let Some(m) = self.input.next(cx) {
            let w: [f64; N_CABLES] = core::array::from_fn(|i| m.cable_disp_mm[i]);
            if m.n_cables as usize == N_CABLES && w.iter().all(|v| v.is_finite()) {
                self.w_mm = w;
                self.last_tick = m.header.tick;
            } else {
                self.rejected += 1;
            }
        }
        let now = cx.clock_ns();
        let dt_ns = cx.time_step_ns(now, self.t_prev_ns);
        self.t_prev_ns = Some(now);
        if let Err(e) = self.plant.step(&self.w_mm, dt_ns as f64 * 1e-9) {
            // An out-of-range cable command leaves the plant as it was: count it and go on.
            self.step_errors += 1;
            self.first_error.get_or_insert_with(|| e.to_string());
        }
        let mut s = PlantState::default();
        self.plant.fill_state(&mut s);
        if let Some((kind, after_ns)) = self.fault {
            if self.plant.t_sim_ns() >= after_ns {
                self.faulty_states += 1;
                let n = s.n_joints as usize;
                match kind {
                    FaultKind::Nan => s.q_phy_deg[..n].fill(f64::NAN),
                    FaultKind::OutOfRange => s.q_phy_deg[..n].fill(900.0),
                    FaultKind::Silent => return Ok(StepReport::IDLE),
                }
            }
        }
        self.out.publish(cx.out_tick(self.last_tick), now, s)?;
        Ok(StepReport {
            active: true,
            t_origin_ns: None,
        })
    }

    fn counters(&self) -> StageCounters {
        StageCounters {
            rejected: self.rejected + self.step_errors,
            ..Default::default()
        }
    }

    fn summary(&self) -> Vec<String> {
        let mut v = vec![format!(
            "plant: t_sim {:.3} s, rejected commands {}, refused steps {}",
            self.plant.t_sim_ns() as f64 / 1e9,
            self.rejected,
            self.step_errors
        )];
        if let Some(e) = &self.first_error {
            v.push(format!("plant: first refused step: {e}"));
        }
        if let Some((kind, after_ns)) = self.fault {
            v.push(format!(
                "plant: injected fault {kind:?} from t_sim {:.3} s: {} faulty states",
                after_ns as f64 / 1e9,
                self.faulty_states
            ));
        }
        v
    }
}
