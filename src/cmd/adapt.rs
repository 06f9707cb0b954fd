//! `bowden adapt status` (what an adapt node did: generations, swaps with their held-out
//! errors, the last checks) and `bowden bench swap` (the compensator's cycle with hot model
//! swaps against its normal cycle). The adapt node itself runs in a pipeline
//! (`kind = "adapt"`, components/adapt/src/node.rs).

use anyhow::{bail, Context, Result};
use bowden_adapt::{CheckRecord, SwapRecord};
use bowden_compensator::{Compensator, Loaded, LoaderSettings, ModelLoader, StepOutput};
use bowden_interfaces::{fnv1a64, ModelUpdate};
use bowden_latency::{LatencyHistogram, Percentiles};
use bowden_runtime::alloc;
use clap::{Args, Subcommand};
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Subcommand)]
pub enum Command {
    /// Online adaptation: what an `adapt` node decided (generations, swaps, checks).
    #[command(subcommand)]
    Adapt(AdaptCommand),
}

#[derive(Subcommand)]
pub enum AdaptCommand {
    /// The state an adapt node keeps in its state directory: the generation in use, every swap
    /// with its held-out errors before and after, the last checks.
    Status(StatusArgs),
}

#[derive(Args, Debug)]
pub struct StatusArgs {
    /// The node's `state_dir`.
    #[arg(long, default_value = "out/adapt")]
    state_dir: PathBuf,
    /// Checks to list (the newest).
    #[arg(long, default_value_t = 10)]
    last: usize,
    /// Print JSON on stdout instead of the tables.
    #[arg(long)]
    json: bool,
}

#[derive(Subcommand)]
pub enum BenchCommand {
    /// The compensator's cycle with hot model swaps (models loaded and checked on the loader
    /// thread, exchanged at a cycle boundary) against its normal cycle, paced at a period, on a
    /// fine path: p50/p99/p99.9/max of both, and the allocations of the swap cycles.
    Swap(SwapArgs),
}

#[derive(Args, Debug)]
pub struct SwapArgs {
    #[command(flatten)]
    models: super::compensate::ModelArgs,
    /// Cycles to run.
    #[arg(long, default_value_t = 20_000)]
    cycles: u64,
    /// A swap is requested every N cycles.
    #[arg(long, default_value_t = 100)]
    swap_every: u64,
    /// Cycle period, µs (the pace of a 1 kHz chain).
    #[arg(long, default_value_t = 1000)]
    period_us: u64,
    /// Joint motion per cycle on the fine path, deg (0.06 = 60°/s at 1 kHz).
    #[arg(long, default_value_t = 0.06)]
    fine_deg_per_step: f64,
    /// Print JSON on stdout instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn run(c: Command) -> Result<()> {
    let Command::Adapt(AdaptCommand::Status(a)) = c;
    let state: serde_json::Value = {
        let p = a.state_dir.join("state.json");
        let text = std::fs::read_to_string(&p)
            .with_context(|| format!("{}: no adapt state here (the node's `state_dir`)", p.display()))?;
        serde_json::from_str(&text).with_context(|| format!("{}: not an adapt state", p.display()))?
    };
    let swaps: Vec<SwapRecord> = serde_json::from_value(state["swaps"].clone()).context("state.json: swaps")?;
    let log = a.state_dir.join("adapt.jsonl");
    let mut checks: Vec<CheckRecord> = Vec::new();
    if let Ok(text) = std::fs::read_to_string(&log) {
        for (i, line) in text.lines().enumerate() {
            checks.push(serde_json::from_str(line).with_context(|| format!("{}:{}", log.display(), i + 1))?);
        }
    }
    if a.json {
        let v = serde_json::json!({ "state": state, "checks": checks });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let f = |v: f64| if v.is_finite() { format!("{v:.3}") } else { "-".into() };
    println!(
        "adapt state {}: generation {} in use, {} checks, reference (held-out RMSE) {}",
        a.state_dir.display(),
        state["generation"],
        checks.len(),
        state["reference_deg"]
    );
    println!("\n| generation | tick | forward before → after [°] | inverse before → after [°] | directory |");
    println!("|---:|---:|---|---|---|");
    // A direction whose fine-tune did not validate better kept its model (hash 0 in the swap).
    let change = |hash: u64, b: f64, a: f64| {
        if hash == 0 {
            format!("kept ({} → {} not better)", f(b), f(a))
        } else {
            format!("{} → {}", f(b), f(a))
        }
    };
    for s in &swaps {
        println!(
            "| {} | {} | {} | {} | {} |",
            s.generation,
            s.tick,
            change(s.fwd_hash, s.fwd_before_deg, s.fwd_after_deg),
            change(s.inv_hash, s.inv_before_deg, s.inv_after_deg),
            s.dir.display()
        );
    }
    println!(
        "\n| tick | rows | decision | forward held-out [°] | running prediction [°] | inverse held-out [°] | message |"
    );
    println!("|---:|---:|---|---:|---:|---:|---|");
    for c in checks.iter().rev().take(a.last).rev() {
        println!(
            "| {} | {} | {:?} | {} | {} | {} | {} |",
            c.tick,
            c.rows,
            c.decision,
            f(c.fwd_holdout_deg),
            f(c.fwd_running_deg),
            f(c.inv_holdout_deg),
            c.message
        );
    }
    Ok(())
}

#[derive(serde::Serialize)]
struct Row {
    cycles: String,
    #[serde(flatten)]
    latency: Percentiles,
    system_allocs: u64,
}

fn row(name: &str, h: &LatencyHistogram, allocs: u64) -> Row {
    Row {
        cycles: name.into(),
        latency: h.percentiles(),
        system_allocs: allocs,
    }
}

/// A directory removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Result<Self> {
        let p = std::env::temp_dir().join(format!("bowden-bench-swap-{}", std::process::id()));
        std::fs::create_dir_all(&p).with_context(|| p.display().to_string())?;
        Ok(Self(p))
    }
    fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub fn bench(c: BenchCommand) -> Result<()> {
    let BenchCommand::Swap(a) = c;
    if a.cycles == 0 || a.swap_every == 0 || a.period_us == 0 {
        bail!("--cycles, --swap-every and --period-us must be positive");
    }
    let (cfg, robot) = super::compensate::load_setup(&a.models)?;
    let mut comp = Compensator::from_config(&cfg, &robot).context("loading the controller")?;
    comp.set_budget_ns(0);
    comp.set_period_ns(a.period_us * 1000);
    // One generation directory holding the controller's own files: every swap loads and checks
    // them afresh (the same weights, so the commands do not change).
    let gen = TempDir::new()?;
    let mut u = ModelUpdate::default();
    for (file, src, hash) in [
        ("fwd.onnx", &cfg.model_fwd, &mut u.fwd_hash),
        ("inv.onnx", &cfg.model_inv, &mut u.inv_hash),
    ] {
        if let Some(p) = src {
            let p = cfg.resolve_model_path("model", p)?;
            let bytes = std::fs::read(&p).with_context(|| p.display().to_string())?;
            std::fs::write(gen.path().join(file), &bytes)?;
            *hash = fnv1a64(&bytes);
        }
    }
    if !u.set_dir(&gen.path().display().to_string()) {
        bail!("the temporary directory's path is longer than 255 bytes");
    }
    let loader = ModelLoader::spawn(LoaderSettings::for_compensator(&comp, &cfg, "bench swap", false))?;
    let targets = bowden_compensator::bench::random_trajectory(&robot, a.cycles as usize + 1, a.fine_deg_per_step, 7);
    let new_h = LatencyHistogram::new;
    let (mut normal, mut advance, mut swap) = (new_h(), new_h(), new_h());
    let (mut normal_allocs, mut swap_allocs) = (0u64, 0u64);
    let mut out = StepOutput::default();
    let period = Duration::from_micros(a.period_us);
    let mut next = Instant::now() + period;
    let (mut requested, mut swapped) = (0u64, 0u64);
    for (k, q) in targets.iter().enumerate().take(a.cycles as usize) {
        let before = alloc::thread_counts();
        let t0 = Instant::now();
        // The node's cycle: step, (publish), then at the boundary take a ready swap, then the
        // next window prefix.
        let _ = comp.step(q, &mut out);
        let mut did_swap = false;
        if let Some(Loaded::Ready(mut p)) = loader.try_take() {
            did_swap = comp.swap_models(&mut p).is_ok();
            loader.retire(p);
        }
        comp.prepare();
        let ns = t0.elapsed().as_nanos() as u64;
        let d = alloc::thread_counts().since(&before).system_allocs;
        // The first 200 cycles warm caches and the allocator; not measured.
        if k >= 200 {
            if did_swap {
                swap.record(ns);
                swap_allocs += d;
                swapped += 1;
            } else {
                if out.history_appended > 0 {
                    advance.record(ns);
                }
                normal.record(ns);
                normal_allocs += d;
            }
        }
        if (k as u64 + 1).is_multiple_of(a.swap_every) && loader.request(&u) {
            u.generation += 1;
            requested += 1;
        }
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        }
        next += period;
    }
    let rows = [
        row("normal (incl. history steps)", &normal, normal_allocs),
        row("… of which a history step", &advance, 0),
        row("swap", &swap, swap_allocs),
    ];
    let ratio = rows[2].latency.p999_ns as f64 / rows[0].latency.p999_ns.max(1) as f64;
    if a.json {
        let v = serde_json::json!({
            "mode": comp.mode().to_string(), "period_us": a.period_us, "requested": requested, "swapped": swapped,
            "refused": loader.refused(), "rows": rows, "swap_p999_over_normal_p999": ratio,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!(
        "bench swap: {} cycles at {} µs, mode {}, {requested} swaps requested, {swapped} made, {} refused; cycle = step + swap (if ready) + next prefix, on this thread",
        a.cycles,
        a.period_us,
        comp.mode(),
        loader.refused()
    );
    println!("\n| cycles | n | p50 [µs] | p99 [µs] | p99.9 [µs] | max [µs] | system allocations |");
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for r in &rows {
        println!(
            "| {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {} |",
            r.cycles,
            r.latency.count,
            Percentiles::us(r.latency.p50_ns),
            Percentiles::us(r.latency.p99_ns),
            Percentiles::us(r.latency.p999_ns),
            Percentiles::us(r.latency.max_ns),
            r.system_allocs
        );
    }
    println!("\nswap-cycle p99.9 / normal-cycle p99.9 = {ratio:.2}");
    Ok(())
}
