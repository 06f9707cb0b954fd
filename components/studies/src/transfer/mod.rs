//! `bowden bench transfer` (issue #12): how well the shipped recipe transfers to robots it has
//! never seen. For each unit of several plant families it runs exactly what a user runs with a
//! new robot — `bowden collect` through the vision loop, `bowden train` with the recipe,
//! `bowden tune`, `bowden evaluate` — as subprocesses of this executable, without any per-unit
//! tuning, and reports per unit, trajectory and controller the reduction of the tip position,
//! tip orientation and joint errors against the uncalibrated robot, by vision and by truth.
//!
//! Units are split into tuning units (whatever was looked at while choosing the recipe) and
//! held-out units (the only ones the results speak for). Units run in parallel (`--jobs`), and
//! every step leaves a `UNIT/<step>.done` stamp (command, duration, hash of its inputs): a rerun
//! skips finished steps and redoes unfinished or changed ones. A step's inputs are its command
//! line, the files it reads (the unit's plant file, the pipeline's configs, the trajectories, the
//! controller configs) and the stamps of the steps before it; the `bowden` binary itself is not
//! one: after changing the code, use another `--out` (or remove the stamps).
//!
//! On a cluster scheduler the units split like a sweep's runs: `--plan` numbers the selected
//! units and fingerprints each (version, seed, recipe and the files it names, family, unit
//! plant, role), `--shard I/N` runs the units whose index ≡ I (mod N), every unit leaves
//! `UNIT/outcome.json` (written atomically, by local runs too), and `--merge` reads them back,
//! refusing missing ones and ones of another fingerprint by name, and writes the report. The merged report's results (summary,
//! never-worse checks, rows) equal a local run's; its timings, load and parallelism are not
//! one process's and are marked as merged.

use anyhow::{anyhow, bail, Context, Result};
use bowden_evaluation::metrics::reduction_pct;
use bowden_evaluation::CONTROLLERS;
use bowden_interfaces::model::one_of;
use bowden_learning::dataset::fnv1a64_hex;
use bowden_learning::spacing::DecimationRule;
use bowden_learning::sweep::{Selection, SHARDING};
use bowden_learning::{Architecture, Precision};
use bowden_trajectory::ExcitationKind;
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// What one `bowden bench transfer` run does (the command line's options, parsed).
#[derive(Debug, Clone)]
pub struct TransferOptions {
    /// The config as the user named it (for messages).
    pub config: PathBuf,
    /// The config file itself, resolved by bowden's order (docs/architecture.md §1).
    pub config_file: PathBuf,
    /// The directory the built-in configs and models were extracted to, when there is one: a
    /// config inside it makes it the project the steps run in.
    pub builtin_root: Option<PathBuf>,
    /// The `bowden` executable every step runs as a subprocess.
    pub exe: PathBuf,
    /// Output directory: transfer.md, transfer.json, transfer.svg and units/FAMILY/unit-N/.
    pub out: PathBuf,
    /// Units run at once (at least 1).
    pub jobs: usize,
    pub units: UnitSet,
    /// Only these families (names from the config); empty: all.
    pub families: Vec<String>,
    /// At most N units, taken in turn from each family.
    pub max_units: Option<usize>,
    /// The tiny test recipe ([`Recipe::quick`]).
    pub quick: bool,
    /// Print the selected units instead of running them.
    pub plan: bool,
    /// Run only shard I of N ("I/N").
    pub shard: Option<String>,
    /// Run nothing: read the units' outcome files and write the report.
    pub merge: bool,
    /// With `plan`: JSON on stdout instead of the table.
    pub json: bool,
    /// With `plan`: also write the plan JSON to this file (overwriting it: the caller decides
    /// whether an earlier one may go).
    pub json_out: Option<PathBuf>,
}

/// Which units a run selects.
#[derive(
    Clone,
    Copy,
    Debug,
    PartialEq,
    Eq,
    Serialize,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
)]
#[serde(rename_all = "kebab-case")]
#[strum(serialize_all = "kebab-case")]
pub enum UnitSet {
    /// The ones anybody may look at while choosing the recipe.
    Tuning,
    /// The only ones the results speak for.
    Heldout,
    All,
}

mod config;
mod markdown;
mod plan;
mod plot;
mod results;
mod steps;
#[cfg(test)]
mod tests;

pub use config::*;
use markdown::*;
use plan::*;
use plot::*;
use results::*;
use steps::*;

/// Runs (or plans, or merges) a transfer study.
// Long: the study's phases in order (set-up, plan, shard, run or merge, report), each a call.
pub fn transfer(a: TransferOptions) -> Result<()> {
    if a.jobs == 0 {
        bail!("--jobs must be at least 1");
    }
    let t_start = Instant::now();
    let load_average = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok());
    let Setup {
        cfg,
        config_file,
        project,
        recipe,
        base_controller,
        feedback_config,
        trajectory_sets,
        families,
    } = setup(&a)?;
    let out = absolute(&a.out);
    let plans = plan_units(&a, &families, &out)?;
    // What each unit's outcome depends on: checked by --merge, shown by --plan.
    let recipe_files = format!(
        "{}\u{1e}{}",
        read_text(&base_controller),
        feedback_config.as_deref().map(read_text).unwrap_or_default()
    );
    let fingerprints: Vec<String> = plans
        .iter()
        .map(|p| unit_fingerprint(&recipe, &recipe_files, cfg.seed, &families[p.family], p))
        .collect::<Result<_>>()?;
    if a.plan {
        return print_unit_plan(&a, &plans, &families, &fingerprints);
    }
    let selection = a
        .shard
        .as_deref()
        .map(|s| s.parse::<Selection>().map_err(anyhow::Error::msg))
        .transpose()?;
    let selected: Vec<usize> = match selection {
        Some(s) => s.indices(plans.len())?,
        None => (0..plans.len()).collect(),
    };
    if let (Some(s), true) = (selection, selected.is_empty()) {
        // A job array larger than the plan: this slot has nothing to do.
        println!("bench transfer {s}: no units (the plan has {})", plans.len());
        return Ok(());
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let jobs = a.jobs.min(selected.len());
    let threads = recipe.threads.unwrap_or((cores / jobs).max(1));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let units: Vec<UnitOutcome> = if a.merge {
        load_outcomes(&plans, &fingerprints, &recipe)?
    } else {
        let ctx = Ctx {
            exe: a.exe.clone(),
            project: project.clone(),
            recipe: recipe.clone(),
            seed: cfg.seed,
            threads,
            base_controller,
            feedback_config,
            trajectory_sets: trajectory_sets.clone(),
            config_file: config_file.clone(),
            mp: MultiProgress::new(),
        };
        let sel = Selected {
            plans: &plans,
            indices: &selected,
            fingerprints: &fingerprints,
            shard: selection,
        };
        match run_selected(&a, &ctx, &families, &sel, jobs)? {
            Some(units) => units,
            // A shard: its units' outcome files are written, the report is --merge's.
            None => return Ok(()),
        }
    };
    let held: Vec<&UnitOutcome> = units.iter().filter(|u| u.role == Role::HeldOut).collect();
    let summary = summarise(&held, &families, &recipe);
    let mut rep = Report {
        config: config_file,
        out: out.clone(),
        project_dir: project,
        quick: a.quick,
        units_selected: a.units,
        jobs,
        train_threads: threads,
        cores,
        load_average,
        seed: cfg.seed,
        recipe: recipe.clone(),
        families,
        best_mode: best_mode(&held, &recipe, false),
        best_feed_forward: best_mode(&held, &recipe, true),
        goals: goals(&held, &recipe),
        summary,
        never_worse: never_worse(&held, &recipe),
        timing: timing(&units),
        units: Vec::new(),
        merged: a.merge,
        wall_seconds: 0.0,
    };
    let (plotted, which): (Vec<&UnitOutcome>, &str) = if held.iter().any(|u| !u.rows.is_empty()) {
        (held.clone(), "held-out")
    } else {
        let t: Vec<&UnitOutcome> = units.iter().filter(|u| u.role == Role::Tuning).collect();
        if rep.best_mode.is_none() {
            rep.best_mode = best_mode(&t, &recipe, false);
        }
        (t, "tuning (no held-out results)")
    };
    let svg = out.join("transfer.svg");
    plot(&svg, &rep, &plotted, which)?;
    let n_failed = units.iter().filter(|u| u.failure.is_some()).count();
    let failed_names: Vec<String> = units
        .iter()
        .filter_map(|u| {
            u.failure
                .as_ref()
                .map(|f| format!("{}/unit-{} at {}", u.family, u.unit, f.step))
        })
        .collect();
    rep.wall_seconds = if a.merge {
        units.iter().map(|u| u.wall_seconds).sum()
    } else {
        t_start.elapsed().as_secs_f64()
    };
    rep.units = units;
    let md = markdown(&rep);
    write_atomic(&out.join("transfer.md"), &md)?;
    write_atomic(&out.join("transfer.json"), &serde_json::to_string_pretty(&rep)?)?;
    println!("{md}");
    eprintln!(
        "wrote {0}/transfer.md, {0}/transfer.json, {0}/transfer.svg",
        out.display()
    );
    if n_failed > 0 {
        bail!(
            "{n_failed} of {} unit(s) failed ({}); the report lists them",
            rep.units.len(),
            failed_names.join(", ")
        );
    }
    Ok(())
}

/// What a run works with, found and checked before any unit is planned.
struct Setup {
    cfg: TransferConfig,
    config_file: PathBuf,
    /// The directory the user's commands run in (their default `configs/...` paths).
    project: PathBuf,
    recipe: Recipe,
    base_controller: PathBuf,
    feedback_config: Option<PathBuf>,
    trajectory_sets: Vec<(String, PathBuf)>,
    families: Vec<Family>,
}

/// Reads and checks the config, the recipe's files and the families (`--families` included).
fn setup(a: &TransferOptions) -> Result<Setup> {
    // The config by bowden's resolution order (docs/architecture.md §1): the shipped one is found
    // outside a checkout too, and then the built-in copy is the project the steps run in.
    let config_file = absolute(&a.config_file);
    let text = std::fs::read_to_string(&config_file).with_context(|| format!("reading {}", a.config.display()))?;
    let cfg: TransferConfig = toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", a.config.display()))?;
    cfg.validate().map_err(|e| anyhow!("{}: {e}", a.config.display()))?;
    let cfg_dir = config_file.parent().map(Path::to_path_buf).unwrap_or_default();
    let root = find_root(&cfg_dir).or_else(|| {
        a.builtin_root
            .as_deref()
            .filter(|b| cfg_dir.starts_with(b))
            .map(Path::to_path_buf)
    });
    // The directory the user's commands run in (their default `configs/...` paths).
    let project = root
        .clone()
        .or_else(|| std::env::current_dir().ok().as_deref().and_then(find_root))
        .unwrap_or_else(|| absolute(Path::new(".")));
    let recipe = if a.quick {
        cfg.recipe.quick()
    } else {
        cfg.recipe.clone()
    };
    let base_controller = resolve(&recipe.base_controller, &cfg_dir, root.as_deref());
    if !base_controller.is_file() {
        bail!(
            "{}: recipe.base_controller: no file {} (relative paths resolve against the config's directory, \
             the repository root, then the working directory)",
            a.config.display(),
            recipe.base_controller.display()
        );
    }
    let feedback_config = match &recipe.feedback {
        None => None,
        Some(f) => {
            let p = resolve(&f.config, &cfg_dir, root.as_deref());
            feedback_table(&p).with_context(|| format!("{}: recipe.feedback.config", a.config.display()))?;
            Some(p)
        }
    };
    for t in &recipe.trajectories {
        let f = project.join("configs/trajectories").join(format!("{t}.toml"));
        if !f.is_file() {
            bail!(
                "{}: recipe.trajectories: no trajectory `{t}` ({})",
                a.config.display(),
                f.display()
            );
        }
    }
    let mut trajectory_sets = Vec::new();
    for (name, dir) in &recipe.trajectory_sets {
        let d = resolve(dir, &cfg_dir, root.as_deref());
        for t in &recipe.trajectories {
            let f = d.join(format!("{t}.toml"));
            if !f.is_file() {
                bail!(
                    "{}: recipe.trajectory_sets.{name}: no trajectory `{t}` ({})",
                    a.config.display(),
                    f.display()
                );
            }
        }
        trajectory_sets.push((name.clone(), d));
    }
    // Families, named.
    let mut families = Vec::new();
    for (i, f) in cfg.families.iter().enumerate() {
        let plant = resolve(&f.plant, &cfg_dir, root.as_deref());
        let model = plant_family_label(&plant).unwrap_or_else(|| file_stem(&plant));
        let name = f.name.clone().unwrap_or_else(|| model.clone());
        if !path_safe(&name) {
            bail!(
                "{}: family[{i}].name: `{name}` (from the plant file) cannot name a directory: give `name`",
                a.config.display()
            );
        }
        if families.iter().any(|x: &Family| x.name == name) {
            bail!("{}: family[{i}].name: `{name}` appears twice", a.config.display());
        }
        families.push(Family {
            name,
            model,
            plant,
            tuning_units: f.tuning_units.clone(),
            heldout_units: f.heldout_units.clone(),
        });
    }
    for f in &a.families {
        if !families.iter().any(|x| &x.name == f) {
            bail!(
                "--families: no family `{f}` in {} (it has {})",
                a.config.display(),
                families.iter().map(|x| x.name.as_str()).collect::<Vec<_>>().join(", ")
            );
        }
    }
    Ok(Setup {
        cfg,
        config_file,
        project,
        recipe,
        base_controller,
        feedback_config,
        trajectory_sets,
        families,
    })
}

/// The selected units (`--units`, `--families`, `--max-units`), taken in turn from each family
/// so `--max-units` covers the families; every one's plant file must exist.
fn plan_units(a: &TransferOptions, families: &[Family], out: &Path) -> Result<Vec<UnitPlan>> {
    // Units, taken in turn from each family (so --max-units covers the families).
    let mut queues: Vec<Vec<UnitPlan>> = Vec::new();
    for (fi, f) in families.iter().enumerate() {
        if !a.families.is_empty() && !a.families.contains(&f.name) {
            continue;
        }
        let mut q = Vec::new();
        let want = |r: Role| match a.units {
            UnitSet::All => true,
            UnitSet::Tuning => r == Role::Tuning,
            UnitSet::Heldout => r == Role::HeldOut,
        };
        for (role, list) in [(Role::HeldOut, &f.heldout_units), (Role::Tuning, &f.tuning_units)] {
            if want(role) {
                for &u in list {
                    q.push(UnitPlan {
                        family: fi,
                        unit: u,
                        role,
                        dir: out.join("units").join(&f.name).join(format!("unit-{u}")),
                    });
                }
            }
        }
        queues.push(q);
    }
    let mut plans = Vec::new();
    for k in 0.. {
        let before = plans.len();
        for q in &queues {
            if let Some(p) = q.get(k) {
                plans.push(p.clone());
            }
        }
        if plans.len() == before {
            break;
        }
    }
    if let Some(m) = a.max_units {
        plans.truncate(m);
    }
    if plans.is_empty() {
        bail!("no units selected (--units, --families, --max-units)");
    }
    for p in &plans {
        let f = &families[p.family];
        if !f.plant.is_file() {
            bail!(
                "{}: family[{}] ({}).plant: no file {} (relative paths resolve against the config's directory, \
                 the repository root, then the working directory); leave the family out with --families",
                a.config.display(),
                p.family,
                f.name,
                f.plant.display()
            );
        }
    }
    Ok(plans)
}

/// The units one run makes (all selected, or a shard's).
struct Selected<'a> {
    plans: &'a [UnitPlan],
    /// Indices into `plans` of the units to run.
    indices: &'a [usize],
    fingerprints: &'a [String],
    shard: Option<Selection>,
}

/// Runs the selected units, `jobs` at once, and leaves each one's outcome file beside its
/// stamps. A shard prints what it did and returns `None`: the report is `--merge`'s.
// Long: the parallel run of the units with its progress display and the outcome files, which share the threads' state.
fn run_selected(
    a: &TransferOptions,
    ctx: &Ctx,
    families: &[Family],
    sel: &Selected<'_>,
    jobs: usize,
) -> Result<Option<Vec<UnitOutcome>>> {
    if ctx.recipe.tune {
        let o = std::process::Command::new(&ctx.exe)
            .args(["tune", "--help"])
            .stdin(Stdio::null())
            .output()
            .context("running bowden tune --help")?;
        if !o.status.success() {
            let err = String::from_utf8_lossy(&o.stderr);
            if err.contains("unrecognized subcommand") {
                bail!(
                    "{}: recipe.tune = true but this bowden has no `tune` subcommand: set `recipe.tune = false`",
                    a.config.display()
                );
            }
            bail!("bowden tune --help failed ({}): {}", o.status, err.trim());
        }
    }
    eprintln!(
        "bench transfer: {} unit(s), {} at once, into {}",
        sel.indices.len(),
        jobs,
        absolute(&a.out).display()
    );
    let overall = ctx.mp.add(ProgressBar::new(sel.indices.len() as u64));
    overall.set_style(
        ProgressStyle::with_template("units [{bar:30}] {pos}/{len}  {elapsed_precise}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let next = AtomicUsize::new(0);
    let outcomes: Mutex<Vec<Option<UnitOutcome>>> = Mutex::new(vec![None; sel.indices.len()]);
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(plan) = sel.indices.get(i).map(|&k| &sel.plans[k]) else {
                    break;
                };
                let label = format!("{}/unit-{}", families[plan.family].name, plan.unit);
                let bar = ctx.mp.insert_before(&overall, ProgressBar::new_spinner());
                bar.set_style(
                    ProgressStyle::with_template("{spinner} {prefix:32} {msg:28} {elapsed}")
                        .unwrap_or_else(|_| ProgressStyle::default_spinner()),
                );
                bar.set_prefix(label.clone());
                bar.enable_steady_tick(Duration::from_millis(250));
                let o = run_unit(ctx, families, plan, &bar);
                bar.finish_and_clear();
                ctx.mp.remove(&bar);
                ctx.mp.suspend(|| match &o.failure {
                    None => eprintln!("{label}: done in {:.0} s", o.wall_seconds),
                    Some(f) => eprintln!(
                        "{label}: FAILED at step {} ({}){}{}{}",
                        f.step,
                        f.status,
                        f.hint.as_ref().map(|h| format!(": {h}")).unwrap_or_default(),
                        f.log
                            .as_ref()
                            .map(|l| format!("; log {}", l.display()))
                            .unwrap_or_default(),
                        if f.log_tail.is_empty() {
                            String::new()
                        } else {
                            format!("\n    {}", f.log_tail.join("\n    "))
                        }
                    ),
                });
                if let Ok(mut v) = outcomes.lock() {
                    v[i] = Some(o);
                }
                overall.inc(1);
            });
        }
    });
    overall.finish_and_clear();
    let units: Vec<UnitOutcome> = outcomes
        .into_inner()
        .map_err(|_| anyhow!("a unit's thread panicked"))?
        .into_iter()
        .flatten()
        .collect();
    if units.len() != sel.indices.len() {
        bail!(
            "{} of {} units did not report (a thread panicked)",
            sel.indices.len() - units.len(),
            sel.indices.len()
        );
    }
    // Every unit's outcome beside its stamps, for --merge (a shard's units, or a local run's).
    for (&k, u) in sel.indices.iter().zip(&units) {
        let file = OutcomeFile {
            format: OUTCOME_FORMAT.into(),
            fingerprint: sel.fingerprints[k].clone(),
            outcome: u.clone(),
        };
        std::fs::create_dir_all(&sel.plans[k].dir)
            .with_context(|| format!("creating {}", sel.plans[k].dir.display()))?;
        write_atomic(&outcome_path(&sel.plans[k]), &serde_json::to_string_pretty(&file)?)?;
    }
    if let Some(s) = sel.shard {
        for (&k, u) in sel.indices.iter().zip(&units) {
            println!(
                "unit {k} {}/unit-{}: {}; {}",
                u.family,
                u.unit,
                match &u.failure {
                    None => "ok".to_string(),
                    Some(f) => format!("FAILED at step {}", f.step),
                },
                outcome_path(&sel.plans[k]).display()
            );
        }
        let failed = units.iter().filter(|u| u.failure.is_some()).count();
        if failed > 0 {
            bail!(
                "bench transfer {s}: {failed} of {} unit(s) failed; their outcome files record it",
                units.len()
            );
        }
        println!(
            "bench transfer {s}: {} of {} units done; when every shard has finished: bench transfer ... --merge",
            units.len(),
            sel.plans.len()
        );
        return Ok(None);
    }
    Ok(Some(units))
}
