//! The engine of `bowden bench compensate`: latency percentiles of one compensation step per
//! mode over a seeded trajectory, side by side with the naive approach (tract's full
//! evaluation for every trial) and the pass-through floor (no model: validation, output stage,
//! history) in the same run. The window prefix is computed three ways: in the step, in
//! `Compensator::prepare` after the step (as the compensator node did), and on the prefix
//! worker thread (as the node does in real time), whose rows also say how often a step ran on
//! an older prefix.

use crate::compensator::{Compensator, CompensatorError, StepOutput};
use crate::config::{ControllerConfig, EvaluatorChoice, Mode};
use crate::model::{LoadOptions, Model};
use crate::prefix::{PrefixSync, PrefixWorkerOptions};
use crate::refine::StopReason;
use bowden_interfaces::model::Direction;
use bowden_kinematics::{Robot, N_JOINTS};
use bowden_latency::{LatencyHistogram, Percentiles};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// How the targets move.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    serde::Serialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum Scenario {
    /// One dataset step (3·√5 deg) per call, as eq. (16): every step appends a history entry,
    /// so both models' prefixes change every step (the worst case).
    DatasetStep,
    /// A finely commanded path (`fine_deg_per_step`, e.g. 60 deg/s at 1 kHz): the history
    /// changes only every ~100 steps (the normal case at the robot).
    Fine,
}

impl Scenario {
    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }
}

#[derive(Clone)]
pub struct BenchOptions {
    /// Steps measured per (scenario, mode) with the incremental evaluator.
    pub steps: usize,
    /// Steps measured for the naive tract loop (paper mode).
    pub naive_steps: usize,
    pub seed: u64,
    /// Joint-space distance per call in the `fine` scenario, deg.
    pub fine_deg_per_step: f64,
    pub scenarios: Vec<Scenario>,
    /// Release one step per control period (`config.output.period_ns`), as the 1 kHz loop
    /// does, instead of back to back (the naive tract rows always run back to back). Only
    /// then does a worker row's prefix lag show what it is at the robot: back to back, a
    /// history step comes every ~100 × 15 µs instead of every ~100 ms.
    pub paced: bool,
    /// Runs first on each prefix worker thread: its placement (e.g. off the CPU the bench is
    /// pinned to; the worker inherits the bench thread's affinity otherwise).
    pub worker_placement: Option<std::sync::Arc<dyn Fn() + Send + Sync>>,
    /// Models, refinement settings and history rule come from here; the bench disables the
    /// time budget so every step runs its full iteration count.
    pub config: ControllerConfig,
    /// How long to probe the platform's interruptions before the rows (0: not probed).
    pub probe: std::time::Duration,
}

impl std::fmt::Debug for BenchOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BenchOptions")
            .field("steps", &self.steps)
            .field("naive_steps", &self.naive_steps)
            .field("seed", &self.seed)
            .field("fine_deg_per_step", &self.fine_deg_per_step)
            .field("scenarios", &self.scenarios)
            .field("paced", &self.paced)
            .field("worker_placement", &self.worker_placement.is_some())
            .field("config", &self.config)
            .field("probe", &self.probe)
            .finish()
    }
}

/// Percentiles of one configuration.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Latency {
    pub scenario: Scenario,
    pub mode: Mode,
    /// `incremental`, `tract` (naive) or `none` (the pass-through floor).
    pub evaluator: &'static str,
    /// One step per control period (`--paced`) instead of back to back.
    pub paced: bool,
    /// Where the window prefix was computed: `in step`, `prepare` (after the step, see
    /// `prepare_*`), `worker` (the prefix worker thread, real-time mode) or `none`.
    pub prefix: &'static str,
    /// True when the prefix update ran in `Compensator::prepare` after each step (off the
    /// target → command path) instead of at the start of the next step; its own percentiles
    /// are in `prepare_*`.
    pub prepare: Option<Percentiles>,
    /// The steps' latency (`count` steps).
    #[serde(flatten)]
    pub latency: Percentiles,
    pub mean_forward_evals: f64,
    pub max_forward_evals: u32,
    /// Fraction of steps after which the history changed (prefix recomputed next step).
    pub history_change_fraction: f64,
    /// Fraction of steps whose refinement stopped at the threshold / tolerance.
    pub threshold_fraction: f64,
    /// Fraction of steps that ran on an older prefix than the history's (worker rows).
    pub lagged_fraction: f64,
    /// The largest lag, history entries (worker rows).
    pub max_prefix_lag: u32,
}

impl Latency {
    /// A row with the percentiles of `h` and nothing else measured (no prepare split, no model
    /// evaluations, no history changes).
    fn of(
        h: &LatencyHistogram,
        scenario: Scenario,
        mode: Mode,
        evaluator: &'static str,
        paced: bool,
        prefix: &'static str,
    ) -> Self {
        Latency {
            scenario,
            mode,
            evaluator,
            paced,
            prefix,
            prepare: None,
            latency: h.percentiles(),
            mean_forward_evals: 0.0,
            max_forward_evals: 0,
            history_change_fraction: 0.0,
            threshold_fraction: 0.0,
            lagged_fraction: 0.0,
            max_prefix_lag: 0,
        }
    }
}

/// Naive / incremental, paper mode, same scenario.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Ratio {
    pub scenario: Scenario,
    pub p50: f64,
    pub mean: f64,
    pub p999: f64,
}

#[derive(Debug, Clone, serde::Serialize)]
pub struct BenchReport {
    pub model_fwd: String,
    pub model_inv: String,
    pub paper_iterations: u32,
    pub rows: Vec<Latency>,
    pub ratios: Vec<Ratio>,
    /// What the platform took from the bench thread, probed just before the rows.
    pub interruptions: Option<Interruptions>,
}

/// The platform's interruptions of a busy thread: gaps in a tight loop that only reads the
/// clock (what `hwlatdetect` and cyclictest's busy mode look at), on the bench thread with its
/// pinning and policy. A step of length s meets one with probability ≈ s · `per_s`; once that
/// exceeds 0.1 %, the step's p99.9 is the step plus an interruption, whatever the code does.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Interruptions {
    pub probe_ns: u64,
    /// Gaps longer than this count as interruptions (a clock read takes ~20 ns).
    pub threshold_ns: u64,
    pub count: u64,
    pub per_s: f64,
    pub p50_ns: u64,
    pub mean_ns: f64,
    pub max_ns: u64,
    /// The longest step an interruption reaches in fewer than 0.1 % of steps: 1e-3 / `per_s`.
    pub p999_clear_step_ns: f64,
}

/// Probes the calling thread's interruptions for `duration` (see [`Interruptions`]).
pub fn probe_interruptions(duration: std::time::Duration) -> Interruptions {
    let start = std::time::Instant::now();
    probe_gaps(duration.as_nanos() as u64, || start.elapsed().as_nanos() as u64)
}

/// The probe over any clock (ns since the start): gaps between consecutive reads.
fn probe_gaps(duration_ns: u64, mut now_ns: impl FnMut() -> u64) -> Interruptions {
    const THRESHOLD_NS: u64 = 5_000;
    let mut gaps: Vec<u64> = Vec::with_capacity(1 << 16);
    let (mut count, mut sum, mut max) = (0u64, 0u128, 0u64);
    let mut prev = now_ns();
    let start = prev;
    loop {
        let t = now_ns();
        let d = t.saturating_sub(prev);
        prev = t;
        if d > THRESHOLD_NS {
            count += 1;
            sum += d as u128;
            max = max.max(d);
            if gaps.len() < gaps.capacity() {
                gaps.push(d);
            }
        }
        if t - start >= duration_ns {
            break;
        }
    }
    let probe_ns = (prev - start).max(1);
    gaps.sort_unstable();
    let per_s = count as f64 / (probe_ns as f64 * 1e-9);
    Interruptions {
        probe_ns,
        threshold_ns: THRESHOLD_NS,
        count,
        per_s,
        p50_ns: gaps.get(gaps.len() / 2).copied().unwrap_or(0),
        mean_ns: if count > 0 { sum as f64 / count as f64 } else { 0.0 },
        max_ns: max,
        p999_clear_step_ns: if per_s > 0.0 { 1e-3 / per_s * 1e9 } else { f64::INFINITY },
    }
}

/// eq. (16): random waypoints within 80 % of the joint limits (jaws not crossing), joined by
/// points `spacing_deg` apart in joint space.
pub fn random_trajectory(robot: &Robot, n: usize, spacing_deg: f64, seed: u64) -> Vec<[f64; N_JOINTS]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let lim = &robot.config.limits;
    let mut waypoint = || {
        let mut q = [0.0; N_JOINTS];
        for (c, v) in q.iter_mut().enumerate() {
            *v = rng.random_range(0.8 * lim.q_min_deg[c]..0.8 * lim.q_max_deg[c]);
        }
        if q[4] < q[3] {
            q.swap(3, 4);
        }
        robot.clamp_to_limits(&q)
    };
    let mut out = Vec::with_capacity(n);
    let mut a = [0.0; N_JOINTS];
    while out.len() < n {
        let b = waypoint();
        let d = (0..N_JOINTS).map(|c| (b[c] - a[c]).powi(2)).sum::<f64>().sqrt();
        let k_max = (d / spacing_deg).floor() as usize;
        for k in 0..=k_max {
            if out.len() == n {
                break;
            }
            let f = if d > 0.0 { k as f64 * spacing_deg / d } else { 0.0 };
            let mut q = [0.0; N_JOINTS];
            for c in 0..N_JOINTS {
                q[c] = a[c] + f * (b[c] - a[c]);
            }
            out.push(q);
        }
        a = b;
    }
    out
}

/// Where a row computes the window prefix.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PrefixAt {
    InStep,
    Prepare,
    Worker,
}

/// Sleeps to step `i`'s release time, as a periodic loop does (never measured); back to back
/// without a period. The step rows and their spin rows are released by this one function.
fn sleep_to_release(start: std::time::Instant, period: Option<std::time::Duration>, i: usize) {
    if let Some(p) = period {
        let release = start + p * i as u32;
        let now = std::time::Instant::now();
        if release > now {
            std::thread::sleep(release - now);
        }
    }
}

fn histogram() -> LatencyHistogram {
    LatencyHistogram::new()
}

#[allow(clippy::too_many_arguments)]
fn measure(
    comp: &mut Compensator,
    targets: &[[f64; N_JOINTS]],
    warmup: usize,
    steps: usize,
    scenario: Scenario,
    evaluator: &'static str,
    at: PrefixAt,
    period: Option<std::time::Duration>,
    progress: &mut dyn FnMut(u64),
) -> Latency {
    let split = at == PrefixAt::Prepare;
    let (mut h, mut hp) = (histogram(), histogram());
    let mut out = StepOutput::default();
    let (mut evals, mut max_evals, mut changes, mut thr) = (0u64, 0u32, 0u64, 0u64);
    let (mut lagged, mut max_lag) = (0u64, 0u32);
    comp.reset();
    let start = std::time::Instant::now();
    for i in 0..warmup + steps {
        sleep_to_release(start, period, i);
        let t = &targets[i % targets.len()];
        // Targets come from the generator: always valid.
        let _ = comp.step(t, &mut out);
        let mut prep_ns = 0;
        if split {
            let t0 = std::time::Instant::now();
            comp.prepare();
            prep_ns = t0.elapsed().as_nanos() as u64;
        } else if at == PrefixAt::Worker {
            // As the node does after publishing: hand the new history to the worker.
            comp.prepare();
        }
        if i >= warmup {
            h.record(out.elapsed_ns);
            if split {
                hp.record(prep_ns);
            }
            evals += out.forward_evals as u64;
            max_evals = max_evals.max(out.forward_evals);
            changes += (out.history_appended > 0) as u64;
            thr += (out.stop_reason == StopReason::Threshold) as u64;
            lagged += (out.prefix_lag > 0) as u64;
            max_lag = max_lag.max(out.prefix_lag);
            progress(1);
        }
    }
    let n = steps.max(1) as f64;
    let prefix = match (evaluator, at) {
        ("none", _) => "none",
        (_, PrefixAt::InStep) => "in step",
        (_, PrefixAt::Prepare) => "prepare",
        (_, PrefixAt::Worker) => "worker",
    };
    Latency {
        prepare: split.then(|| hp.percentiles()),
        mean_forward_evals: evals as f64 / n,
        max_forward_evals: max_evals,
        history_change_fraction: changes as f64 / n,
        threshold_fraction: thr as f64 / n,
        lagged_fraction: lagged as f64 / n,
        max_prefix_lag: max_lag,
        ..Latency::of(&h, scenario, comp.mode(), evaluator, period.is_some(), prefix)
    }
}

/// The platform's floor for a step of `length_ns`: a clock spin of exactly that length,
/// released like the measured rows (paced or back to back) and timed the same way. The
/// pass-through floor is too short to meet the platform's interruptions (≈ 400/s here) as often
/// as a step of several µs does; a spin as long as the step meets them exactly as often, so its
/// p99.9 is the lowest p99.9 any code of that length can show on this machine.
fn measure_spin(
    length_ns: u64,
    warmup: usize,
    steps: usize,
    scenario: Scenario,
    mode: Mode,
    period: Option<std::time::Duration>,
    progress: &mut dyn FnMut(u64),
) -> Latency {
    let mut h = histogram();
    let length = std::time::Duration::from_nanos(length_ns);
    let start = std::time::Instant::now();
    for i in 0..warmup + steps {
        sleep_to_release(start, period, i);
        let t0 = std::time::Instant::now();
        while t0.elapsed() < length {
            std::hint::spin_loop();
        }
        let ns = t0.elapsed().as_nanos() as u64;
        if i >= warmup {
            h.record(ns);
            progress(1);
        }
    }
    Latency::of(&h, scenario, mode, "spin", period.is_some(), "none")
}

fn load(cfg: &ControllerConfig, field: &'static str, dir: Direction) -> Result<(Model, String), CompensatorError> {
    let p = match (field, &cfg.model_fwd, &cfg.model_inv) {
        ("model_fwd", Some(p), _) | ("model_inv", _, Some(p)) => p.clone(),
        _ => {
            return Err(CompensatorError::MissingModel {
                mode: Mode::Paper,
                which: if dir == Direction::Forward {
                    "a forward"
                } else {
                    "an inverse"
                },
                field,
            })
        }
    };
    let path = cfg.resolve_model_path(field, &p)?;
    let m = Model::load_with(
        &path,
        &LoadOptions {
            check_windows: cfg.load_check.windows,
            tolerance_deg: cfg.load_check.tolerance_deg,
            ..LoadOptions::default()
        },
    )?;
    Ok((m, path.display().to_string()))
}

/// Total steps `run` will report through `progress` (for a progress bar).
pub fn total_steps(opts: &BenchOptions) -> u64 {
    // Every mode in step, paper and newton in prepare and on the worker, and a spin as long as
    // each worker row.
    (opts.scenarios.len() * ((Mode::ALL.len() + 6) * opts.steps + opts.naive_steps)) as u64
}

/// Runs every scenario × mode with the incremental evaluator (the prefix in the step; paper
/// and newton also with it in `prepare` and on the worker), the pass-through floor, and paper
/// mode with the naive tract loop, in this process, one after the other.
pub fn run(opts: &BenchOptions, robot: &Robot, progress: &mut dyn FnMut(u64)) -> Result<BenchReport, CompensatorError> {
    let (fwd, fwd_name) = load(&opts.config, "model_fwd", Direction::Forward)?;
    let (inv, inv_name) = load(&opts.config, "model_inv", Direction::Inverse)?;
    let mut cfg = opts.config.clone();
    cfg.budget.budget_ns = 0;
    let interruptions = (!opts.probe.is_zero()).then(|| probe_interruptions(opts.probe));
    let mut rows = Vec::new();
    let mut ratios = Vec::new();
    for &scenario in &opts.scenarios {
        let spacing = match scenario {
            Scenario::DatasetStep => cfg.history.step_deg,
            Scenario::Fine => opts.fine_deg_per_step,
        };
        let n_targets = (opts.steps + 2000).min(400_000);
        let targets = random_trajectory(robot, n_targets, spacing, opts.seed);
        let mut paper_inc = None;
        let runs = Mode::ALL.iter().map(|&m| (m, PrefixAt::InStep)).chain([
            (Mode::Paper, PrefixAt::Prepare),
            (Mode::Newton, PrefixAt::Prepare),
            (Mode::Paper, PrefixAt::Worker),
            (Mode::Newton, PrefixAt::Worker),
        ]);
        for (mode, at) in runs {
            let mut c = cfg.clone();
            c.mode = mode;
            c.evaluator = EvaluatorChoice::Auto;
            // The floor: uncalibrated without models, as the node runs it (validation, output
            // stage, history; no prefix, no prediction).
            let floor = mode == Mode::Uncalibrated;
            let mut comp = if floor {
                Compensator::from_models(&c, robot, None, None)?
            } else {
                Compensator::from_models(&c, robot, Some(fwd.clone()), Some(inv.clone()))?
            };
            if at == PrefixAt::Worker {
                comp.start_prefix_worker(PrefixWorkerOptions {
                    sync: PrefixSync::Newest,
                    name: "bench-prefix".into(),
                    on_start: opts
                        .worker_placement
                        .clone()
                        .map(|f| Box::new(move || f()) as Box<dyn FnOnce() + Send>),
                })
                .map_err(|e| CompensatorError::Mismatch {
                    path: "prefix worker".into(),
                    what: e.to_string(),
                })?;
            }
            let evaluator = if floor { "none" } else { "incremental" };
            let period = opts
                .paced
                .then(|| std::time::Duration::from_nanos(cfg.output.period_ns.max(1)));
            let lat = measure(
                &mut comp, &targets, 1000, opts.steps, scenario, evaluator, at, period, progress,
            );
            if mode == Mode::Paper && at == PrefixAt::InStep {
                paper_inc = Some(lat.clone());
            }
            let matched = (at == PrefixAt::Worker).then_some(lat.latency.p50_ns);
            rows.push(lat);
            if let Some(length_ns) = matched {
                drop(comp);
                rows.push(measure_spin(
                    length_ns, 1000, opts.steps, scenario, mode, period, progress,
                ));
            }
        }
        let mut c = cfg.clone();
        c.mode = Mode::Paper;
        c.evaluator = EvaluatorChoice::Tract;
        let mut comp = Compensator::from_models(&c, robot, Some(fwd.clone()), Some(inv.clone()))?;
        let naive = measure(
            &mut comp,
            &targets,
            10,
            opts.naive_steps,
            scenario,
            "tract",
            PrefixAt::InStep,
            None,
            progress,
        );
        if let Some(p) = paper_inc {
            ratios.push(Ratio {
                scenario,
                p50: naive.latency.p50_ns as f64 / p.latency.p50_ns.max(1) as f64,
                mean: naive.latency.mean_ns / p.latency.mean_ns.max(1.0),
                p999: naive.latency.p999_ns as f64 / p.latency.p999_ns.max(1) as f64,
            });
        }
        rows.push(naive);
    }
    Ok(BenchReport {
        model_fwd: fwd_name,
        model_inv: inv_name,
        paper_iterations: cfg.paper.iterations,
        rows,
        ratios,
        interruptions,
    })
}

/// A plot that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{path}: cannot write the plot: {message}")]
pub struct PlotError {
    pub path: String,
    pub message: String,
}

impl BenchReport {
    /// Latency percentiles per configuration on a log axis (SVG): p50 ●, p99 ▲, p99.9 ✕, max ·.
    pub fn write_svg(&self, path: &std::path::Path) -> Result<(), PlotError> {
        use plotters::prelude::*;
        let err = |e: &dyn std::fmt::Display| PlotError {
            path: path.display().to_string(),
            message: e.to_string(),
        };
        let n = self.rows.len();
        let label = |r: &Latency| {
            format!(
                "{} · {} · {}{}",
                r.scenario.as_str(),
                r.mode,
                r.evaluator,
                match r.prefix {
                    "prepare" => " (prefix in prepare)",
                    "worker" => " (prefix worker)",
                    "none" if r.evaluator == "spin" => " (platform floor at the row above's p50)",
                    "none" => " (pass-through floor)",
                    _ => "",
                }
            )
        };
        let labels: Vec<String> = self.rows.iter().map(label).collect();
        const LEGEND_PX: u32 = 30;
        let root = SVGBackend::new(path, (1100, 90 + LEGEND_PX + 34 * n as u32)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let root = root
            .titled(
                &format!("Compensation step latency (paper mode M = {})", self.paper_iterations),
                ("sans-serif", 20),
            )
            .map_err(|e| err(&e))?;
        // The legend on its own strip above the chart, where it covers no row.
        let (legend, root) = root.split_vertically(LEGEND_PX);
        {
            use plotters::style::text_anchor::{HPos, Pos, VPos};
            let style = TextStyle::from(("sans-serif", 14).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
            let y = LEGEND_PX as i32 / 2;
            for (k, label) in ["p50", "p99", "p99.9", "max"].into_iter().enumerate() {
                let x = 350 + 110 * k as i32;
                match k {
                    0 => legend.draw(&Circle::new((x, y), 5, BLUE.filled())),
                    1 => legend.draw(&TriangleMarker::new((x, y), 6, GREEN.filled())),
                    2 => legend.draw(&Cross::new((x, y), 6, RED.stroke_width(2))),
                    _ => legend.draw(&Circle::new((x, y), 2, BLACK.filled())),
                }
                .map_err(|e| err(&e))?;
                legend
                    .draw(&Text::new(label, (x + 12, y), style.clone()))
                    .map_err(|e| err(&e))?;
            }
        }
        let us = |ns: u64| (ns.max(1) as f64) / 1000.0;
        let x_max = self.rows.iter().map(|r| us(r.latency.max_ns)).fold(1.0, f64::max) * 2.0;
        let mut chart = ChartBuilder::on(&root)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(330)
            .build_cartesian_2d((0.05f64..x_max).log_scale(), -0.5f64..(n as f64 - 0.5))
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("µs per step (log)")
            .y_labels(n)
            .y_label_formatter(&|y| {
                let i = y.round();
                if (y - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < n {
                    labels[i as usize].clone()
                } else {
                    String::new()
                }
            })
            .draw()
            .map_err(|e| err(&e))?;
        let pts = |f: &dyn Fn(&Latency) -> u64| -> Vec<(f64, f64)> {
            self.rows
                .iter()
                .enumerate()
                .map(|(i, r)| (us(f(r)), i as f64))
                .collect()
        };
        chart
            .draw_series(
                pts(&|r| r.latency.p50_ns)
                    .into_iter()
                    .map(|p| Circle::new(p, 5, BLUE.filled())),
            )
            .map_err(|e| err(&e))?;
        chart
            .draw_series(
                pts(&|r| r.latency.p99_ns)
                    .into_iter()
                    .map(|p| TriangleMarker::new(p, 6, GREEN.filled())),
            )
            .map_err(|e| err(&e))?;
        chart
            .draw_series(
                pts(&|r| r.latency.p999_ns)
                    .into_iter()
                    .map(|p| Cross::new(p, 6, RED.stroke_width(2))),
            )
            .map_err(|e| err(&e))?;
        chart
            .draw_series(
                pts(&|r| r.latency.max_ns)
                    .into_iter()
                    .map(|p| Circle::new(p, 2, BLACK.filled())),
            )
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
        Ok(())
    }

    /// Markdown table of the rows and the ratios.
    pub fn to_markdown(&self) -> String {
        let us = |ns: u64| format!("{:.2}", ns as f64 / 1000.0);
        let mut s = format!(
            "forward model: {}\ninverse model: {}\n(paper mode: M = {}; time budget disabled; {})\n\n",
            self.model_fwd,
            self.model_inv,
            self.paper_iterations,
            if self.rows.iter().any(|r| r.paced) {
                "incremental rows paced at one step per control period, tract rows back to back"
            } else {
                "steps back to back"
            }
        );
        s += "| scenario | mode | evaluator | prefix | steps | p50 µs | p99 µs | p99.9 µs | max µs | mean µs | fwd evals (mean/max) | history changes | at threshold | prepare p50 / p99.9 / max µs | on older prefix (max lag) |\n";
        s += "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
        for r in &self.rows {
            let prep = match &r.prepare {
                Some(p) => format!("{} / {} / {}", us(p.p50_ns), us(p.p999_ns), us(p.max_ns)),
                None => "–".to_string(),
            };
            let lag = if r.prefix == "worker" {
                format!("{:.2} % ({})", 100.0 * r.lagged_fraction, r.max_prefix_lag)
            } else {
                "–".to_string()
            };
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.1}/{} | {:.1} % | {:.1} % | {} | {} |\n",
                r.scenario.as_str(),
                r.mode,
                r.evaluator,
                r.prefix,
                r.latency.count,
                us(r.latency.p50_ns),
                us(r.latency.p99_ns),
                us(r.latency.p999_ns),
                us(r.latency.max_ns),
                r.latency.mean_ns / 1000.0,
                r.mean_forward_evals,
                r.max_forward_evals,
                100.0 * r.history_change_fraction,
                100.0 * r.threshold_fraction,
                prep,
                lag,
            );
        }
        if let Some(i) = &self.interruptions {
            s += &format!(
                "\nPlatform interruptions of this thread (a {:.1} s busy clock loop before the rows, gaps > {} µs): {:.0}/s, p50 {} µs, mean {:.1} µs, max {} µs. A step longer than {:.1} µs meets one in more than 0.1 % of steps, so its p99.9 includes about {:.0} µs that no code change removes (on an isolated `nohz_full` CPU the rate falls towards 0).\n",
                i.probe_ns as f64 * 1e-9,
                us(i.threshold_ns),
                i.per_s,
                us(i.p50_ns),
                i.mean_ns / 1000.0,
                us(i.max_ns),
                i.p999_clear_step_ns / 1000.0,
                i.mean_ns / 1000.0,
            );
        }
        let floors: Vec<(&Latency, &Latency, Option<&Latency>)> = self
            .rows
            .windows(2)
            .filter(|w| w[1].evaluator == "spin")
            .map(|w| {
                let pass = self
                    .rows
                    .iter()
                    .find(|r| r.scenario == w[0].scenario && r.evaluator == "none");
                (&w[0], &w[1], pass)
            })
            .collect();
        if !floors.is_empty() {
            s += "\nAgainst the floors measured in this run (prefix on the worker, as the real-time node runs): the pass-through (no model), and the platform's floor at the step's length (a clock spin as long as the step's p50, released the same way).\n\n";
            s += "| scenario | mode | step p50 / p99.9 µs | pass-through p99.9 µs | step / pass-through | spin of the step's p50: p99.9 µs | step / spin |\n|---|---|---:|---:|---:|---:|---:|\n";
            for (step, spin, pass) in floors {
                let ratio = |a: u64, b: u64| format!("{:.2}×", a as f64 / b.max(1) as f64);
                s += &format!(
                    "| {} | {} | {} / {} | {} | {} | {} | {} |\n",
                    step.scenario.as_str(),
                    step.mode,
                    us(step.latency.p50_ns),
                    us(step.latency.p999_ns),
                    pass.map_or("–".into(), |p| us(p.latency.p999_ns)),
                    pass.map_or("–".into(), |p| ratio(step.latency.p999_ns, p.latency.p999_ns)),
                    us(spin.latency.p999_ns),
                    ratio(step.latency.p999_ns, spin.latency.p999_ns),
                );
            }
        }
        s += "\n| scenario | naive tract / incremental (paper mode): p50 | mean | p99.9 |\n|---|---:|---:|---:|\n";
        for r in &self.ratios {
            s += &format!(
                "| {} | {:.0}× | {:.0}× | {:.0}× |\n",
                r.scenario.as_str(),
                r.p50,
                r.mean,
                r.p999
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_renders_as_markdown_and_svg() {
        let row = |mode, evaluator, p50| Latency {
            scenario: Scenario::Fine,
            mode,
            evaluator,
            paced: false,
            prefix: "in step",
            prepare: None,
            latency: Percentiles {
                count: 10,
                p50_ns: p50,
                p99_ns: 2 * p50,
                p999_ns: 3 * p50,
                max_ns: 4 * p50,
                mean_ns: p50 as f64,
            },
            mean_forward_evals: 51.0,
            max_forward_evals: 51,
            history_change_fraction: 0.01,
            threshold_fraction: 0.0,
            lagged_fraction: 0.0,
            max_prefix_lag: 0,
        };
        let r = BenchReport {
            model_fwd: "f.onnx".into(),
            model_inv: "i.onnx".into(),
            paper_iterations: 50,
            rows: vec![
                row(Mode::Paper, "incremental", 10_000),
                row(Mode::Paper, "tract", 2_000_000),
            ],
            ratios: vec![Ratio {
                scenario: Scenario::Fine,
                p50: 200.0,
                mean: 200.0,
                p999: 200.0,
            }],
            interruptions: Some(Interruptions {
                probe_ns: 500_000_000,
                threshold_ns: 5_000,
                count: 200,
                per_s: 400.0,
                p50_ns: 20_000,
                mean_ns: 23_500.0,
                max_ns: 150_000,
                p999_clear_step_ns: 2_500.0,
            }),
        };
        let md = r.to_markdown();
        assert!(
            md.contains("| fine | paper | tract | in step | 10 | 2000.00 |") && md.contains("200×"),
            "{md}"
        );
        assert!(
            md.contains("400/s, p50 20.00 µs, mean 23.5 µs") && md.contains("longer than 2.5 µs"),
            "{md}"
        );
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lat.svg");
        r.write_svg(&p).unwrap();
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(svg.starts_with("<svg") && svg.contains("p99.9") && svg.contains("fine · paper · tract"));
        // The legend is a strip above the rows, not a box over them (plotters' box is 0.8 opaque).
        assert!(!svg.contains(r#"opacity="0.8""#), "a legend box over the data");

        // A worker row followed by its matched spin, with the pass-through in the same scenario:
        // the floors table compares the step's p99.9 with both.
        let mut pass = row(Mode::Uncalibrated, "none", 500);
        pass.prefix = "none";
        let mut worker = row(Mode::Paper, "incremental", 10_000);
        worker.prefix = "worker";
        let mut spin = row(Mode::Paper, "spin", 10_000);
        spin.prefix = "none";
        spin.latency.p999_ns = 20_000;
        let r = BenchReport {
            rows: vec![pass, worker, spin],
            ..r
        };
        let md = r.to_markdown();
        assert!(
            md.contains("| fine | paper | 10.00 / 30.00 | 1.50 | 20.00× | 20.00 | 1.50× |"),
            "{md}"
        );
        let p = dir.path().join("floors.svg");
        r.write_svg(&p).unwrap();
        assert!(std::fs::read_to_string(&p)
            .unwrap()
            .contains("platform floor at the row above"));
    }

    #[test]
    fn a_matched_spin_lasts_at_least_its_length() {
        let mut ticks = 0;
        let l = measure_spin(20_000, 10, 200, Scenario::DatasetStep, Mode::Newton, None, &mut |n| {
            ticks += n
        });
        assert_eq!(
            (l.latency.count, ticks, l.evaluator, l.mode),
            (200, 200, "spin", Mode::Newton)
        );
        assert!(
            l.latency.p50_ns >= 20_000
                && l.latency.max_ns >= l.latency.p999_ns
                && l.latency.p999_ns >= l.latency.p50_ns,
            "{l:?}"
        );
    }

    #[test]
    fn trajectory_is_eq16_spaced_and_within_limits() {
        let robot = Robot::paper_default();
        let step = 3.0 * 5f64.sqrt();
        let t = random_trajectory(&robot, 500, step, 1);
        assert_eq!(t.len(), 500);
        assert_eq!(t, random_trajectory(&robot, 500, step, 1), "seeded");
        let mut exact = 0;
        for w in t.windows(2) {
            let d = (0..N_JOINTS).map(|c| (w[1][c] - w[0][c]).powi(2)).sum::<f64>().sqrt();
            assert!(d <= step + 1e-9);
            exact += ((d - step).abs() < 1e-9) as usize;
        }
        assert!(exact > 400, "most consecutive targets are one step apart ({exact})");
        assert!(t.iter().all(|q| robot.check_limits(q).is_ok()));
    }
}

#[cfg(test)]
mod probe_tests {
    /// A clock advancing 50 ns per read with a 20 µs stall every 10 000 reads (one per
    /// 519.95 µs: 1 923 in 1 s) and one 150 µs stall: the probe must count, rate and size them.
    #[test]
    fn probe_counts_rates_and_sizes_gaps() {
        let mut t = 0u64;
        let mut k = 0u64;
        let i = super::probe_gaps(1_000_000_000, || {
            k += 1;
            t += if k == 777_777 {
                150_000
            } else if k.is_multiple_of(10_000) {
                20_000
            } else {
                50
            };
            t
        });
        assert!((1_922..=1_925).contains(&i.count), "{i:?}");
        assert!((i.per_s - i.count as f64).abs() < 2.0, "{i:?}");
        assert_eq!((i.p50_ns, i.max_ns), (20_000, 150_000), "{i:?}");
        assert!((i.p999_clear_step_ns - 1e6 / i.per_s).abs() < 1e-6 * i.p999_clear_step_ns);
        // A clock that never stalls: no interruption, every step clears.
        let mut t = 0u64;
        let quiet = super::probe_gaps(1_000_000, || {
            t += 40;
            t
        });
        assert_eq!(quiet.count, 0);
        assert!(quiet.p999_clear_step_ns.is_infinite());
    }
}
