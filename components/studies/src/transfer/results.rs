//! What a unit's evaluation reports, read back, summarised per family, and checked against the goals.

use super::*;

/// The six errors of one (trajectory, controller), or their reductions in percent.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub(super) struct Six {
    pub(super) position_vision: Option<f64>,
    pub(super) position_truth: Option<f64>,
    pub(super) orientation_vision: Option<f64>,
    pub(super) orientation_truth: Option<f64>,
    pub(super) joint_vision: Option<f64>,
    pub(super) joint_truth: Option<f64>,
}

/// (key, heading) of Six's fields, in order.
pub(super) const METRICS: [(&str, &str); 6] = [
    ("position_vision", "position, vision"),
    ("position_truth", "position, truth"),
    ("orientation_vision", "orientation, vision"),
    ("orientation_truth", "orientation, truth"),
    ("joint_vision", "joint MAE, vision"),
    ("joint_truth", "joint MAE, truth"),
];

impl Six {
    pub(super) fn get(&self, i: usize) -> Option<f64> {
        [
            self.position_vision,
            self.position_truth,
            self.orientation_vision,
            self.orientation_truth,
            self.joint_vision,
            self.joint_truth,
        ][i]
    }

    pub(super) fn zip(a: &Six, b: &Six, f: impl Fn(f64, f64) -> f64) -> Six {
        let g = |x: Option<f64>, y: Option<f64>| match (x, y) {
            (Some(x), Some(y)) if x.is_finite() && y.is_finite() => Some(f(x, y)),
            _ => None,
        };
        Six {
            position_vision: g(a.position_vision, b.position_vision),
            position_truth: g(a.position_truth, b.position_truth),
            orientation_vision: g(a.orientation_vision, b.orientation_vision),
            orientation_truth: g(a.orientation_truth, b.orientation_truth),
            joint_vision: g(a.joint_vision, b.joint_vision),
            joint_truth: g(a.joint_truth, b.joint_truth),
        }
    }
}

/// One (trajectory, calibrated controller) of a unit.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct Row {
    pub(super) trajectory: String,
    pub(super) controller: String,
    /// Mean tip position error (mm), orientation error (°), joint MAE averaged over joints (°).
    pub(super) error: Six,
    pub(super) uncalibrated: Six,
    /// reduction_pct(uncalibrated, controller): + = better.
    pub(super) reduction_pct: Six,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct UnitOutcome {
    pub(super) family: String,
    pub(super) model: String,
    pub(super) unit: u64,
    pub(super) role: Role,
    pub(super) dir: PathBuf,
    pub(super) status: String,
    pub(super) failure: Option<Failure>,
    pub(super) steps: Vec<StepRecord>,
    pub(super) wall_seconds: f64,
    pub(super) rows: Vec<Row>,
}

#[derive(Deserialize)]
pub(super) struct SummaryIn {
    pub(super) cells: Vec<CellIn>,
}

#[derive(Deserialize)]
pub(super) struct CellIn {
    pub(super) trajectory: String,
    pub(super) controller: String,
    pub(super) task_vision: TaskIn,
    pub(super) task_truth: TaskIn,
    pub(super) joint_vision: JointIn,
    pub(super) joint_truth: JointIn,
}

#[derive(Deserialize)]
pub(super) struct TaskIn {
    pub(super) n: usize,
    pub(super) pos_mean_mm: Option<f64>,
    pub(super) rot_mean_deg: Option<f64>,
}

#[derive(Deserialize)]
pub(super) struct JointIn {
    pub(super) n: usize,
    pub(super) mae_deg: Vec<Option<f64>>,
}

impl CellIn {
    pub(super) fn six(&self) -> Six {
        let task = |t: &TaskIn, f: fn(&TaskIn) -> Option<f64>| if t.n > 0 { f(t) } else { None };
        let joint = |j: &JointIn| {
            let v: Option<Vec<f64>> = j.mae_deg.iter().copied().collect();
            v.filter(|v| j.n > 0 && !v.is_empty())
                .map(|v| v.iter().sum::<f64>() / v.len() as f64)
        };
        Six {
            position_vision: task(&self.task_vision, |t| t.pos_mean_mm),
            position_truth: task(&self.task_truth, |t| t.pos_mean_mm),
            orientation_vision: task(&self.task_vision, |t| t.rot_mean_deg),
            orientation_truth: task(&self.task_truth, |t| t.rot_mean_deg),
            joint_vision: joint(&self.joint_vision),
            joint_truth: joint(&self.joint_truth),
        }
    }
}

/// A finished unit's rows: its evaluation's, then (with `recipe.feedback`) those with feedback.
pub(super) fn unit_rows(dir: &Path, r: &Recipe) -> Result<Vec<Row>> {
    let mut rows = rows_from_summary(&dir.join("eval/summary.json"), r, "")?;
    if r.feedback.is_some() {
        rows.extend(rows_from_summary(&dir.join("eval-feedback/summary.json"), r, "+fb")?);
    }
    for name in r.trajectory_sets.keys() {
        let path = dir.join(format!("eval-{name}/summary.json"));
        rows.extend(rows_from_summary(&path, r, &set_name("", name))?);
        if r.feedback.is_some() {
            let path = dir.join(format!("eval-feedback-{name}/summary.json"));
            rows.extend(rows_from_summary(&path, r, &set_name("+fb", name))?);
        }
    }
    Ok(rows)
}

/// The name of controller `c` evaluated on the paths of trajectory set `set`.
pub(super) fn set_name(c: &str, set: &str) -> String {
    format!("{c}@{set}")
}

/// The rows of one evaluation; `suffix` is appended to the calibrated controllers' names
/// (`+fb`: the evaluation with vision feedback).
pub(super) fn rows_from_summary(path: &Path, r: &Recipe, suffix: &str) -> Result<Vec<Row>> {
    let s: SummaryIn =
        serde_json::from_str(&std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?)
            .with_context(|| format!("parsing {}", path.display()))?;
    let cell = |t: &str, c: &str| s.cells.iter().find(|x| x.trajectory == t && x.controller == c);
    let mut rows = Vec::new();
    for t in &r.trajectories {
        let u = cell(t, "uncalibrated")
            .with_context(|| format!("{}: no uncalibrated cell for trajectory {t}", path.display()))?
            .six();
        for c in r.controllers.iter().filter(|c| *c != "uncalibrated") {
            let e = cell(t, c)
                .with_context(|| format!("{}: no cell for trajectory {t}, controller {c}", path.display()))?
                .six();
            rows.push(Row {
                trajectory: t.clone(),
                controller: format!("{c}{suffix}"),
                error: e,
                uncalibrated: u,
                reduction_pct: Six::zip(&u, &e, reduction_pct),
            });
        }
    }
    Ok(rows)
}

#[derive(Debug, Clone, Copy, Serialize)]
pub(super) struct Stat {
    pub(super) n: usize,
    pub(super) min: f64,
    pub(super) median: f64,
    pub(super) max: f64,
}

pub(super) fn stat(mut v: Vec<f64>) -> Option<Stat> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    let median = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    Some(Stat {
        n,
        min: v[0],
        median,
        max: v[n - 1],
    })
}

/// min / median / max of each reduction over a family's (unit, trajectory) pairs.
#[derive(Debug, Clone, Serialize)]
pub(super) struct FamilySummary {
    pub(super) family: String,
    pub(super) controller: String,
    pub(super) units: usize,
    /// Keyed like `Six`'s fields.
    pub(super) reduction_pct: std::collections::BTreeMap<String, Stat>,
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct Violation {
    pub(super) family: String,
    pub(super) unit: u64,
    pub(super) trajectory: String,
    pub(super) metric: String,
    pub(super) reduction_pct: f64,
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct NeverWorse {
    pub(super) controller: String,
    pub(super) checks: usize,
    pub(super) violations: Vec<Violation>,
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct TimingRow {
    pub(super) family: String,
    pub(super) unit: u64,
    pub(super) collect: Option<StepTime>,
    /// All `train-*` steps.
    pub(super) train: Option<StepTime>,
    pub(super) tune: Option<StepTime>,
    pub(super) evaluate: Option<StepTime>,
    pub(super) total: StepTime,
    /// Steps whose time comes from an earlier run's stamp.
    pub(super) resumed: usize,
}

/// Wall and CPU seconds.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub(super) struct StepTime {
    pub(super) seconds: f64,
    pub(super) cpu_seconds: f64,
}

#[derive(Debug, Clone, Serialize)]
pub(super) struct Report {
    pub(super) config: PathBuf,
    pub(super) out: PathBuf,
    pub(super) project_dir: PathBuf,
    pub(super) quick: bool,
    pub(super) units_selected: UnitSet,
    pub(super) jobs: usize,
    pub(super) train_threads: usize,
    pub(super) cores: usize,
    /// 1-minute load average when the run started (other work on the machine slows it).
    pub(super) load_average: Option<f64>,
    pub(super) seed: u64,
    pub(super) recipe: Recipe,
    pub(super) families: Vec<Family>,
    /// The calibrated controller with the best median truth position reduction over the
    /// held-out (unit, trajectory) pairs: the one plotted.
    pub(super) best_mode: Option<String>,
    /// The same among the feed-forward controllers only (without vision feedback).
    pub(super) best_feed_forward: Option<String>,
    /// The goals per calibrated controller, held-out units.
    pub(super) goals: Vec<GoalCheck>,
    pub(super) summary: Vec<FamilySummary>,
    pub(super) never_worse: Vec<NeverWorse>,
    pub(super) timing: Vec<TimingRow>,
    pub(super) units: Vec<UnitOutcome>,
    /// Read back from the units' outcome files (`--merge`) instead of run by this process:
    /// jobs, threads, cores and load are then the merging process's, and `wall_seconds` is the
    /// sum of the units' wall times.
    pub(super) merged: bool,
    pub(super) wall_seconds: f64,
}

/// The feed-forward controllers, then (with `recipe.feedback`) the same with vision feedback.
pub(super) fn calibrated(r: &Recipe) -> Vec<String> {
    let ff: Vec<String> = r.controllers.iter().filter(|c| *c != "uncalibrated").cloned().collect();
    let fb: Vec<String> = if r.feedback.is_some() {
        ff.iter().map(|c| fb_name(c)).collect()
    } else {
        Vec::new()
    };
    let base: Vec<String> = ff.into_iter().chain(fb).collect();
    let sets: Vec<String> = r
        .trajectory_sets
        .keys()
        .flat_map(|set| base.iter().map(move |c| set_name(c, set)))
        .collect();
    base.into_iter().chain(sets).collect()
}

pub(super) fn summarise(units: &[&UnitOutcome], families: &[Family], r: &Recipe) -> Vec<FamilySummary> {
    let mut out = Vec::new();
    let groups: Vec<(String, Vec<&UnitOutcome>)> = families
        .iter()
        .map(|f| {
            (
                f.name.clone(),
                units.iter().copied().filter(|u| u.family == f.name).collect(),
            )
        })
        .chain(std::iter::once(("all".to_string(), units.to_vec())))
        .collect();
    for (name, us) in groups {
        let us: Vec<&UnitOutcome> = us.into_iter().filter(|u| !u.rows.is_empty()).collect();
        if us.is_empty() {
            continue;
        }
        for c in calibrated(r) {
            let mut m = std::collections::BTreeMap::new();
            for (i, (key, _)) in METRICS.iter().enumerate() {
                let v = us
                    .iter()
                    .flat_map(|u| &u.rows)
                    .filter(|row| row.controller == c)
                    .filter_map(|row| row.reduction_pct.get(i))
                    .collect();
                if let Some(s) = stat(v) {
                    m.insert(key.to_string(), s);
                }
            }
            out.push(FamilySummary {
                family: name.clone(),
                controller: c,
                units: us.len(),
                reduction_pct: m,
            });
        }
    }
    out
}

pub(super) fn never_worse(units: &[&UnitOutcome], r: &Recipe) -> Vec<NeverWorse> {
    calibrated(r)
        .into_iter()
        .map(|c| {
            let mut checks = 0;
            let mut violations = Vec::new();
            for u in units {
                for row in u.rows.iter().filter(|row| row.controller == c) {
                    for (i, (key, _)) in METRICS.iter().enumerate() {
                        if let Some(v) = row.reduction_pct.get(i) {
                            checks += 1;
                            if v < 0.0 {
                                violations.push(Violation {
                                    family: u.family.clone(),
                                    unit: u.unit,
                                    trajectory: row.trajectory.clone(),
                                    metric: key.to_string(),
                                    reduction_pct: v,
                                });
                            }
                        }
                    }
                }
            }
            NeverWorse {
                controller: c,
                checks,
                violations,
            }
        })
        .collect()
}

/// The goals (#12) for one calibrated controller over the held-out pairs: every
/// reduction ≥ 60 % and the median of each ≥ 75 %, for tip position, orientation and joint MAE,
/// by vision and by truth.
#[derive(Debug, Clone, Serialize)]
pub(super) struct GoalCheck {
    pub(super) controller: String,
    /// The smallest reduction over every pair and metric, and where.
    pub(super) worst_pct: f64,
    pub(super) worst_at: String,
    /// The smallest per-metric median.
    pub(super) lowest_median_pct: f64,
    pub(super) lowest_median_metric: String,
    /// Pairs × metrics below 60 %.
    pub(super) below_60: usize,
    pub(super) checks: usize,
    pub(super) met: bool,
}

pub(super) const GOAL_MIN_PCT: f64 = 60.0;
pub(super) const GOAL_MEDIAN_PCT: f64 = 75.0;

pub(super) fn goals(units: &[&UnitOutcome], r: &Recipe) -> Vec<GoalCheck> {
    calibrated(r)
        .into_iter()
        .filter_map(|c| {
            let (mut worst, mut worst_at, mut below, mut checks) = (f64::INFINITY, String::new(), 0, 0);
            let mut per_metric: Vec<Vec<f64>> = vec![Vec::new(); METRICS.len()];
            for u in units {
                for row in u.rows.iter().filter(|row| row.controller == c) {
                    for (i, (_, h)) in METRICS.iter().enumerate() {
                        let Some(v) = row.reduction_pct.get(i).filter(|v| v.is_finite()) else {
                            continue;
                        };
                        checks += 1;
                        per_metric[i].push(v);
                        if v < GOAL_MIN_PCT {
                            below += 1;
                        }
                        if v < worst {
                            worst = v;
                            worst_at = format!("{} {} {}, {h}", u.family, u.unit, row.trajectory);
                        }
                    }
                }
            }
            let (lowest, metric) = per_metric
                .into_iter()
                .zip(METRICS)
                .filter_map(|(v, (_, h))| stat(v).map(|s| (s.median, h.to_string())))
                .min_by(|a, b| a.0.total_cmp(&b.0))?;
            Some(GoalCheck {
                controller: c,
                worst_pct: worst,
                worst_at,
                lowest_median_pct: lowest,
                lowest_median_metric: metric,
                below_60: below,
                checks,
                met: below == 0 && lowest >= GOAL_MEDIAN_PCT,
            })
        })
        .collect()
}

/// The best calibrated controller by median truth position reduction; `feed_forward_only`
/// leaves out those with vision feedback.
pub(super) fn best_mode(units: &[&UnitOutcome], r: &Recipe, feed_forward_only: bool) -> Option<String> {
    calibrated(r)
        .into_iter()
        // The shipped paths' controllers only: other sets are reported beside them.
        .filter(|c| !c.contains('@'))
        .filter(|c| !(feed_forward_only && c.contains("+fb")))
        .filter_map(|c| {
            let v = units
                .iter()
                .flat_map(|u| &u.rows)
                .filter(|row| row.controller == c)
                .filter_map(|row| row.reduction_pct.position_truth)
                .collect();
            stat(v).map(|s| (c, s.median))
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(c, _)| c)
}

pub(super) fn timing(units: &[UnitOutcome]) -> Vec<TimingRow> {
    units
        .iter()
        .map(|u| {
            let sum = |pred: &dyn Fn(&str) -> bool| -> Option<StepTime> {
                let v: Vec<&StepRecord> = u
                    .steps
                    .iter()
                    .filter(|s| pred(&s.step) && s.status != StepStatus::Failed)
                    .collect();
                (!v.is_empty()).then(|| StepTime {
                    seconds: v.iter().map(|s| s.seconds).sum(),
                    cpu_seconds: v.iter().map(|s| s.cpu_seconds).sum(),
                })
            };
            let collect = sum(&|s| s.starts_with("collect"));
            let train = sum(&|s| s.starts_with("train-"));
            let tune = sum(&|s| s.starts_with("tune") || s == "feedback");
            let evaluate = sum(&|s| s.starts_with("evaluate"));
            TimingRow {
                family: u.family.clone(),
                unit: u.unit,
                collect,
                train,
                tune,
                evaluate,
                total: {
                    let parts = [collect, train, tune, evaluate];
                    let parts = parts.iter().flatten();
                    // `0.0 +`: an empty f64 sum is −0.0.
                    StepTime {
                        seconds: 0.0 + parts.clone().map(|t| t.seconds).sum::<f64>(),
                        cpu_seconds: 0.0 + parts.map(|t| t.cpu_seconds).sum::<f64>(),
                    }
                },
                resumed: u.steps.iter().filter(|s| s.status == StepStatus::Skipped).count(),
            }
        })
        .collect()
}
