//! `bowden compensate` (offline, CSV in/out) and `bowden bench compensate`: thin wrappers over
//! `bowden-compensator`.

use anyhow::{bail, Context};
use bowden_compensator::bench::{self, BenchOptions, Scenario};
use bowden_compensator::{offline, Compensator, ControllerConfig, Mode};
use bowden_kinematics::Robot;
use clap::{Args, Subcommand};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum Command {
    /// Compensate a target file offline: CSV in (columns q1..q5, degrees), CSV out with the
    /// command, the forward model's prediction, iterations and stop reason per target.
    ///
    /// The rows are waypoints, compensated in order with no output rate limit, unless
    /// --period-ns gives their spacing in time. Joint limits apply (`output.joint_limits`).
    ///
    /// Output columns, one row per target: `step` (0-based row), `q_des_1..5` (the target),
    /// `q_cmd_1..5` (the command to send), `q_pred_1..5` (the forward model's prediction of the
    /// physical angles at q_cmd; zeros without a forward model), `loss_max_abs_deg`
    /// (max_j |q_pred − q_des|: the predicted error; empty without a forward model),
    /// `iterations` and `forward_evals` (refinement iterations and forward-model evaluations),
    /// `stop_reason` (none | threshold | max-iterations | budget | stalled | rejected-input),
    /// `elapsed_ns` (wall time of the step). All angles in degrees. The summary on stderr
    /// gives the mean and max predicted error, and with `[safety] never_worse` how often the
    /// refinement's result, its start or the target unchanged was sent (many targets sent
    /// unchanged: the models do not fit this robot); run with `--mode uncalibrated` to compare.
    /// Every row the robot's joint limits or jaw rule changed is counted (per joint) and
    /// reported, with a warning when more than 1 % of the rows were.
    Compensate(CompensateArgs),
}

/// Model and config options shared by `compensate` and `bench compensate`.
#[derive(Args, Debug, Clone)]
pub struct ModelArgs {
    /// Forward model (ONNX, contract of docs/architecture.md §5); default: the config's `model_fwd`.
    #[arg(long)]
    pub model_fwd: Option<PathBuf>,
    /// Inverse model; default: the config's `model_inv`.
    #[arg(long)]
    pub model_inv: Option<PathBuf>,
    /// Controller config; found as given, under $BOWDEN_HOME, or built in (`bowden shipped`).
    #[arg(long, default_value = "configs/controller.toml")]
    pub config: PathBuf,
    /// Robot config for the joint limits (default: the shipped configs/robot.toml).
    #[arg(long)]
    pub robot: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct CompensateArgs {
    #[command(flatten)]
    models: ModelArgs,
    /// Target file: CSV with a header naming the joint columns q1..q5 (or --cols), degrees;
    /// other columns are ignored; `#` lines and blank lines are skipped.
    #[arg(long)]
    targets: PathBuf,
    /// CSV target columns, q1..q5 in order (default: q1, q2, ...), e.g.
    /// `--cols q_des_1,q_des_2,q_des_3,q_des_4,q_des_5`.
    #[arg(long)]
    cols: Option<String>,
    /// Controller mode (default: the config's mode).
    #[arg(long, value_parser = super::typed::<Mode>(), ignore_case = true)]
    mode: Option<Mode>,
    /// Output CSV (default: standard output); the columns are listed above.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite --out if it exists.
    #[arg(long)]
    force: bool,
    /// Time budget per step in ns; default 0 (none), so the output is reproducible.
    #[arg(long, default_value_t = 0)]
    budget_ns: u64,
    /// Time between consecutive rows, ns. Default (or 0): the rows are waypoints and no output
    /// rate limit applies. N > 0: the rows are N ns apart and the controller's output limits
    /// apply, so each command moves at most `output.rate_limit_deg_s` · N ns from the last
    /// (e.g. 0.36° per row for the shipped 360°/s at N = 1000000, a 1 kHz stream).
    #[arg(long)]
    period_ns: Option<u64>,
    /// Also write the summary as JSON to FILE: steps, predicted error, stop reasons, and how
    /// many rows the joint limits (per joint, lowered / raised) and the rate limit changed.
    #[arg(long, value_name = "FILE")]
    summary_json: Option<PathBuf>,
}

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Latency of one compensation step per mode (p50/p99/p99.9/max over ≥ 100k steps) beside
    /// the naive approach (tract's full evaluation for every trial) and their ratio.
    Compensate(BenchArgs),
}

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(flatten)]
    models: ModelArgs,
    /// Steps measured per scenario and mode.
    #[arg(long, default_value_t = 100_000)]
    steps: usize,
    /// Steps measured for the naive tract loop (slow: ~50 tract runs per step).
    #[arg(long, default_value_t = 300)]
    naive_steps: usize,
    /// dataset-step (a history change every step: the worst case), fine (1 kHz-like), both.
    #[arg(long, value_enum, default_value_t = ScenarioChoice::Both, ignore_case = true)]
    scenario: ScenarioChoice,
    /// Joint-space distance per step of the `fine` scenario, deg (0.06 = 60 deg/s at 1 kHz).
    #[arg(long, default_value_t = 0.06)]
    fine_deg_per_step: f64,
    /// Trajectory seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Pin the benchmark thread to this CPU.
    #[arg(long)]
    cpu: Option<usize>,
    /// Run the benchmark thread under SCHED_FIFO at this priority, as the real-time loop runs
    /// (processes at lower priority, compilers included, then cannot preempt a step). The
    /// prefix worker stays under SCHED_OTHER. Back-to-back runs at 100 % CPU are throttled by
    /// the kernel's RT bandwidth limit (50 ms per second by default): use with --paced.
    #[arg(long, value_name = "PRIO")]
    fifo: Option<u8>,
    /// Release one step per control period (the config's output.period_ns, 1 ms) as the
    /// real-time loop does, instead of back to back (naive tract rows stay back to back). The
    /// prefix worker's lag is only representative paced.
    #[arg(long)]
    paced: bool,
    /// Before the rows, read the clock in a tight loop on the bench thread for this long and
    /// report the platform's interruptions (gaps > 5 µs): what sets the p99.9 of any step long
    /// enough to meet one in 0.1 % of steps. 0: skip.
    #[arg(long, value_name = "MS", default_value_t = 500)]
    probe_ms: u64,
    /// Print JSON instead of the Markdown table.
    #[arg(long)]
    json: bool,
    /// Also write the report as FILE.json, FILE.md and FILE.svg (latency plot).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite the --out files if they exist.
    #[arg(long)]
    force: bool,
}

fn absolute(p: &Path) -> anyhow::Result<PathBuf> {
    if p.is_absolute() {
        Ok(p.to_path_buf())
    } else {
        Ok(std::env::current_dir().context("current directory")?.join(p))
    }
}

pub fn load_setup(m: &ModelArgs) -> anyhow::Result<(ControllerConfig, Robot)> {
    // The config's relative model paths resolve beside it, wherever it was found.
    let config = crate::home::resolve(&m.config)?;
    let mut cfg = ControllerConfig::load(&config.path)
        .with_context(|| format!("loading controller config {}", config.shown()))?;
    if let Some(p) = &m.model_fwd {
        cfg.model_fwd = Some(absolute(&crate::home::path(p)?)?);
    }
    if let Some(p) = &m.model_inv {
        cfg.model_inv = Some(absolute(&crate::home::path(p)?)?);
    }
    let robot = match &m.robot {
        Some(p) => {
            Robot::load(crate::home::path(p)?).with_context(|| format!("loading robot config {}", p.display()))?
        }
        None => Robot::paper_default(),
    };
    Ok((cfg, robot))
}

/// `bench compensate --scenario`: one of the compensator bench's scenarios, or both.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ScenarioChoice {
    DatasetStep,
    Fine,
    Both,
}

fn progress_bar(n: u64, what: &str) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new(n);
    b.set_style(
        indicatif::ProgressStyle::with_template(&format!("{{bar:40}} {{pos}}/{{len}} {what} {{per_sec}} eta {{eta}}"))
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    b
}

pub fn run(c: Command) -> anyhow::Result<()> {
    match c {
        Command::Compensate(a) => compensate(a),
    }
}

fn compensate(a: CompensateArgs) -> anyhow::Result<()> {
    let (mut cfg, robot) = load_setup(&a.models)?;
    if let Some(m) = a.mode {
        cfg.mode = m;
    }
    cfg.budget.budget_ns = a.budget_ns;
    // Waypoints unless a period is given: the rate limit is a speed, meaningless without time.
    match a.period_ns {
        None | Some(0) => cfg.output.rate_limit_deg_s = 0.0,
        Some(ns) => cfg.output.period_ns = ns,
    }
    if let Some(p) = &a.out {
        if p.exists() && !a.force {
            bail!("{}: exists; pass --force to overwrite it", p.display());
        }
    }
    let mut comp = Compensator::from_config(&cfg, &robot).context("building the compensator")?;
    let targets = match &a.cols {
        None => offline::read_targets_csv(&a.targets, comp.joints())?,
        Some(cols) => read_targets_named(&a.targets, &split_names(cols), comp.joints())?,
    };
    let bar = progress_bar(targets.len() as u64, "targets");
    let outs = offline::run(&mut comp, &targets, |i| bar.set_position(i as u64));
    bar.finish_and_clear();
    match &a.out {
        Some(p) => {
            let f = if a.force {
                std::fs::File::create(p)
            } else {
                std::fs::File::options().write(true).create_new(true).open(p)
            }
            .with_context(|| {
                format!(
                    "creating {}{}",
                    p.display(),
                    if a.force { "" } else { " (without --force)" }
                )
            })?;
            let mut w = std::io::BufWriter::new(f);
            offline::write_csv(&mut w, &outs).with_context(|| format!("writing {}", p.display()))?;
            w.flush().with_context(|| format!("writing {}", p.display()))?;
        }
        None => offline::write_csv(&mut std::io::stdout().lock(), &outs).context("writing to stdout")?,
    }
    let s = offline::summarize(&outs);
    eprintln!(
        "{} targets, mode {}: mean max|f(q_cmd) − q_desired| = {:.3} deg (max {:.3}), mean iterations {:.1}, \
         mean forward evaluations {:.1}, stop reasons {:?}",
        s.steps,
        comp.mode(),
        s.mean_loss_deg,
        s.max_loss_deg,
        s.mean_iterations,
        s.mean_forward_evals,
        s.stop_reasons
    );
    if let Some(line) = comp.safety_summary() {
        eprintln!("{line}");
    }
    let robot_file = a.models.robot.as_ref().map_or_else(
        || "the shipped configs/robot.toml".to_string(),
        |p| p.display().to_string(),
    );
    let names: Vec<String> = (1..=comp.joints()).map(|k| format!("q{k}")).collect();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let by_joint = s.clamps_by_joint(&names);
    eprintln!(
        "joint limits ({robot_file}): changed {} of {} rows ({:.1} %){}; the rate limit changed {}",
        s.joint_limited_rows,
        s.steps,
        100.0 * s.joint_limited_fraction(),
        if by_joint.is_empty() {
            String::new()
        } else {
            format!(": {by_joint}")
        },
        s.rate_limited_rows
    );
    if s.joint_limited_fraction() > offline::LOUD_CLAMP_FRACTION {
        eprintln!(
            "warning: the joint limits of {robot_file} changed {:.1} % of the commands ({by_joint}): these targets \
             go where that robot file says the robot cannot. If this robot can, its limits belong in its own robot \
             file (--robot); if not, the targets are not this robot's.",
            100.0 * s.joint_limited_fraction()
        );
    }
    if let Some(p) = &a.summary_json {
        let text = serde_json::to_string_pretty(&s).context("serialising the summary")?;
        std::fs::write(p, text + "\n").with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// Column names as `bowden import --cmd-cols` takes them: comma-separated, trimmed.
fn split_names(s: &str) -> Vec<String> {
    s.split(',')
        .map(|p| p.trim().to_string())
        .filter(|p| !p.is_empty())
        .collect()
}

/// Reads targets whose joint columns are `names` (q1..qJ in order, matched exactly as
/// `bowden import` matches them); errors name the file's own columns.
fn read_targets_named(path: &Path, names: &[String], joints: usize) -> anyhow::Result<Vec<Vec<f64>>> {
    if names.len() != joints {
        bail!(
            "--cols: {} names given ({}), the controller has {joints} joints (q1..q{joints} in order)",
            names.len(),
            names.join(",")
        );
    }
    for (i, n) in names.iter().enumerate() {
        if names[..i].contains(n) {
            bail!("--cols: column {n:?} is named twice");
        }
    }
    let bytes = std::fs::read(path).with_context(|| format!("{}: cannot read", path.display()))?;
    offline::parse_targets_csv(&bytes, path, names, false).context("--cols")
}

/// Whether `others` is a proper, non-empty subset of the `n` CPUs (--cpu was given).
fn a_cpu_pinned(others: &[usize], n: usize) -> bool {
    !others.is_empty() && others.len() < n
}

fn pin_to_cpu(cpu: usize) -> anyhow::Result<()> {
    // SAFETY: cpu_set_t is plain data; sched_setaffinity reads it for the calling thread.
    let rc = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set)
    };
    if rc != 0 {
        bail!(
            "--cpu {cpu}: sched_setaffinity failed: {}",
            std::io::Error::last_os_error()
        );
    }
    Ok(())
}

pub fn bench(c: BenchCommand) -> anyhow::Result<()> {
    let BenchCommand::Compensate(a) = c;
    if let Some(p) = &a.out {
        let files = ["json", "md", "svg"].map(|e| p.with_extension(e));
        super::refuse_overwrite(&files, a.force, "--out")?;
    }
    let (cfg, robot) = load_setup(&a.models)?;
    if a.steps == 0 {
        bail!("--steps must be > 0");
    }
    let scenarios = match a.scenario {
        ScenarioChoice::DatasetStep => vec![Scenario::DatasetStep],
        ScenarioChoice::Fine => vec![Scenario::Fine],
        ScenarioChoice::Both => vec![Scenario::DatasetStep, Scenario::Fine],
    };
    if !(a.fine_deg_per_step.is_finite() && a.fine_deg_per_step > 0.0) {
        bail!("--fine-deg-per-step {}: must be a positive number", a.fine_deg_per_step);
    }
    if let Some(cpu) = a.cpu {
        pin_to_cpu(cpu)?;
    }
    if let Some(prio) = a.fifo {
        match bowden_runtime::rt::set_fifo(prio) {
            bowden_runtime::rt::Outcome::Applied => {}
            o => bail!("--fifo {prio}: SCHED_FIFO {o}"),
        }
    }
    let opts = BenchOptions {
        steps: a.steps,
        naive_steps: a.naive_steps,
        seed: a.seed,
        fine_deg_per_step: a.fine_deg_per_step,
        scenarios,
        paced: a.paced,
        // The prefix worker as the node places it: on the CPUs other than --cpu, under
        // SCHED_OTHER (a thread inherits its creator's policy).
        worker_placement: (a.cpu.is_some() || a.fifo.is_some()).then(|| {
            let n = std::thread::available_parallelism().map_or(1, |n| n.get());
            let others: Vec<usize> = (0..n).filter(|&c| Some(c) != a.cpu).collect();
            let fifo = a.fifo.is_some();
            std::sync::Arc::new(move || {
                if a_cpu_pinned(&others, n) {
                    let _ = bowden_runtime::rt::pin_to_cpus(&others);
                }
                if fifo {
                    let param = libc::sched_param { sched_priority: 0 };
                    // SAFETY: plain syscall on the calling thread with a valid parameter.
                    unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) };
                }
            }) as std::sync::Arc<dyn Fn() + Send + Sync>
        }),
        config: cfg,
        probe: std::time::Duration::from_millis(a.probe_ms),
    };
    let bar = progress_bar(bench::total_steps(&opts), "steps");
    let report = bench::run(&opts, &robot, &mut |n| bar.inc(n)).context("compensator benchmark")?;
    bar.finish_and_clear();
    let json = serde_json::to_string_pretty(&report).context("serialising the report")?;
    let md = report.to_markdown();
    if let Some(p) = &a.out {
        for (ext, text) in [("json", &json), ("md", &md)] {
            let f = p.with_extension(ext);
            std::fs::write(&f, text).with_context(|| format!("writing {}", f.display()))?;
        }
        report.write_svg(&p.with_extension("svg"))?;
    }
    if a.json {
        println!("{json}");
    } else {
        println!("{md}");
    }
    Ok(())
}
