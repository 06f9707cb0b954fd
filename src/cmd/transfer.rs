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
use clap::{Args, Subcommand};
use indicatif::{MultiProgress, ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

#[derive(Subcommand)]
pub enum BenchCommand {
    /// Transfer to unseen units (issue #12): collect, train, tune and evaluate each unit of
    /// several plant families exactly as a user would (the `bowden` commands, as subprocesses;
    /// parallel, resumable), then the error reduction per unit, trajectory and controller, by
    /// vision and truth, as Markdown, JSON and SVG.
    Transfer(TransferArgs),
}

#[derive(Args, Debug)]
pub struct TransferArgs {
    /// Families, units and the recipe.
    #[arg(long, default_value = "configs/transfer.toml")]
    pub config: PathBuf,
    /// Output directory: transfer.md, transfer.json, transfer.svg and units/FAMILY/unit-N/.
    #[arg(long, default_value = "out/transfer")]
    pub out: PathBuf,
    /// Units run at once. collect and evaluate are lockstep pipelines that keep less than one
    /// core busy (measured CPU/wall ≈ 0.7), so two units overlap well on 2 cores (two small
    /// units: 107 s at --jobs 2, 207 s at --jobs 1); each training gets cores / jobs threads
    /// (recipe.threads overrides).
    #[arg(long, default_value_t = 2)]
    pub jobs: usize,
    /// Which units to run: the held-out ones (the results), the tuning ones, or all.
    #[arg(long, value_enum, ignore_case = true, default_value_t = UnitSet::Heldout)]
    pub units: UnitSet,
    /// Only these families (names from the config, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub families: Vec<String>,
    /// At most N units, taken in turn from each family.
    #[arg(long)]
    pub max_units: Option<usize>,
    /// A tiny recipe for tests: 30 configurations, 2 epochs, L = 10, 1 repeat, 8 points per
    /// trajectory. Its numbers say nothing about transfer; use another --out.
    #[arg(long)]
    pub quick: bool,
    /// Print the selected units instead of running them: index, unit, role, directory,
    /// fingerprint (recipe and the controller files it names, seed, unit plant, version) and
    /// status in --out; --json for JSON.
    #[arg(long, conflicts_with_all = ["shard", "merge"])]
    pub plan: bool,
    /// Run only shard I of N of the selected units: those whose index (see --plan) ≡ I (mod N),
    /// e.g. "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT"; each unit leaves UNIT/outcome.json,
    /// no report is written (see --merge). Exits non-zero if one of its units failed.
    #[arg(long, value_name = "I/N", conflicts_with = "merge")]
    pub shard: Option<String>,
    /// Run nothing: read every selected unit's outcome.json (refusing missing ones and ones of
    /// another config, by name) and write transfer.md, transfer.json and transfer.svg.
    #[arg(long)]
    pub merge: bool,
    /// With --plan: print the plan as JSON on stdout instead of the table.
    #[arg(long, requires = "plan")]
    pub json: bool,
    /// With --plan: also write the plan JSON to FILE.
    #[arg(long, value_name = "FILE", requires = "plan")]
    pub json_out: Option<PathBuf>,
    /// Overwrite --json-out if it exists.
    #[arg(long)]
    pub force: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum UnitSet {
    Tuning,
    Heldout,
    All,
}

pub fn bench(c: BenchCommand) -> Result<()> {
    match c {
        BenchCommand::Transfer(a) => transfer(a),
    }
}

// ---------------------------------------------------------------------------------------------
// Configuration

/// `configs/transfer.toml`.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TransferConfig {
    /// Seed of every unit's `collect` (a user types the same command for every robot).
    pub seed: u64,
    pub recipe: Recipe,
    #[serde(rename = "family")]
    pub families: Vec<FamilySpec>,
}

/// What a user runs with a new robot, the same for every unit.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    /// `collect --samples`: random configurations of eq. (16).
    pub samples: usize,
    /// `collect --excitation`: paper | mixed.
    pub excitation: ExcitationKind,
    /// `train --arch` for each (both directions each).
    pub archs: Vec<String>,
    /// Forward models trained only to judge `tune`'s candidates (`tune --judge`), never sent
    /// commands: a model judging its own refinement rates newton at μ = 0 best because that is
    /// what it minimises. An architecture that is also a forward candidate (`archs`,
    /// `forward_archs`) is trained a second time for judging, with `judge_seed`
    /// (`ARCH_forward_judge_L{L}.onnx`), so no candidate is rated by itself.
    #[serde(default)]
    pub judge_archs: Vec<String>,
    /// `train --seed` of a judge whose architecture is also a forward candidate (default 1; the
    /// candidates train with seed 0).
    #[serde(default = "default_judge_seed")]
    pub judge_seed: u64,
    /// Forward models trained as further controller candidates beside `archs`' pairs: `tune`
    /// pairs each with every inverse model and keeps what its judges rate best (e.g. an LSTM
    /// forward model; how the architectures compare: docs/results/data-study/). An architecture
    /// here must not be in `archs`.
    #[serde(default)]
    pub forward_archs: Vec<String>,
    /// Inverse models trained as further controller candidates beside `archs`' pairs: `tune`
    /// pairs each with every forward model of `archs` and keeps what validates best (e.g. the
    /// LSTM inverse of the accurate controller). An architecture here must not be in `archs`.
    #[serde(default)]
    pub inverse_archs: Vec<String>,
    /// `train --epochs`.
    pub epochs: usize,
    /// `train --early-stop`.
    #[serde(default)]
    pub early_stop: Option<usize>,
    /// `train --seq-len`.
    pub seq_len: usize,
    /// `train --decimation` of every model: `"auto"` (the default, as `train`'s: decimated
    /// histories on single-step data such as eq. (16)'s, consecutive samples otherwise) or a
    /// whole number (1 = consecutive samples only, the paper).
    #[serde(default)]
    pub decimation: DecimationRule,
    /// Per-architecture `epochs` / `early_stop` replacing the two above for that architecture
    /// (an LSTM epoch costs about 25 TCN epochs, and the LSTM inverse overfits after ~15).
    #[serde(default)]
    pub per_arch: std::collections::BTreeMap<String, ArchTraining>,
    /// `train --threads` (default: the machine's cores / --jobs); results do not depend on it.
    #[serde(default)]
    pub threads: Option<usize>,
    /// `evaluate --repeats`.
    pub repeats: u32,
    /// `evaluate --trajectories`.
    pub trajectories: Vec<String>,
    /// Further sets of the same trajectory names, each a directory (`evaluate
    /// --trajectories-dir`), e.g. `large = "configs/trajectories/large"`: the paths at the
    /// paper's magnitude. Each is evaluated beside the shipped paths (with and without feedback)
    /// and reported as controllers `paper@NAME`, `newton+fb@NAME`, ..., with goals of their own.
    #[serde(default, skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub trajectory_sets: std::collections::BTreeMap<String, PathBuf>,
    /// `evaluate --controllers` (must include uncalibrated: the reference of every reduction).
    pub controllers: Vec<String>,
    /// `evaluate --max-points`.
    #[serde(default)]
    pub max_points: Option<usize>,
    /// Run `bowden tune` (true) or use the base controller with the first trained pair (false).
    pub tune: bool,
    /// `tune --base`: the controller config the unit's is made from.
    pub base_controller: PathBuf,
    /// Vision feedback on top of the unit's tuned controller (docs/architecture.md, "Vision
    /// feedback"): evaluated a second time with it, as controllers `paper+fb`, `newton+fb`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub feedback: Option<FeedbackRecipe>,
    /// A second collection round under the compensator the first round made (`collect
    /// --controller-config --extend`), then every model trained and tuned again on the whole.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub closed_loop: Option<ClosedLoopRecipe>,
}

/// What a trained model is for in `tune`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ModelRole {
    /// A forward model the controller may use (`tune --forward`).
    Forward,
    /// `tune --inverse`.
    Inverse,
    /// Rates the candidates only (`tune --judge`).
    Judge,
}

/// One `bowden train` of a unit's recipe.
#[derive(Debug, Clone, PartialEq, Eq)]
struct TrainJob {
    arch: String,
    direction: &'static str,
    role: ModelRole,
    /// `train --seed` (None: its default, 0).
    seed: Option<u64>,
    /// The model's file name in the unit's models directory.
    file: String,
    /// The step's name after `train-` (round suffix apart).
    step: String,
}

fn default_judge_seed() -> u64 {
    1
}

/// `[recipe.closed_loop]`: what the second, compensated collection round records.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ClosedLoopRecipe {
    /// `collect --samples`: random configurations, now targets of the compensator.
    pub samples: usize,
    /// `collect --excitation` of the targets: paper | mixed.
    pub excitation: ExcitationKind,
}

/// `[recipe.feedback]`: the same `[feedback]` settings for every unit, added to the controller
/// `tune` chose for it.
#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FeedbackRecipe {
    /// A controller file whose `[feedback]` table is added to each unit's controller (its other
    /// settings are not used).
    pub config: PathBuf,
    /// `evaluate --camera-fps`: frames during each held point for the feedback to act on.
    pub camera_fps: f64,
}

/// The name of controller `c` with vision feedback on.
fn fb_name(c: &str) -> String {
    format!("{c}+fb")
}

/// `[recipe.per_arch.ARCH]`: what differs for one architecture.
#[derive(Debug, Clone, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ArchTraining {
    #[serde(default)]
    pub epochs: Option<usize>,
    #[serde(default)]
    pub early_stop: Option<usize>,
    /// `train --precision` for this architecture ("f32", the default, or "bf16": mixed
    /// precision for an LSTM's recurrent products, about a quarter faster per epoch).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub precision: Option<Precision>,
}

#[derive(Debug, Clone, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FamilySpec {
    /// Name in the report and the output directory (default: the plant file's `family`, else
    /// its file stem).
    #[serde(default)]
    pub name: Option<String>,
    /// The family's plant file; each unit is it with `[variation] unit = N`.
    pub plant: PathBuf,
    /// Units looked at while choosing the recipe: never reported as results.
    #[serde(default)]
    pub tuning_units: Vec<u64>,
    /// Units the results are reported on.
    #[serde(default)]
    pub heldout_units: Vec<u64>,
}

fn path_safe(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.')
        && s != "."
        && s != ".."
}

impl TransferConfig {
    fn validate(&self) -> std::result::Result<(), String> {
        let r = &self.recipe;
        if r.samples < 2 {
            return Err(format!(
                "recipe.samples: need at least 2 random configurations, got {}",
                r.samples
            ));
        }
        if let Some(cl) = &r.closed_loop {
            if cl.samples < 2 {
                return Err(format!(
                    "recipe.closed_loop.samples: need at least 2 random configurations, got {}",
                    cl.samples
                ));
            }
        }
        if r.archs.is_empty() {
            return Err("recipe.archs: name at least one architecture".into());
        }
        for (i, a) in r.archs.iter().enumerate() {
            a.parse::<Architecture>()
                .map_err(|_| format!("recipe.archs[{i}]: {a:?} is not one of {}", one_of::<Architecture>()))?;
            if r.archs[..i].contains(a) {
                return Err(format!("recipe.archs: `{a}` appears twice"));
            }
        }
        if r.epochs == 0 {
            return Err("recipe.epochs: must be at least 1".into());
        }
        if r.early_stop == Some(0) {
            return Err("recipe.early_stop: must be at least 1 (or left out)".into());
        }
        for (i, a) in r.judge_archs.iter().enumerate() {
            a.parse::<Architecture>().map_err(|_| {
                format!(
                    "recipe.judge_archs[{i}]: {a:?} is not one of {}",
                    one_of::<Architecture>()
                )
            })?;
            if r.judge_archs[..i].contains(a) {
                return Err(format!("recipe.judge_archs: `{a}` appears twice"));
            }
        }
        for (field, list) in [("inverse_archs", &r.inverse_archs), ("forward_archs", &r.forward_archs)] {
            for (i, a) in list.iter().enumerate() {
                a.parse::<Architecture>()
                    .map_err(|_| format!("recipe.{field}[{i}]: {a:?} is not one of {}", one_of::<Architecture>()))?;
                if list[..i].contains(a) {
                    return Err(format!("recipe.{field}: `{a}` appears twice"));
                }
                if r.archs.contains(a) {
                    return Err(format!(
                        "recipe.{field}: `{a}` is in recipe.archs already (trained in both directions)"
                    ));
                }
            }
        }
        if r.judge_seed == 0 && r.judge_archs.iter().any(|a| r.is_forward_candidate(a)) {
            return Err(
                "recipe.judge_seed: 0 is the candidates' own seed, so a judge of a candidate's \
                 architecture would be that candidate (same data, same seed, same weights); use \
                 another"
                    .into(),
            );
        }
        for (arch, o) in &r.per_arch {
            if !r.archs.contains(arch)
                && !r.judge_archs.contains(arch)
                && !r.inverse_archs.contains(arch)
                && !r.forward_archs.contains(arch)
            {
                return Err(format!(
                    "recipe.per_arch.{arch}: not one of recipe.archs {:?}, recipe.judge_archs {:?}, recipe.inverse_archs {:?} or recipe.forward_archs {:?}",
                    r.archs, r.judge_archs, r.inverse_archs, r.forward_archs
                ));
            }
            if o.epochs == Some(0) || o.early_stop == Some(0) {
                return Err(format!(
                    "recipe.per_arch.{arch}: epochs and early_stop must be at least 1"
                ));
            }
        }
        if r.seq_len == 0 {
            return Err("recipe.seq_len: must be at least 1".into());
        }
        if r.threads == Some(0) {
            return Err("recipe.threads: must be at least 1 (or left out)".into());
        }
        if r.repeats == 0 {
            return Err("recipe.repeats: must be at least 1".into());
        }
        if r.max_points == Some(0) {
            return Err("recipe.max_points: must be at least 1 (or left out)".into());
        }
        if r.trajectories.is_empty() {
            return Err("recipe.trajectories: name at least one trajectory".into());
        }
        for t in &r.trajectories {
            if !path_safe(t) {
                return Err(format!("recipe.trajectories: `{t}` is not a trajectory name"));
            }
        }
        for name in r.trajectory_sets.keys() {
            if !path_safe(name) {
                return Err(format!(
                    "recipe.trajectory_sets: `{name}` (use letters, digits, `-`, `_`, `.`: it names a directory)"
                ));
            }
        }
        for c in &r.controllers {
            if !CONTROLLERS.contains(&c.as_str()) {
                return Err(format!(
                    "recipe.controllers: unknown controller `{c}` (expected {})",
                    CONTROLLERS.join(", ")
                ));
            }
        }
        if !r.controllers.iter().any(|c| c == "uncalibrated") {
            return Err("recipe.controllers: must include uncalibrated (every reduction is against it)".into());
        }
        if !r.controllers.iter().any(|c| c != "uncalibrated") {
            return Err("recipe.controllers: name at least one calibrated controller (paper, newton)".into());
        }
        if let Some(f) = &r.feedback {
            if !(f.camera_fps.is_finite() && f.camera_fps > 0.0) {
                return Err(format!(
                    "recipe.feedback.camera_fps: must be a positive frame rate, got {}",
                    f.camera_fps
                ));
            }
        }
        if self.families.is_empty() {
            return Err("family: give at least one [[family]]".into());
        }
        for (i, f) in self.families.iter().enumerate() {
            if let Some(n) = &f.name {
                if !path_safe(n) {
                    return Err(format!(
                        "family[{i}].name: `{n}` (use letters, digits, `-`, `_`: it names a directory)"
                    ));
                }
            }
            if f.tuning_units.is_empty() && f.heldout_units.is_empty() {
                return Err(format!("family[{i}]: give tuning_units or heldout_units"));
            }
            for (field, list) in [("tuning_units", &f.tuning_units), ("heldout_units", &f.heldout_units)] {
                for (k, u) in list.iter().enumerate() {
                    if *u > i64::MAX as u64 {
                        return Err(format!("family[{i}].{field}: unit {u} does not fit a TOML integer"));
                    }
                    if list[..k].contains(u) {
                        return Err(format!("family[{i}].{field}: unit {u} appears twice"));
                    }
                }
            }
            if let Some(u) = f.tuning_units.iter().find(|u| f.heldout_units.contains(u)) {
                return Err(format!(
                    "family[{i}].heldout_units: unit {u} is also a tuning unit (a held-out unit must be unseen)"
                ));
            }
        }
        Ok(())
    }
}

impl Recipe {
    /// `train --epochs` and `--early-stop` for `arch`.
    fn training(&self, arch: &str) -> (usize, Option<usize>) {
        match self.per_arch.get(arch) {
            Some(o) => (o.epochs.unwrap_or(self.epochs), o.early_stop.or(self.early_stop)),
            None => (self.epochs, self.early_stop),
        }
    }

    /// `train --precision` for `arch` (f32 unless its `per_arch` table says otherwise).
    fn precision(&self, arch: &str) -> Precision {
        self.per_arch.get(arch).and_then(|o| o.precision).unwrap_or_default()
    }

    /// Every model the recipe trains, in order: each of `archs` forward and inverse, then
    /// `forward_archs`, the judges, `inverse_archs`. A judge of an architecture that is also a
    /// forward candidate is a second training with `judge_seed`, in a file of its own.
    fn training_jobs(&self) -> Vec<TrainJob> {
        let l = self.seq_len;
        let job = |arch: &String, direction: &'static str, role: ModelRole, judge_copy: bool| {
            let suffix = if judge_copy { "-judge" } else { "" };
            TrainJob {
                arch: arch.clone(),
                direction,
                role,
                seed: judge_copy.then_some(self.judge_seed),
                file: format!("{arch}_{direction}{}_L{l}.onnx", suffix.replace('-', "_")),
                step: format!("{arch}-{direction}{suffix}"),
            }
        };
        let mut jobs = Vec::new();
        for a in &self.archs {
            jobs.push(job(a, "forward", ModelRole::Forward, false));
            jobs.push(job(a, "inverse", ModelRole::Inverse, false));
        }
        jobs.extend(
            self.forward_archs
                .iter()
                .map(|a| job(a, "forward", ModelRole::Forward, false)),
        );
        jobs.extend(
            self.judge_archs
                .iter()
                .map(|a| job(a, "forward", ModelRole::Judge, self.is_forward_candidate(a))),
        );
        jobs.extend(
            self.inverse_archs
                .iter()
                .map(|a| job(a, "inverse", ModelRole::Inverse, false)),
        );
        jobs
    }

    /// True when `arch` is trained as a forward model the controller may use.
    fn is_forward_candidate(&self, arch: &str) -> bool {
        self.archs.iter().chain(&self.forward_archs).any(|a| a == arch)
    }

    /// The `bowden train` arguments of one model of the recipe (`seed`: `train --seed`, left
    /// to its default 0 when `None`, so the steps of recipes without judges' seeds keep their
    /// stamps).
    fn train_args(
        &self,
        arch: &str,
        direction: &str,
        seed: Option<u64>,
        threads: usize,
        data: &Path,
        model: &Path,
    ) -> Vec<String> {
        let (epochs, early_stop) = self.training(arch);
        let mut args: Vec<String> = vec![
            "train".into(),
            "--arch".into(),
            arch.into(),
            "--direction".into(),
            direction.into(),
            "--seq-len".into(),
            self.seq_len.to_string(),
            "--epochs".into(),
            epochs.to_string(),
        ];
        if let Some(e) = early_stop {
            args.extend(["--early-stop".into(), e.to_string()]);
        }
        if let Some(seed) = seed {
            args.extend(["--seed".into(), seed.to_string()]);
        }
        args.extend(["--decimation".into(), self.decimation.to_string()]);
        // f32 is not passed, so the steps of a recipe without the key keep their stamps.
        let precision = self.precision(arch);
        if precision != Precision::F32 {
            args.extend(["--precision".into(), precision.as_str().into()]);
        }
        args.extend([
            "--threads".into(),
            threads.to_string(),
            "--data".into(),
            data.display().to_string(),
            "--out".into(),
            model.display().to_string(),
        ]);
        args
    }

    /// The `--quick` recipe: every step runs, cheaply.
    fn quick(&self) -> Recipe {
        Recipe {
            samples: 30,
            epochs: 2,
            early_stop: None,
            per_arch: Default::default(),
            seq_len: 10,
            repeats: 1,
            max_points: Some(8),
            closed_loop: self.closed_loop.as_ref().map(|cl| ClosedLoopRecipe {
                samples: 20,
                ..cl.clone()
            }),
            ..self.clone()
        }
    }
}

/// The ancestor of `start` (inclusive) holding a `Cargo.toml`.
fn find_root(start: &Path) -> Option<PathBuf> {
    start
        .ancestors()
        .find(|d| d.join("Cargo.toml").is_file())
        .map(Path::to_path_buf)
}

fn absolute(p: &Path) -> PathBuf {
    if p.is_absolute() {
        p.to_path_buf()
    } else {
        std::env::current_dir()
            .map(|d| d.join(p))
            .unwrap_or_else(|_| p.to_path_buf())
    }
}

/// Relative paths: against the config file's directory, then the repository root, then the
/// working directory (the first that exists; else the config file's directory).
fn resolve(p: &Path, cfg_dir: &Path, root: Option<&Path>) -> PathBuf {
    if p.is_absolute() {
        return p.to_path_buf();
    }
    let mut candidates = vec![cfg_dir.join(p)];
    if let Some(r) = root {
        candidates.push(r.join(p));
    }
    candidates.push(absolute(p));
    // Nothing there: name it under the repository root, where `configs/...` paths live.
    let fallback = if root.is_some() { &candidates[1] } else { &candidates[0] };
    let hit = candidates.iter().find(|c| c.exists()).unwrap_or(fallback);
    std::fs::canonicalize(hit).unwrap_or_else(|_| hit.clone())
}

/// The family's display name in the plant file: `family = "..."` or `[family] name = "..."`.
fn plant_family_label(plant: &Path) -> Option<String> {
    let v: toml::Table = toml::from_str(&std::fs::read_to_string(plant).ok()?).ok()?;
    match v.get("family")? {
        toml::Value::String(s) => Some(s.clone()),
        toml::Value::Table(t) => t.get("name")?.as_str().map(str::to_string),
        _ => None,
    }
}

fn file_stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "plant".into())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum Role {
    Tuning,
    HeldOut,
}

impl Role {
    fn label(self) -> &'static str {
        match self {
            Role::Tuning => "tuning",
            Role::HeldOut => "held-out",
        }
    }
}

/// One family as resolved for this run.
#[derive(Debug, Clone, Serialize)]
struct Family {
    name: String,
    /// The plant file's own family label (or its file stem).
    model: String,
    plant: PathBuf,
    tuning_units: Vec<u64>,
    heldout_units: Vec<u64>,
}

/// One unit to run.
#[derive(Debug, Clone)]
struct UnitPlan {
    family: usize,
    unit: u64,
    role: Role,
    dir: PathBuf,
}

// ---------------------------------------------------------------------------------------------
// Steps, stamps, subprocesses

/// `UNIT/<step>.done`.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Stamp {
    step: String,
    command: String,
    inputs_hash: String,
    /// Wall time.
    seconds: f64,
    /// CPU time (user + system) of the subprocess and the children it waited for.
    #[serde(default)]
    cpu_seconds: f64,
    finished_unix_ms: u128,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
enum StepStatus {
    Ran,
    Skipped,
    Failed,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct StepRecord {
    step: String,
    status: StepStatus,
    /// Wall and CPU time of this run, or (skipped) of the run that made the stamp.
    seconds: f64,
    cpu_seconds: f64,
    command: String,
    log: Option<PathBuf>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Failure {
    step: String,
    status: String,
    log: Option<PathBuf>,
    log_tail: Vec<String>,
    hint: Option<String>,
}

/// What runs the step: a `bowden` subcommand, or an edit done here.
enum Action<'a> {
    Exe(Vec<String>),
    Local(String, Box<dyn FnOnce() -> Result<()> + 'a>),
}

struct Ctx {
    exe: PathBuf,
    project: PathBuf,
    recipe: Recipe,
    seed: u64,
    threads: usize,
    base_controller: PathBuf,
    /// `recipe.feedback.config`, resolved and checked to hold a `[feedback]` table.
    feedback_config: Option<PathBuf>,
    /// `recipe.trajectory_sets`, resolved: (name, directory).
    trajectory_sets: Vec<(String, PathBuf)>,
    config_file: PathBuf,
    mp: MultiProgress,
}

fn quote(s: &str) -> String {
    if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "-_./,=:+@".contains(c)) {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

fn command_line(args: &[String]) -> String {
    std::iter::once("bowden".to_string())
        .chain(args.iter().map(|a| quote(a)))
        .collect::<Vec<_>>()
        .join(" ")
}

fn now_ms() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis())
}

/// Temp file + rename: a reader sees the old file or the new one, never half of one.
fn write_atomic(path: &Path, text: &str) -> Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

fn remove_any(p: &Path) -> std::io::Result<()> {
    let r = if p.is_dir() {
        std::fs::remove_dir_all(p)
    } else {
        std::fs::remove_file(p)
    };
    match r {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(e),
        _ => Ok(()),
    }
}

fn log_tail(log: &Path, n: usize) -> Vec<String> {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    // Progress bars of a child redraw with carriage returns: keep the last state of a line.
    let lines: Vec<String> = text
        .lines()
        .map(|l| l.rsplit('\r').next().unwrap_or("").trim_end().to_string())
        .filter(|l| !l.is_empty())
        .collect();
    lines[lines.len().saturating_sub(n)..].to_vec()
}

/// Runs one unit's steps in order; stops at the first failure.
struct UnitRunner<'a> {
    ctx: &'a Ctx,
    plan: &'a UnitPlan,
    label: String,
    bar: &'a ProgressBar,
    records: Vec<StepRecord>,
    stamps: std::collections::BTreeMap<String, Stamp>,
    total_steps: usize,
}

impl UnitRunner<'_> {
    fn stamp_path(&self, step: &str) -> PathBuf {
        self.plan.dir.join(format!("{step}.done"))
    }

    /// Runs `step` unless its stamp says it finished with the same inputs: the arguments (the
    /// unit's directory written `$UNIT`, `--threads` left out: results do not depend on it),
    /// `extra` (contents of input files) and the stamps of the `upstream` steps it reads, and
    /// its main product `outputs[0]` still exists. A (re)run first removes all `outputs`.
    fn step(
        &mut self,
        step: &str,
        action: Action<'_>,
        extra: &str,
        upstream: &[String],
        outputs: &[PathBuf],
    ) -> std::result::Result<(), Failure> {
        let dir = self.plan.dir.display().to_string();
        let (command, hashed) = match &action {
            Action::Exe(args) => {
                let mut view = Vec::new();
                let mut skip = false;
                for a in args {
                    if std::mem::take(&mut skip) {
                        continue;
                    }
                    if a == "--threads" {
                        skip = true;
                        continue;
                    }
                    view.push(a.replace(&dir, "$UNIT"));
                }
                (command_line(args), view.join("\u{1f}"))
            }
            Action::Local(desc, _) => (desc.clone(), desc.replace(&dir, "$UNIT")),
        };
        let mut h = format!("{step}\u{1e}{hashed}\u{1e}{extra}");
        for u in upstream {
            match self.stamps.get(u) {
                Some(s) => {
                    let _ = write!(h, "\u{1e}{u}={}@{}", s.inputs_hash, s.finished_unix_ms);
                }
                None => {
                    let _ = write!(h, "\u{1e}{u}=none");
                }
            }
        }
        let hash = fnv1a64_hex(h.as_bytes());
        let stamp_path = self.stamp_path(step);
        let k = self.records.len() + 1;
        self.bar.set_message(format!("{step} ({k}/{})", self.total_steps));
        if let Some(s) = std::fs::read_to_string(&stamp_path)
            .ok()
            .and_then(|t| serde_json::from_str::<Stamp>(&t).ok())
        {
            if s.inputs_hash == hash && outputs.first().is_none_or(|o| o.exists()) {
                self.records.push(StepRecord {
                    step: step.into(),
                    status: StepStatus::Skipped,
                    seconds: s.seconds,
                    cpu_seconds: s.cpu_seconds,
                    command: s.command.clone(),
                    log: None,
                });
                self.stamps.insert(step.into(), s);
                return Ok(());
            }
        }
        let fail = |status: String, log: Option<PathBuf>, hint: Option<String>| {
            let log_tail = log.as_deref().map(|l| log_tail(l, 15)).unwrap_or_default();
            Failure {
                step: step.into(),
                status,
                log,
                log_tail,
                hint,
            }
        };
        // Unfinished or stale: the stamp goes first, then whatever a partial run left.
        let _ = remove_any(&stamp_path);
        for o in outputs {
            remove_any(o).map_err(|e| fail(format!("removing {}: {e}", o.display()), None, None))?;
        }
        let logs = self.plan.dir.join("logs");
        std::fs::create_dir_all(&logs).map_err(|e| fail(format!("creating {}: {e}", logs.display()), None, None))?;
        let log = logs.join(format!("{step}.log"));
        let t0 = Instant::now();
        let mut cpu_seconds = 0.0;
        match action {
            Action::Exe(args) => {
                let run = || -> std::io::Result<(std::process::ExitStatus, f64)> {
                    use std::io::Write as _;
                    let mut f = std::fs::File::create(&log)?;
                    writeln!(
                        f,
                        "$ cd {} && {}",
                        quote(&self.ctx.project.display().to_string()),
                        command
                    )?;
                    let f2 = f.try_clone()?;
                    run_measured(
                        std::process::Command::new(&self.ctx.exe)
                            .args(&args)
                            .current_dir(&self.ctx.project)
                            .stdin(Stdio::null())
                            .stdout(f)
                            .stderr(f2),
                    )
                };
                let (status, cpu) = run().map_err(|e| fail(format!("could not run: {e}"), Some(log.clone()), None))?;
                if !status.success() {
                    let text = std::fs::read_to_string(&log).unwrap_or_default();
                    let hint = (text.contains("unrecognized subcommand")
                        && args.first().map(String::as_str) == Some("tune"))
                    .then(|| {
                        format!(
                            "this bowden has no `tune` subcommand: set `recipe.tune = false` in {}",
                            self.ctx.config_file.display()
                        )
                    });
                    return Err(fail(status.to_string(), Some(log), hint));
                }
                cpu_seconds = cpu;
            }
            Action::Local(desc, f) => {
                let r = f();
                let _ = std::fs::write(
                    &log,
                    format!(
                        "{desc}\n{}\n",
                        r.as_ref().map_or_else(|e| format!("error: {e:#}"), |_| "done".into())
                    ),
                );
                if let Err(e) = r {
                    return Err(fail(format!("error: {e:#}"), Some(log), None));
                }
            }
        }
        let seconds = t0.elapsed().as_secs_f64();
        let stamp = Stamp {
            step: step.into(),
            command: command.clone(),
            inputs_hash: hash,
            seconds,
            cpu_seconds,
            finished_unix_ms: now_ms(),
        };
        let text = serde_json::to_string_pretty(&stamp).unwrap_or_default();
        write_atomic(&stamp_path, &text).map_err(|e| fail(format!("{e:#}"), Some(log.clone()), None))?;
        self.ctx
            .mp
            .suspend(|| eprintln!("{}: {step} {seconds:.1} s (CPU {cpu_seconds:.1} s)", self.label));
        self.records.push(StepRecord {
            step: step.into(),
            status: StepStatus::Ran,
            seconds,
            cpu_seconds,
            command,
            log: Some(log),
        });
        self.stamps.insert(step.into(), stamp);
        Ok(())
    }
}

/// Steps 3 and 4 of the recipe on one dataset: every model trained (the pair of each
/// architecture, the judges, the further inverse candidates), then `tune` (or the base
/// controller). `round` suffixes the step names, the models' directory and the controller
/// ("" for the first dataset). Returns the controller and the name of the step that wrote it.
fn train_and_tune(
    runner: &mut UnitRunner,
    data: &Path,
    collect_step: &str,
    round: &str,
) -> std::result::Result<(PathBuf, String), Failure> {
    let ctx = runner.ctx;
    let r = &ctx.recipe;
    let dir = runner.plan.dir.clone();
    let s = |p: &Path| p.display().to_string();
    // 3. Train every architecture in both directions, the judges' forward models and the
    //    further inverse candidates.
    let models = dir.join(format!("models{round}"));
    let _ = std::fs::create_dir_all(&models);
    let (mut fwd, mut inv, mut judges) = (Vec::new(), Vec::new(), Vec::new());
    let mut trained = Vec::new();
    for job in r.training_jobs() {
        let model = models.join(&job.file);
        let (json, svg) = bowden_learning::report::sidecar_paths(&model);
        let args = r.train_args(&job.arch, job.direction, job.seed, ctx.threads, data, &model);
        let name = format!("train-{}{round}", job.step);
        runner.step(
            &name,
            Action::Exe(args),
            "",
            &[collect_step.into()],
            &[model.clone(), json, svg],
        )?;
        trained.push(name);
        match job.role {
            ModelRole::Forward => fwd.push(model),
            ModelRole::Inverse => inv.push(model),
            ModelRole::Judge => judges.push(model),
        }
    }
    // 4. Choose the settings.
    let tune_step = format!("tune{round}");
    let controller = dir.join(format!("controller{round}.toml"));
    let base_text = read_text(&ctx.base_controller);
    let join = |v: &[PathBuf]| v.iter().map(|p| s(p)).collect::<Vec<_>>().join(",");
    let action = if r.tune {
        let mut args: Vec<String> = vec![
            "tune".into(),
            "--data".into(),
            s(data),
            "--forward".into(),
            join(&fwd),
            "--inverse".into(),
            join(&inv),
        ];
        // Judges are never candidates (a judge of a candidate's architecture is trained
        // again with another seed), so every candidate is rated by models it did not use.
        if !judges.is_empty() {
            args.extend(["--judge".into(), join(&judges)]);
        }
        args.extend(["--base".into(), s(&ctx.base_controller), "--out".into(), s(&controller)]);
        Action::Exe(args)
    } else {
        let (f, i, c, b) = (
            fwd[0].clone(),
            inv[0].clone(),
            controller.clone(),
            ctx.base_controller.clone(),
        );
        Action::Local(
            format!(
                "recipe.tune = false: {} with model_fwd = {}, model_inv = {} → {}",
                b.display(),
                f.display(),
                i.display(),
                c.display()
            ),
            Box::new(move || controller_from_base(&b, &f, &i, &c)),
        )
    };
    runner.step(
        &tune_step,
        action,
        &base_text,
        &trained,
        &[controller.clone(), controller.with_extension("tune.json")],
    )?;
    Ok((controller, tune_step))
}

/// Runs `cmd` to its end: its exit status and the CPU time (user + system, s) it and the
/// children it waited for used.
fn run_measured(cmd: &mut std::process::Command) -> std::io::Result<(std::process::ExitStatus, f64)> {
    use std::os::unix::process::ExitStatusExt as _;
    let child = cmd.spawn()?;
    let pid = child.id() as libc::pid_t;
    let mut status = 0;
    // SAFETY: `rusage` is plain old data, for which all zeroes is a valid value.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: waits for our own child, writing into the two locals above.
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut ru) };
        if r == pid {
            break;
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
    // Reaped above; dropping a `Child` neither waits nor kills.
    drop(child);
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Ok((
        std::process::ExitStatus::from_raw(status),
        secs(ru.ru_utime) + secs(ru.ru_stime),
    ))
}

fn read_text(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

/// The family's plant file with `[variation] unit = N`.
fn unit_plant_text(family_plant: &Path, unit: u64) -> Result<String> {
    let text = std::fs::read_to_string(family_plant).with_context(|| format!("reading {}", family_plant.display()))?;
    let mut t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", family_plant.display()))?;
    let var = t
        .entry("variation")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()));
    let Some(var) = var.as_table_mut() else {
        bail!("{}: `variation` is not a table", family_plant.display());
    };
    var.insert("unit".into(), toml::Value::Integer(i64::try_from(unit)?));
    Ok(format!(
        "# {} as manufactured unit {unit} (written by `bowden bench transfer`).\n{}",
        family_plant.display(),
        toml::to_string(&t)?
    ))
}

/// The unit's controller with the `[feedback]` table of `feedback_file` added (replacing one it
/// may have).
fn controller_with_feedback(controller: &Path, feedback_file: &Path, out: &Path) -> Result<()> {
    let text = std::fs::read_to_string(controller).with_context(|| format!("reading {}", controller.display()))?;
    let mut t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", controller.display()))?;
    t.insert("feedback".into(), feedback_table(feedback_file)?);
    // Model paths are relative to the controller's own directory: `out` is written beside it.
    write_atomic(
        out,
        &format!(
            "# {} with the [feedback] settings of {} (written by `bowden bench transfer`).\n{}",
            controller.display(),
            feedback_file.display(),
            toml::to_string(&t)?
        ),
    )
}

/// The `[feedback]` table of a controller file, which must switch it on.
fn feedback_table(file: &Path) -> Result<toml::Value> {
    let text = std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    let t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", file.display()))?;
    match t.get("feedback") {
        Some(v @ toml::Value::Table(f)) if f.get("enabled").and_then(toml::Value::as_bool) == Some(true) => {
            Ok(v.clone())
        }
        Some(toml::Value::Table(_)) => bail!("{}: [feedback] does not set enabled = true", file.display()),
        _ => bail!("{}: no [feedback] table", file.display()),
    }
}

/// `recipe.tune = false`: the base controller with the unit's first forward/inverse models.
fn controller_from_base(base: &Path, fwd: &Path, inv: &Path, out: &Path) -> Result<()> {
    let text = std::fs::read_to_string(base).with_context(|| format!("reading {}", base.display()))?;
    let mut t: toml::Table = toml::from_str(&text).with_context(|| format!("parsing {}", base.display()))?;
    for (k, p) in [("model_fwd", fwd), ("model_inv", inv)] {
        t.insert(k.into(), toml::Value::String(absolute(p).display().to_string()));
    }
    write_atomic(
        out,
        &format!(
            "# {} with this unit's models (written by `bowden bench transfer`, recipe.tune = false).\n{}",
            base.display(),
            toml::to_string(&t)?
        ),
    )
}

fn run_unit(ctx: &Ctx, families: &[Family], plan: &UnitPlan, bar: &ProgressBar) -> UnitOutcome {
    let fam = &families[plan.family];
    let label = format!("{}/unit-{}", fam.name, plan.unit);
    let r = &ctx.recipe;
    let mut runner = UnitRunner {
        ctx,
        plan,
        label: label.clone(),
        bar,
        records: Vec::new(),
        stamps: Default::default(),
        total_steps: {
            let train_and_tune = 1 + r.training_jobs().len();
            let rounds = if r.closed_loop.is_some() { 2 } else { 1 };
            let evaluations = if r.feedback.is_some() { 2 } else { 1 };
            rounds * (1 + train_and_tune)
                + evaluations * (1 + r.trajectory_sets.len())
                + usize::from(r.feedback.is_some())
        },
    };
    let t0 = Instant::now();
    let result = (|| -> std::result::Result<Vec<Row>, Failure> {
        let dir = &plan.dir;
        let local_fail = |step: &str, e: String| Failure {
            step: step.into(),
            status: e,
            log: None,
            log_tail: Vec::new(),
            hint: None,
        };
        // 1. The unit's plant file (rewritten only when it changes).
        let plant = dir.join("plant.toml");
        let text = unit_plant_text(&fam.plant, plan.unit).map_err(|e| local_fail("plant", format!("{e:#}")))?;
        std::fs::create_dir_all(dir).map_err(|e| local_fail("plant", format!("creating {}: {e}", dir.display())))?;
        if read_text(&plant) != text {
            write_atomic(&plant, &text).map_err(|e| local_fail("plant", format!("{e:#}")))?;
        }
        let s = |p: &Path| p.display().to_string();
        // 2. Collect through the vision loop.
        let data = dir.join("data");
        let collect = vec![
            "collect".into(),
            "--plant".into(),
            s(&plant),
            "--samples".into(),
            r.samples.to_string(),
            "--seed".into(),
            ctx.seed.to_string(),
            "--excitation".into(),
            r.excitation.as_str().into(),
            "--out".into(),
            s(&data),
        ];
        // The pipeline's own files (the subcommands' defaults) are inputs too.
        let pipeline_text = ["evaluate.toml", "robot.toml", "camera.toml", "markers.toml"]
            .iter()
            .map(|f| read_text(&ctx.project.join("configs").join(f)))
            .collect::<String>();
        let collect_inputs = format!("{text}{pipeline_text}");
        runner.step(
            "collect",
            Action::Exe(collect),
            &collect_inputs,
            &[],
            std::slice::from_ref(&data),
        )?;
        // 3–4. Train every model and choose the settings.
        let (mut controller, mut tune_step) = train_and_tune(&mut runner, &data, "collect", "")?;
        // 3b–4b. A second round under the compensator the first round made: its commands on
        //    this robot are added to the data and everything is trained and tuned again.
        if let Some(cl) = &r.closed_loop {
            let data2 = dir.join("data-closed-loop");
            let collect2 = vec![
                "collect".into(),
                "--plant".into(),
                s(&plant),
                "--samples".into(),
                cl.samples.to_string(),
                "--seed".into(),
                (ctx.seed + 1).to_string(),
                "--excitation".into(),
                cl.excitation.as_str().into(),
                "--controller-config".into(),
                s(&controller),
                "--extend".into(),
                s(&data),
                "--out".into(),
                s(&data2),
            ];
            runner.step(
                "collect-closed-loop",
                Action::Exe(collect2),
                &collect_inputs,
                &["collect".into(), tune_step.clone()],
                std::slice::from_ref(&data2),
            )?;
            (controller, tune_step) = train_and_tune(&mut runner, &data2, "collect-closed-loop", "-closed-loop")?;
        }
        // 5. Evaluate on the unseen trajectories.
        let eval = dir.join("eval");
        let summary = eval.join("summary.json");
        // `bowden evaluate` of `controller` on the unit's plant, the camera at `camera_fps`
        // (default: one frame per held point).
        let evaluate =
            |controller: &Path, camera_fps: Option<f64>, set: Option<&Path>, report: &Path, summary: &Path| {
                let mut args: Vec<String> = vec![
                    "evaluate".into(),
                    "--plant".into(),
                    s(&plant),
                    "--controller-config".into(),
                    s(controller),
                ];
                if let Some(f) = camera_fps {
                    args.extend(["--camera-fps".into(), f.to_string()]);
                }
                args.extend([
                    "--repeats".into(),
                    r.repeats.to_string(),
                    "--trajectories".into(),
                    r.trajectories.join(","),
                    "--controllers".into(),
                    r.controllers.join(","),
                ]);
                if let Some(d) = set {
                    args.extend(["--trajectories-dir".into(), s(d)]);
                }
                if let Some(n) = r.max_points {
                    args.extend(["--max-points".into(), n.to_string()]);
                }
                args.extend(["--report".into(), s(report), "--json-out".into(), s(summary)]);
                args
            };
        let args = evaluate(&controller, None, None, &eval, &summary);
        let eval_inputs = r
            .trajectories
            .iter()
            .fold(format!("{text}{pipeline_text}{}", read_text(&controller)), |acc, t| {
                acc + &read_text(&ctx.project.join("configs/trajectories").join(format!("{t}.toml")))
            });
        runner.step(
            "evaluate",
            Action::Exe(args),
            &eval_inputs,
            std::slice::from_ref(&tune_step),
            &[summary.clone(), eval.clone()],
        )?;
        // 6. The same controller with vision feedback, the camera fast enough to give it frames.
        if let (Some(fb), Some(fb_file)) = (&r.feedback, &ctx.feedback_config) {
            let fb_controller = dir.join("controller-feedback.toml");
            let (c, f, o) = (controller.clone(), fb_file.clone(), fb_controller.clone());
            runner.step(
                "feedback",
                Action::Local(
                    format!(
                        "{} with [feedback] of {} → {}",
                        controller.display(),
                        fb_file.display(),
                        fb_controller.display()
                    ),
                    Box::new(move || controller_with_feedback(&c, &f, &o)),
                ),
                &read_text(fb_file),
                std::slice::from_ref(&tune_step),
                std::slice::from_ref(&fb_controller),
            )?;
            let eval_fb = dir.join("eval-feedback");
            let summary_fb = eval_fb.join("summary.json");
            runner.step(
                "evaluate-feedback",
                Action::Exe(evaluate(
                    &fb_controller,
                    Some(fb.camera_fps),
                    None,
                    &eval_fb,
                    &summary_fb,
                )),
                &eval_inputs,
                &["feedback".into()],
                &[summary_fb.clone(), eval_fb.clone()],
            )?;
        }
        // 7. Both again on every further set of paths (e.g. at the paper's magnitude).
        for (name, set_dir) in &ctx.trajectory_sets {
            let set_inputs = r
                .trajectories
                .iter()
                .fold(format!("{text}{pipeline_text}{}", read_text(&controller)), |acc, t| {
                    acc + &read_text(&set_dir.join(format!("{t}.toml")))
                });
            let eval_set = dir.join(format!("eval-{name}"));
            let summary_set = eval_set.join("summary.json");
            runner.step(
                &format!("evaluate-{name}"),
                Action::Exe(evaluate(&controller, None, Some(set_dir), &eval_set, &summary_set)),
                &set_inputs,
                std::slice::from_ref(&tune_step),
                &[summary_set.clone(), eval_set.clone()],
            )?;
            if let Some(fb) = &r.feedback {
                let eval_fb = dir.join(format!("eval-feedback-{name}"));
                let summary_fb = eval_fb.join("summary.json");
                runner.step(
                    &format!("evaluate-feedback-{name}"),
                    Action::Exe(evaluate(
                        &dir.join("controller-feedback.toml"),
                        Some(fb.camera_fps),
                        Some(set_dir),
                        &eval_fb,
                        &summary_fb,
                    )),
                    &set_inputs,
                    &["feedback".into()],
                    &[summary_fb.clone(), eval_fb.clone()],
                )?;
            }
        }
        unit_rows(dir, r).map_err(|e| local_fail("report", format!("{e:#}")))
    })();
    let wall = t0.elapsed().as_secs_f64();
    let (rows, failure) = match result {
        Ok(rows) => (rows, None),
        Err(f) => (Vec::new(), Some(f)),
    };
    if let Some(f) = &failure {
        if !runner.records.iter().any(|x| x.step == f.step) {
            runner.records.push(StepRecord {
                step: f.step.clone(),
                status: StepStatus::Failed,
                seconds: 0.0,
                cpu_seconds: 0.0,
                command: String::new(),
                log: f.log.clone(),
            });
        }
    }
    UnitOutcome {
        family: fam.name.clone(),
        model: fam.model.clone(),
        unit: plan.unit,
        role: plan.role,
        dir: plan.dir.clone(),
        status: if failure.is_some() { "failed" } else { "ok" }.into(),
        failure,
        steps: runner.records,
        wall_seconds: wall,
        rows,
    }
}

// ---------------------------------------------------------------------------------------------
// Results

/// The six errors of one (trajectory, controller), or their reductions in percent.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
struct Six {
    position_vision: Option<f64>,
    position_truth: Option<f64>,
    orientation_vision: Option<f64>,
    orientation_truth: Option<f64>,
    joint_vision: Option<f64>,
    joint_truth: Option<f64>,
}

/// (key, heading) of Six's fields, in order.
const METRICS: [(&str, &str); 6] = [
    ("position_vision", "position, vision"),
    ("position_truth", "position, truth"),
    ("orientation_vision", "orientation, vision"),
    ("orientation_truth", "orientation, truth"),
    ("joint_vision", "joint MAE, vision"),
    ("joint_truth", "joint MAE, truth"),
];

impl Six {
    fn get(&self, i: usize) -> Option<f64> {
        [
            self.position_vision,
            self.position_truth,
            self.orientation_vision,
            self.orientation_truth,
            self.joint_vision,
            self.joint_truth,
        ][i]
    }

    fn zip(a: &Six, b: &Six, f: impl Fn(f64, f64) -> f64) -> Six {
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
struct Row {
    trajectory: String,
    controller: String,
    /// Mean tip position error (mm), orientation error (°), joint MAE averaged over joints (°).
    error: Six,
    uncalibrated: Six,
    /// reduction_pct(uncalibrated, controller): + = better.
    reduction_pct: Six,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct UnitOutcome {
    family: String,
    model: String,
    unit: u64,
    role: Role,
    dir: PathBuf,
    status: String,
    failure: Option<Failure>,
    steps: Vec<StepRecord>,
    wall_seconds: f64,
    rows: Vec<Row>,
}

#[derive(Deserialize)]
struct SummaryIn {
    cells: Vec<CellIn>,
}

#[derive(Deserialize)]
struct CellIn {
    trajectory: String,
    controller: String,
    task_vision: TaskIn,
    task_truth: TaskIn,
    joint_vision: JointIn,
    joint_truth: JointIn,
}

#[derive(Deserialize)]
struct TaskIn {
    n: usize,
    pos_mean_mm: Option<f64>,
    rot_mean_deg: Option<f64>,
}

#[derive(Deserialize)]
struct JointIn {
    n: usize,
    mae_deg: Vec<Option<f64>>,
}

impl CellIn {
    fn six(&self) -> Six {
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
fn unit_rows(dir: &Path, r: &Recipe) -> Result<Vec<Row>> {
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
fn set_name(c: &str, set: &str) -> String {
    format!("{c}@{set}")
}

/// The rows of one evaluation; `suffix` is appended to the calibrated controllers' names
/// (`+fb`: the evaluation with vision feedback).
fn rows_from_summary(path: &Path, r: &Recipe, suffix: &str) -> Result<Vec<Row>> {
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
struct Stat {
    n: usize,
    min: f64,
    median: f64,
    max: f64,
}

fn stat(mut v: Vec<f64>) -> Option<Stat> {
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
struct FamilySummary {
    family: String,
    controller: String,
    units: usize,
    /// Keyed like `Six`'s fields.
    reduction_pct: std::collections::BTreeMap<String, Stat>,
}

#[derive(Debug, Clone, Serialize)]
struct Violation {
    family: String,
    unit: u64,
    trajectory: String,
    metric: String,
    reduction_pct: f64,
}

#[derive(Debug, Clone, Serialize)]
struct NeverWorse {
    controller: String,
    checks: usize,
    violations: Vec<Violation>,
}

#[derive(Debug, Clone, Serialize)]
struct TimingRow {
    family: String,
    unit: u64,
    collect: Option<StepTime>,
    /// All `train-*` steps.
    train: Option<StepTime>,
    tune: Option<StepTime>,
    evaluate: Option<StepTime>,
    total: StepTime,
    /// Steps whose time comes from an earlier run's stamp.
    resumed: usize,
}

/// Wall and CPU seconds.
#[derive(Debug, Clone, Copy, Default, Serialize)]
struct StepTime {
    seconds: f64,
    cpu_seconds: f64,
}

#[derive(Debug, Clone, Serialize)]
struct Report {
    config: PathBuf,
    out: PathBuf,
    project_dir: PathBuf,
    quick: bool,
    units_selected: UnitSet,
    jobs: usize,
    train_threads: usize,
    cores: usize,
    /// 1-minute load average when the run started (other work on the machine slows it).
    load_average: Option<f64>,
    seed: u64,
    recipe: Recipe,
    families: Vec<Family>,
    /// The calibrated controller with the best median truth position reduction over the
    /// held-out (unit, trajectory) pairs: the one plotted.
    best_mode: Option<String>,
    /// The same among the feed-forward controllers only (without vision feedback).
    best_feed_forward: Option<String>,
    /// The issue's goals per calibrated controller, held-out units.
    goals: Vec<GoalCheck>,
    summary: Vec<FamilySummary>,
    never_worse: Vec<NeverWorse>,
    timing: Vec<TimingRow>,
    units: Vec<UnitOutcome>,
    /// Read back from the units' outcome files (`--merge`) instead of run by this process:
    /// jobs, threads, cores and load are then the merging process's, and `wall_seconds` is the
    /// sum of the units' wall times.
    merged: bool,
    wall_seconds: f64,
}

/// The feed-forward controllers, then (with `recipe.feedback`) the same with vision feedback.
fn calibrated(r: &Recipe) -> Vec<String> {
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

fn summarise(units: &[&UnitOutcome], families: &[Family], r: &Recipe) -> Vec<FamilySummary> {
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

fn never_worse(units: &[&UnitOutcome], r: &Recipe) -> Vec<NeverWorse> {
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

/// The issue's goals (#12) for one calibrated controller over the held-out pairs: every
/// reduction ≥ 60 % and the median of each ≥ 75 %, for tip position, orientation and joint MAE,
/// by vision and by truth.
#[derive(Debug, Clone, Serialize)]
struct GoalCheck {
    controller: String,
    /// The smallest reduction over every pair and metric, and where.
    worst_pct: f64,
    worst_at: String,
    /// The smallest per-metric median.
    lowest_median_pct: f64,
    lowest_median_metric: String,
    /// Pairs × metrics below 60 %.
    below_60: usize,
    checks: usize,
    met: bool,
}

const GOAL_MIN_PCT: f64 = 60.0;
const GOAL_MEDIAN_PCT: f64 = 75.0;

fn goals(units: &[&UnitOutcome], r: &Recipe) -> Vec<GoalCheck> {
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
fn best_mode(units: &[&UnitOutcome], r: &Recipe, feed_forward_only: bool) -> Option<String> {
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

fn timing(units: &[UnitOutcome]) -> Vec<TimingRow> {
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

// ---------------------------------------------------------------------------------------------
// Markdown

/// `p` relative to the project directory when inside it (reports need not name the machine).
fn shown(project: &Path, p: &Path) -> String {
    p.strip_prefix(project).unwrap_or(p).display().to_string()
}

fn pct(v: Option<f64>) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{v:+.1}"))
}

fn secs(v: Option<StepTime>) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{:.0} ({:.0})", v.seconds, v.cpu_seconds))
}

fn units_list(families: &[Family], pick: fn(&Family) -> &Vec<u64>) -> String {
    let parts: Vec<String> = families
        .iter()
        .filter(|f| !pick(f).is_empty())
        .map(|f| {
            format!(
                "{} {}",
                f.name,
                pick(f).iter().map(|u| u.to_string()).collect::<Vec<_>>().join(", ")
            )
        })
        .collect();
    if parts.is_empty() {
        "none".into()
    } else {
        parts.join("; ")
    }
}

fn reduction_table(out: &mut String, units: &[&UnitOutcome]) {
    let _ = write!(out, "| family | unit | trajectory | controller |");
    for (_, h) in METRICS {
        let _ = write!(out, " {h} |");
    }
    let _ = writeln!(out, "\n|---|---|---|---|---|---|---|---|---|---|");
    for u in units {
        if let Some(f) = &u.failure {
            let _ = writeln!(
                out,
                "| {} | {} | — | — | **failed** at step `{}` ({}) | | | | | |",
                u.family, u.unit, f.step, f.status
            );
            continue;
        }
        for row in &u.rows {
            let _ = write!(
                out,
                "| {} | {} | {} | {} |",
                u.family, u.unit, row.trajectory, row.controller
            );
            for i in 0..METRICS.len() {
                let _ = write!(out, " {} |", pct(row.reduction_pct.get(i)));
            }
            out.push('\n');
        }
    }
    out.push('\n');
}

fn markdown(rep: &Report) -> String {
    let mut out = String::new();
    let r = &rep.recipe;
    let _ = writeln!(out, "# Transfer to unseen units\n");
    let _ = writeln!(
        out,
        "Every unit ran what a user runs with a new robot — `bowden collect` through the vision loop, \
         `bowden train`, {}, `bowden evaluate` — with the same recipe and no per-unit tuning.{}\n",
        if r.tune {
            "`bowden tune`"
        } else {
            "the base controller with the unit's first trained pair (`recipe.tune = false`, no `bowden tune`)"
        },
        if rep.quick {
            " **`--quick` recipe: a smoke test, the numbers say nothing about transfer.**"
        } else {
            ""
        }
    );
    let _ = writeln!(
        out,
        "- **Held-out units** (the results below): {}",
        units_list(&rep.families, |f| &f.heldout_units)
    );
    let _ = writeln!(
        out,
        "- **Tuning units** (looked at while choosing the recipe; never reported as results): {}",
        units_list(&rep.families, |f| &f.tuning_units)
    );
    let ran: Vec<String> = rep.units.iter().map(|u| format!("{}/{}", u.family, u.unit)).collect();
    let _ = writeln!(
        out,
        "- This run: `--units {}`, {} unit(s) ({}), {}; config `{}`, output `{}`.\n",
        match rep.units_selected {
            UnitSet::Tuning => "tuning",
            UnitSet::Heldout => "heldout",
            UnitSet::All => "all",
        },
        rep.units.len(),
        ran.join(", "),
        if rep.merged {
            "merged from the units' outcome files (run as shards, `--shard I/N`)".to_string()
        } else {
            format!("{} at once, train threads {}", rep.jobs, rep.train_threads)
        },
        shown(&rep.project_dir, &rep.config),
        shown(&rep.project_dir, &rep.out)
    );
    let _ = writeln!(out, "## Recipe\n");
    let _ = writeln!(
        out,
        "1. plant: the family's plant file with `[variation] unit = N`\n\
         2. `bowden collect --samples {} --seed {} --excitation {}`\n\
         3. `bowden train --seq-len {} --epochs {}{}` for {} × forward, inverse{}{}\n\
         4. {}\n{}\
         5. `bowden evaluate --repeats {} --trajectories {} --controllers {}{}` on the unit's plant\n{}",
        r.samples,
        rep.seed,
        r.excitation,
        r.seq_len,
        r.epochs,
        r.early_stop.map(|e| format!(" --early-stop {e}")).unwrap_or_default()
            + &format!(" --decimation {}", r.decimation),
        r.archs.join(", "),
        r.per_arch
            .keys()
            .map(|a| {
                let (e, es) = r.training(a);
                let p = r.precision(a);
                format!(
                    "; {a}: `--epochs {e}{}{}`",
                    es.map(|x| format!(" --early-stop {x}")).unwrap_or_default(),
                    if p == Precision::F32 {
                        String::new()
                    } else {
                        format!(" --precision {p}")
                    }
                )
            })
            .collect::<String>(),
        if r.forward_archs.is_empty() {
            String::new()
        } else {
            format!("; further forward candidates: {}", r.forward_archs.join(", "))
        } + &if r.judge_archs.is_empty() {
            String::new()
        } else {
            let seeded: Vec<&str> = r
                .judge_archs
                .iter()
                .filter(|a| r.is_forward_candidate(a))
                .map(String::as_str)
                .collect();
            format!(
                "; judges (forward only, `tune --judge`): {}{}",
                r.judge_archs.join(", "),
                if seeded.is_empty() {
                    String::new()
                } else {
                    format!(
                        " ({} trained again with `--seed {}`, apart from the candidate)",
                        seeded.join(", "),
                        r.judge_seed
                    )
                }
            )
        } + &if r.inverse_archs.is_empty() {
            String::new()
        } else {
            format!("; further inverse candidates: {}", r.inverse_archs.join(", "))
        },
        if r.tune {
            format!(
                "`bowden tune --base {}` with every trained model",
                r.base_controller.display()
            )
        } else {
            format!(
                "controller: {} with the first forward/inverse pair (`recipe.tune = false`)",
                r.base_controller.display()
            )
        },
        r.closed_loop.as_ref().map_or_else(String::new, |cl| format!(
            "4b. a second round under that controller: `bowden collect --samples {} --seed {} --excitation {} \
             --controller-config <4.> --extend <2.>` (its configurations are targets; the commands the \
             compensator sent are recorded), then 3. and 4. again on the whole\n",
            cl.samples,
            rep.seed + 1,
            cl.excitation
        )),
        r.repeats,
        r.trajectories.join(","),
        r.controllers.join(","),
        r.max_points.map(|n| format!(" --max-points {n}")).unwrap_or_default(),
        r.feedback.as_ref().map_or_else(String::new, |f| format!(
            "6. the same with vision feedback (controllers `+fb`): the unit's controller plus the `[feedback]` \
             table of `{}`, `bowden evaluate --camera-fps {}` (frames during each held point)\n",
            shown(&rep.project_dir, &f.config),
            f.camera_fps
        )) + &r
            .trajectory_sets
            .iter()
            .map(|(name, d)| {
                format!(
                    "7. 5.{} again on the paths of `{}` (`--trajectories-dir`), reported as controllers `…@{name}`\n",
                    if r.feedback.is_some() { " and 6." } else { "" },
                    d.display()
                )
            })
            .collect::<String>(),
    );
    let _ = writeln!(out, "## Families\n");
    let _ = writeln!(
        out,
        "| family | plant file | model | tuning units | held-out units |\n|---|---|---|---|---|"
    );
    for f in &rep.families {
        let l = |v: &Vec<u64>| {
            if v.is_empty() {
                "—".into()
            } else {
                v.iter().map(|u| u.to_string()).collect::<Vec<_>>().join(", ")
            }
        };
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} |",
            f.name,
            shown(&rep.project_dir, &f.plant),
            f.model,
            l(&f.tuning_units),
            l(&f.heldout_units)
        );
    }
    out.push('\n');
    let held: Vec<&UnitOutcome> = rep.units.iter().filter(|u| u.role == Role::HeldOut).collect();
    let tuning: Vec<&UnitOutcome> = rep.units.iter().filter(|u| u.role == Role::Tuning).collect();
    let _ = writeln!(
        out,
        "## Held-out units: error reduction vs uncalibrated, % (+ = better)\n\n\
         Mean tip position and orientation error and joint MAE (mean over the joints) of each calibrated \
         controller against the uncalibrated robot on the same trajectory, measured by the vision estimate \
         and by the simulator's truth.\n"
    );
    if held.is_empty() {
        let _ = writeln!(out, "No held-out unit ran (`--units heldout` or `all` runs them).\n");
    } else {
        reduction_table(&mut out, &held);
    }
    let _ = writeln!(
        out,
        "## Per family (held-out): median [min, max] of the reduction, % over units × trajectories\n"
    );
    if rep.summary.is_empty() {
        let _ = writeln!(out, "No results.\n");
    } else {
        let _ = write!(out, "| family | controller | units | pairs |");
        for (_, h) in METRICS {
            let _ = write!(out, " {h} |");
        }
        let _ = writeln!(out, "\n|---|---|---|---|---|---|---|---|---|---|");
        for s in &rep.summary {
            let n = s.reduction_pct.get("position_truth").map_or(0, |x| x.n);
            let _ = write!(out, "| {} | {} | {} | {} |", s.family, s.controller, s.units, n);
            for (key, _) in METRICS {
                let txt = s.reduction_pct.get(key).map_or_else(
                    || "—".into(),
                    |x| format!("{:+.1} [{:+.1}, {:+.1}]", x.median, x.min, x.max),
                );
                let _ = write!(out, " {txt} |");
            }
            out.push('\n');
        }
        out.push('\n');
    }
    let _ = writeln!(
        out,
        "## Never worse than uncalibrated (held-out)\n\nEvery (unit, trajectory, metric) of a calibrated \
         controller must have a reduction ≥ 0.\n"
    );
    let _ = writeln!(out, "| controller | checks | violations |\n|---|---|---|");
    for n in &rep.never_worse {
        let _ = writeln!(
            out,
            "| {} | {} | {} |",
            n.controller,
            n.checks,
            if n.violations.is_empty() {
                "none ✓".to_string()
            } else {
                format!("**{}**", n.violations.len())
            }
        );
    }
    out.push('\n');
    for n in &rep.never_worse {
        for v in &n.violations {
            let _ = writeln!(
                out,
                "- {}: {} unit {}, {}, {}: {:+.1} %",
                n.controller,
                v.family,
                v.unit,
                v.trajectory,
                METRICS
                    .iter()
                    .find(|m| m.0 == v.metric)
                    .map_or(v.metric.as_str(), |m| m.1),
                v.reduction_pct
            );
        }
    }
    if rep.never_worse.iter().any(|n| !n.violations.is_empty()) {
        out.push('\n');
    }
    if let Some(b) = &rep.best_mode {
        let _ = writeln!(
            out,
            "Best calibrated mode (median position reduction by truth over the held-out pairs): **{b}**{}; \
             `transfer.svg` plots its distribution per family.\n",
            match &rep.best_feed_forward {
                Some(f) if f != b => format!("; without vision feedback: **{f}**"),
                _ => String::new(),
            }
        );
    }
    if !rep.goals.is_empty() {
        let _ = writeln!(
            out,
            "## Goals (held-out)\n\nEvery reduction (position, orientation, joint MAE; vision and truth) ≥ \
             {GOAL_MIN_PCT:.0} % on every held-out unit and trajectory, and the median of each ≥ \
             {GOAL_MEDIAN_PCT:.0} %.\n\n\
             | controller | worst reduction | where | cells < {GOAL_MIN_PCT:.0} % | lowest median | of | met |\n\
             |---|---|---|---|---|---|---|"
        );
        for g in &rep.goals {
            let _ = writeln!(
                out,
                "| {} | {:+.1} % | {} | {} of {} | {:+.1} % | {} | {} |",
                g.controller,
                g.worst_pct,
                g.worst_at,
                g.below_60,
                g.checks,
                g.lowest_median_pct,
                g.lowest_median_metric,
                if g.met { "yes" } else { "**no**" }
            );
        }
        out.push('\n');
    }
    let failed: Vec<&UnitOutcome> = rep.units.iter().filter(|u| u.failure.is_some()).collect();
    if !failed.is_empty() {
        let _ = writeln!(out, "## Failures\n");
        for u in failed {
            let Some(f) = &u.failure else { continue };
            let _ = writeln!(
                out,
                "- {} unit {} ({}): step `{}` failed: {}{}{}",
                u.family,
                u.unit,
                u.role.label(),
                f.step,
                f.status,
                f.log
                    .as_ref()
                    .map(|l| format!("; log {}", l.display()))
                    .unwrap_or_default(),
                f.hint.as_ref().map(|h| format!("; {h}")).unwrap_or_default()
            );
            if !f.log_tail.is_empty() {
                let _ = writeln!(out, "\n  ```\n  {}\n  ```", f.log_tail.join("\n  "));
            }
        }
        out.push('\n');
    }
    let machine = if rep.merged {
        "on the machines that ran the shards".to_string()
    } else {
        format!(
            "on a machine with {} core(s), load average {} at the start",
            rep.cores,
            rep.load_average.map_or_else(|| "unknown".into(), |l| format!("{l:.2}"))
        )
    };
    let _ = writeln!(
        out,
        "## Timing per step\n\nWall seconds (CPU seconds of the subprocesses, user + system) {machine}. \
         `*`: steps skipped in this run (finished earlier: the times are the stamp's).\n"
    );
    let _ = writeln!(
        out,
        "| family | unit | collect | train | tune | evaluate | total |\n|---|---|---|---|---|---|---|"
    );
    for t in &rep.timing {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {}{} |",
            t.family,
            t.unit,
            secs(t.collect),
            secs(t.train),
            secs(t.tune),
            secs(t.evaluate),
            secs(Some(t.total)),
            if t.resumed > 0 {
                format!(" ({} step(s) *)", t.resumed)
            } else {
                String::new()
            }
        );
    }
    let mean = |f: fn(&TimingRow) -> Option<StepTime>| {
        let v: Vec<StepTime> = rep.timing.iter().filter_map(f).collect();
        let n = v.len() as f64;
        (!v.is_empty()).then(|| StepTime {
            seconds: v.iter().map(|t| t.seconds).sum::<f64>() / n,
            cpu_seconds: v.iter().map(|t| t.cpu_seconds).sum::<f64>() / n,
        })
    };
    if rep.timing.len() > 1 {
        let _ = writeln!(
            out,
            "| mean | | {} | {} | {} | {} | {} |",
            secs(mean(|t| t.collect)),
            secs(mean(|t| t.train)),
            secs(mean(|t| t.tune)),
            secs(mean(|t| t.evaluate)),
            secs(mean(|t| Some(t.total)))
        );
    }
    if rep.merged {
        let _ = writeln!(
            out,
            "\nWall time of the units (run as shards), summed: {:.0} s.\n",
            rep.wall_seconds
        );
    } else {
        let _ = writeln!(out, "\nWall time of this run: {:.0} s.\n", rep.wall_seconds);
    }
    if !tuning.is_empty() {
        let _ = writeln!(
            out,
            "## Tuning units (for choosing the recipe only; not results)\n\nReduction vs uncalibrated, %.\n"
        );
        reduction_table(&mut out, &tuning);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Plot

/// Best mode's position reduction per family, one point per (unit, trajectory): truth filled,
/// vision hollow; the legend sits beside the chart, off the data.
fn plot(path: &Path, rep: &Report, units: &[&UnitOutcome], which: &str) -> Result<()> {
    use plotters::prelude::*;
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    let e = |x: String| anyhow!("{}: {x}", path.display());
    let mode = rep.best_mode.clone().unwrap_or_else(|| "no results".into());
    // Two series per family: the best mode by truth and by vision; or, when the best mode uses
    // vision feedback (whose loop drives the vision-measured error), the best feed-forward mode
    // and the best mode, both by truth.
    let series: [(String, bool, &str); 2] = match &rep.best_feed_forward {
        Some(ff) if *ff != mode => [
            (ff.clone(), true, "feed-forward"),
            (mode.clone(), true, "with vision feedback"),
        ],
        _ => [(mode.clone(), true, "by truth"), (mode.clone(), false, "by vision")],
    };
    let fams: Vec<&Family> = rep
        .families
        .iter()
        .filter(|f| units.iter().any(|u| u.family == f.name && !u.rows.is_empty()))
        .collect();
    // (family, k, value, series 0 or 1)
    let mut pts: Vec<(usize, usize, f64, bool)> = Vec::new();
    for (fi, f) in fams.iter().enumerate() {
        for (si, (c, truth, _)) in series.iter().enumerate() {
            let mut k = 0;
            for u in units.iter().filter(|u| u.family == f.name) {
                for row in u.rows.iter().filter(|r| r.controller == *c) {
                    let v = if *truth {
                        row.reduction_pct.position_truth
                    } else {
                        row.reduction_pct.position_vision
                    };
                    if let Some(v) = v {
                        pts.push((fi, k, v, si == 0));
                    }
                    k += 1;
                }
            }
        }
    }
    let title = if series[0].0 == series[1].0 {
        mode.clone()
    } else {
        format!("{} and {}", series[0].0, series[1].0)
    };
    let per_family = |fi: usize| pts.iter().filter(|p| p.0 == fi && p.3).count().max(1);
    let lo = pts.iter().map(|p| p.2).fold(0.0f64, f64::min);
    let hi = pts.iter().map(|p| p.2).fold(100.0f64, f64::max);
    let pad = 0.05 * (hi - lo).max(1.0);
    let n = fams.len().max(1);
    let width = (260 + 150 * n as u32).max(640);
    let root = SVGBackend::new(path, (width, 460)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
    let (left, right) = root.split_horizontally(width - 200);
    let names: Vec<String> = fams
        .iter()
        .map(|f| {
            let k = units
                .iter()
                .filter(|u| u.family == f.name && !u.rows.is_empty())
                .count();
            format!("{} ({k} unit{})", f.name, if k == 1 { "" } else { "s" })
        })
        .collect();
    let mut chart = ChartBuilder::on(&left)
        .caption(
            format!("{title}: tip position error reduction vs uncalibrated, {which} units"),
            ("sans-serif", 15),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, (lo - pad)..(hi + pad))
        .map_err(|x| e(x.to_string()))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .y_desc("reduction, % (+ = better)")
        .draw()
        .map_err(|x| e(x.to_string()))?;
    // Family names under their columns (the axis is categorical).
    let label_style = TextStyle::from(("sans-serif", 13).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
    for (fi, name) in names.iter().enumerate() {
        let (px, py) = chart.backend_coord(&(fi as f64, lo - pad));
        left.draw(&Text::new(name.clone(), (px, py + 8), label_style.clone()))
            .map_err(|x| e(x.to_string()))?;
    }
    chart
        .draw_series(LineSeries::new(
            vec![(-0.5, 0.0), (n as f64 - 0.5, 0.0)],
            BLACK.mix(0.6).stroke_width(1),
        ))
        .map_err(|x| e(x.to_string()))?;
    let spread = |fi: usize, k: usize| {
        let m = per_family(fi);
        if m == 1 {
            0.0
        } else {
            0.18 * (k as f64 / (m - 1) as f64 - 0.5)
        }
    };
    let truth_c = RGBColor(31, 119, 180);
    let vision_c = RGBColor(214, 39, 40);
    chart
        .draw_series(
            pts.iter()
                .filter(|p| p.3)
                .map(|p| Circle::new((p.0 as f64 - 0.13 + spread(p.0, p.1), p.2), 4, truth_c.filled())),
        )
        .map_err(|x| e(x.to_string()))?;
    chart
        .draw_series(
            pts.iter()
                .filter(|p| !p.3)
                .map(|p| Circle::new((p.0 as f64 + 0.13 + spread(p.0, p.1), p.2), 4, vision_c.stroke_width(1))),
        )
        .map_err(|x| e(x.to_string()))?;
    for fi in 0..fams.len() {
        for (truth, c, dx) in [(true, truth_c, -0.13), (false, vision_c, 0.13)] {
            let v: Vec<f64> = pts.iter().filter(|p| p.0 == fi && p.3 == truth).map(|p| p.2).collect();
            if let Some(s) = stat(v) {
                let x = fi as f64 + dx;
                chart
                    .draw_series(LineSeries::new(
                        vec![(x - 0.13, s.median), (x + 0.13, s.median)],
                        c.stroke_width(2),
                    ))
                    .map_err(|x| e(x.to_string()))?;
            }
        }
    }
    // Legend panel.
    let text = ("sans-serif", 13).into_font();
    let items: [(String, u8); 4] = [
        (
            if series[0].0 == series[1].0 {
                "by truth (unit × trajectory)".to_string()
            } else {
                format!("{} ({}, truth)", series[0].0, series[0].2)
            },
            0,
        ),
        (
            if series[0].0 == series[1].0 {
                "by vision".to_string()
            } else {
                format!("{} (truth)", series[1].0)
            },
            1,
        ),
        ("median".into(), 2),
        ("0 = uncalibrated".into(), 3),
    ];
    for (i, (label, kind)) in items.iter().enumerate() {
        let y = 60 + 24 * i as i32;
        match kind {
            0 => right.draw(&Circle::new((16, y), 4, truth_c.filled())),
            1 => right.draw(&Circle::new((16, y), 4, vision_c.stroke_width(1))),
            2 => right.draw(&PathElement::new(vec![(6, y), (26, y)], truth_c.stroke_width(2))),
            _ => right.draw(&PathElement::new(vec![(6, y), (26, y)], BLACK.mix(0.6).stroke_width(1))),
        }
        .map_err(|x| e(x.to_string()))?;
        right
            .draw(&Text::new(label.to_string(), (34, y - 7), text.clone()))
            .map_err(|x| e(x.to_string()))?;
    }
    root.present().map_err(|x| e(x.to_string()))?;
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The command

// ---------------------------------------------------------------------------------------------
// Plan, shards, merge

/// `UNIT/outcome.json`: what a unit's run reported, for `--merge` to read back.
#[derive(Debug, Serialize, Deserialize)]
struct OutcomeFile {
    format: String,
    /// [`unit_fingerprint`] of the run that wrote it.
    fingerprint: String,
    outcome: UnitOutcome,
}

const OUTCOME_FORMAT: &str = "bowden-transfer-unit/1";

fn outcome_path(p: &UnitPlan) -> PathBuf {
    p.dir.join("outcome.json")
}

/// FNV-1a 64 (hex) of what a unit's outcome depends on: the bowden version, the seed, the
/// recipe and the files it names (`recipe_files`: the base controller's and the feedback
/// config's text), the family, the unit's plant text and its role. Like the stamps, not the
/// binary itself: after changing the code, use another `--out`.
fn unit_fingerprint(recipe: &Recipe, recipe_files: &str, seed: u64, fam: &Family, p: &UnitPlan) -> Result<String> {
    #[derive(Serialize)]
    struct Identity<'a> {
        version: &'a str,
        seed: u64,
        recipe: &'a Recipe,
        recipe_files: &'a str,
        family: &'a str,
        plant: &'a str,
        unit: u64,
        role: Role,
    }
    // A plant file that cannot be read fails its unit at the `plant` step, not the plan.
    let plant = unit_plant_text(&fam.plant, p.unit).unwrap_or_else(|e| format!("unreadable: {e:#}"));
    let id = Identity {
        version: env!("CARGO_PKG_VERSION"),
        seed,
        recipe,
        recipe_files,
        family: &fam.name,
        plant: &plant,
        unit: p.unit,
        role: p.role,
    };
    Ok(fnv1a64_hex(&serde_json::to_vec(&id)?))
}

enum OutcomeState {
    Done(Box<UnitOutcome>),
    Missing,
    /// There, but not a complete outcome of this unit and config: why.
    Bad(String),
}

fn read_outcome(p: &UnitPlan, fingerprint: &str) -> OutcomeState {
    let text = match std::fs::read_to_string(outcome_path(p)) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return OutcomeState::Missing,
        Err(e) => return OutcomeState::Bad(format!("cannot read: {e}")),
    };
    match serde_json::from_str::<OutcomeFile>(&text) {
        Err(e) => OutcomeState::Bad(format!("not a complete outcome file ({e})")),
        Ok(f) if f.format != OUTCOME_FORMAT => {
            OutcomeState::Bad(format!("format {:?}, expected {OUTCOME_FORMAT:?}", f.format))
        }
        Ok(f) if f.fingerprint != fingerprint => OutcomeState::Bad(format!(
            "made with another config, recipe, seed, plant or bowden version (fingerprint {} ≠ {fingerprint})",
            f.fingerprint
        )),
        Ok(f) => OutcomeState::Done(Box::new(f.outcome)),
    }
}

/// Every planned unit's outcome, or an error listing the missing ones by index and naming each
/// file that is not this plan's. A finished unit's rows are read again from its evaluation's
/// summary.json, as the run that made them did: serde_json's float parsing is not exact to the
/// last bit, so rows read back from outcome.json could differ from a local run's in the 17th
/// digit.
fn load_outcomes(plans: &[UnitPlan], fingerprints: &[String], recipe: &Recipe) -> Result<Vec<UnitOutcome>> {
    let (mut units, mut missing, mut bad) = (Vec::new(), Vec::new(), Vec::new());
    for (k, (p, fp)) in plans.iter().zip(fingerprints).enumerate() {
        match read_outcome(p, fp) {
            OutcomeState::Done(mut u) if u.failure.is_none() => match unit_rows(&p.dir, recipe) {
                Ok(rows) => {
                    u.rows = rows;
                    units.push(*u);
                }
                Err(e) => bad.push(format!("{} (unit {k}): {e:#}", outcome_path(p).display())),
            },
            OutcomeState::Done(u) => units.push(*u),
            OutcomeState::Missing => missing.push(k.to_string()),
            OutcomeState::Bad(why) => bad.push(format!("{} (unit {k}): {why}", outcome_path(p).display())),
        }
    }
    let mut parts = Vec::new();
    if !missing.is_empty() {
        parts.push(format!(
            "{} of {} units have no outcome.json (indices {}; rerun their shards)",
            missing.len(),
            plans.len(),
            missing.join(", ")
        ));
    }
    if !bad.is_empty() {
        parts.push(format!(
            "{} outcome file(s) not from this plan (rerun their shards, which replace them):\n  {}",
            bad.len(),
            bad.join("\n  ")
        ));
    }
    if !parts.is_empty() {
        bail!("cannot merge: {}", parts.join("; "));
    }
    Ok(units)
}

fn print_unit_plan(a: &TransferArgs, plans: &[UnitPlan], families: &[Family], fingerprints: &[String]) -> Result<()> {
    super::refuse_overwrite(a.json_out.as_slice(), a.force, "--json-out")?;
    let units: Vec<serde_json::Value> = plans
        .iter()
        .zip(fingerprints)
        .enumerate()
        .map(|(k, (p, fp))| {
            let status = match read_outcome(p, fp) {
                OutcomeState::Done(u) if u.failure.is_some() => "failed".to_string(),
                OutcomeState::Done(_) => "done".to_string(),
                OutcomeState::Missing => "pending".to_string(),
                OutcomeState::Bad(why) => format!("redo: {why}"),
            };
            serde_json::json!({
                "index": k,
                "family": families[p.family].name,
                "unit": p.unit,
                "role": p.role,
                "dir": p.dir,
                "fingerprint": fp,
                "status": status,
            })
        })
        .collect();
    let plan = serde_json::json!({
        "format": "bowden-transfer-plan/1",
        "sharding": SHARDING.replace("runs", "units"),
        "units": units,
    });
    let json = serde_json::to_string_pretty(&plan)?;
    if let Some(j) = &a.json_out {
        std::fs::write(j, format!("{json}\n")).with_context(|| format!("{}", j.display()))?;
    }
    if a.json {
        println!("{json}");
        return Ok(());
    }
    println!(
        "bench transfer plan: {} units; sharding {}",
        plans.len(),
        SHARDING.replace("runs", "units")
    );
    println!(
        "{:>5}  {:32}  {:8}  {:16}  status",
        "index", "unit", "role", "fingerprint"
    );
    for (k, (u, p)) in units.iter().zip(plans).enumerate() {
        println!(
            "{k:>5}  {:32}  {:8}  {:16}  {}",
            format!("{}/unit-{}", families[p.family].name, p.unit),
            p.role.label(),
            u["fingerprint"].as_str().unwrap_or(""),
            u["status"].as_str().unwrap_or("")
        );
    }
    Ok(())
}

fn transfer(a: TransferArgs) -> Result<()> {
    if a.jobs == 0 {
        bail!("--jobs must be at least 1");
    }
    let t_start = Instant::now();
    let load_average = std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse::<f64>().ok());
    // The config by bowden's resolution order (docs/architecture.md §1): the shipped one is found
    // outside a checkout too, and then the built-in copy is the project the steps run in.
    let config_file = absolute(&crate::home::path(&a.config)?);
    let text = std::fs::read_to_string(&config_file).with_context(|| format!("reading {}", a.config.display()))?;
    let cfg: TransferConfig = toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", a.config.display()))?;
    cfg.validate().map_err(|e| anyhow!("{}: {e}", a.config.display()))?;
    let cfg_dir = config_file.parent().map(Path::to_path_buf).unwrap_or_default();
    let root = find_root(&cfg_dir).or_else(|| {
        crate::home::builtin_root()
            .ok()
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
    // Units, taken in turn from each family (so --max-units covers the families).
    let out = absolute(&a.out);
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
        let exe = std::env::current_exe().context("locating the bowden executable")?;
        if recipe.tune {
            let o = std::process::Command::new(&exe)
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
        let ctx = Ctx {
            exe,
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
        eprintln!(
            "bench transfer: {} unit(s), {} at once, into {}",
            selected.len(),
            jobs,
            out.display()
        );
        let overall = ctx.mp.add(ProgressBar::new(selected.len() as u64));
        overall.set_style(
            ProgressStyle::with_template("units [{bar:30}] {pos}/{len}  {elapsed_precise}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        let next = AtomicUsize::new(0);
        let outcomes: Mutex<Vec<Option<UnitOutcome>>> = Mutex::new(vec![None; selected.len()]);
        std::thread::scope(|s| {
            for _ in 0..jobs {
                s.spawn(|| loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some(plan) = selected.get(i).map(|&k| &plans[k]) else {
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
                    let o = run_unit(&ctx, &families, plan, &bar);
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
        if units.len() != selected.len() {
            bail!(
                "{} of {} units did not report (a thread panicked)",
                selected.len() - units.len(),
                selected.len()
            );
        }
        // Every unit's outcome beside its stamps, for --merge (a shard's units, or a local run's).
        for (&k, u) in selected.iter().zip(&units) {
            let file = OutcomeFile {
                format: OUTCOME_FORMAT.into(),
                fingerprint: fingerprints[k].clone(),
                outcome: u.clone(),
            };
            std::fs::create_dir_all(&plans[k].dir).with_context(|| format!("creating {}", plans[k].dir.display()))?;
            write_atomic(&outcome_path(&plans[k]), &serde_json::to_string_pretty(&file)?)?;
        }
        if let Some(s) = selection {
            for (&k, u) in selected.iter().zip(&units) {
                println!(
                    "unit {k} {}/unit-{}: {}; {}",
                    u.family,
                    u.unit,
                    match &u.failure {
                        None => "ok".to_string(),
                        Some(f) => format!("FAILED at step {}", f.step),
                    },
                    outcome_path(&plans[k]).display()
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
                plans.len()
            );
            return Ok(());
        }
        units
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

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(text: &str) -> std::result::Result<TransferConfig, String> {
        let c: TransferConfig = toml::from_str(text).map_err(|e| e.to_string())?;
        c.validate()?;
        Ok(c)
    }

    const OK: &str = r#"
seed = 1
[recipe]
samples = 100
excitation = "mixed"
archs = ["tcn"]
epochs = 3
seq_len = 80
repeats = 1
trajectories = ["circle"]
controllers = ["uncalibrated", "paper"]
tune = false
base_controller = "configs/controller.toml"
[[family]]
name = "a"
plant = "configs/plant.toml"
heldout_units = [1, 2]
"#;

    #[test]
    fn config_errors_name_the_field() {
        assert!(cfg(OK).is_ok());
        let e = cfg(&OK.replace("samples = 100", "samples = 1")).unwrap_err();
        assert!(e.contains("recipe.samples"), "{e}");
        let e = cfg(&OK.replace("samples = 100", "sampels = 100")).unwrap_err();
        assert!(e.contains("sampels"), "{e}");
        let e = cfg(&OK.replace("[\"tcn\"]", "[\"cnn\"]")).unwrap_err();
        assert!(e.contains("recipe.archs[0]"), "{e}");
        let e = cfg(&OK.replace("[\"uncalibrated\", \"paper\"]", "[\"paper\"]")).unwrap_err();
        assert!(e.contains("recipe.controllers"), "{e}");
        let e = cfg(&OK.replace("heldout_units = [1, 2]", "heldout_units = [1, 2]\ntuning_units = [2]")).unwrap_err();
        assert!(e.contains("family[0].heldout_units"), "{e}");
        let per_arch = |t: &str| OK.replace("[[family]]", &format!("[recipe.per_arch.{t}\n[[family]]"));
        let e = cfg(&per_arch("lstm]\nepochs = 5")).unwrap_err();
        assert!(e.contains("recipe.per_arch.lstm"), "{e}");
        let e = cfg(&per_arch("tcn]\nepochs = 0")).unwrap_err();
        assert!(e.contains("recipe.per_arch.tcn"), "{e}");
        let e = cfg(&per_arch("tcn]\nepoch = 5")).unwrap_err();
        assert!(e.contains("epoch"), "{e}");
    }

    fn row(controller: &str, trajectory: &str, pct: f64) -> Row {
        let six = Six {
            position_vision: Some(pct),
            position_truth: Some(pct),
            orientation_vision: Some(pct),
            orientation_truth: Some(pct),
            joint_vision: Some(pct),
            joint_truth: Some(pct),
        };
        Row {
            trajectory: trajectory.into(),
            controller: controller.into(),
            error: six,
            uncalibrated: six,
            reduction_pct: six,
        }
    }

    fn unit(family: &str, n: u64, rows: Vec<Row>) -> UnitOutcome {
        UnitOutcome {
            family: family.into(),
            model: family.into(),
            unit: n,
            role: Role::HeldOut,
            dir: PathBuf::new(),
            status: "ok".into(),
            failure: None,
            steps: Vec::new(),
            wall_seconds: 0.0,
            rows,
        }
    }

    /// `OK` with `recipe_lines` added to `[recipe]` and a `[recipe.feedback]` table.
    fn ok_with_feedback(recipe_lines: &str) -> String {
        OK.replace(
            "[[family]]",
            &format!(
                "{recipe_lines}[recipe.feedback]\nconfig = \"configs/controller-feedback.toml\"\ncamera_fps = 10.0\n[[family]]"
            ),
        )
    }

    #[test]
    fn feedback_controllers_are_reported_and_judged_by_the_goals() {
        let with_fb = ok_with_feedback("");
        let r = cfg(&with_fb).unwrap().recipe;
        assert_eq!(calibrated(&r), ["paper", "paper+fb"]);
        let e = cfg(&with_fb.replace("camera_fps = 10.0", "camera_fps = 0.0")).unwrap_err();
        assert!(e.contains("recipe.feedback.camera_fps"), "{e}");
        let e = cfg(&with_fb.replace("camera_fps = 10.0", "camera_fps = 10.0\ngain = 1")).unwrap_err();
        assert!(e.contains("gain"), "{e}");
        // paper: one cell below 60 %; paper+fb: all ≥ 60 %, median 80 %.
        let a = unit(
            "a",
            1,
            vec![
                row("paper", "circle", 70.0),
                row("paper+fb", "circle", 80.0),
                row("paper", "zigzag", 59.0),
                row("paper+fb", "zigzag", 61.0),
            ],
        );
        let b = unit(
            "a",
            2,
            vec![row("paper", "circle", 90.0), row("paper+fb", "circle", 90.0)],
        );
        let g = goals(&[&a, &b], &r);
        assert_eq!((g[0].controller.as_str(), g[0].met), ("paper", false));
        assert_eq!((g[0].below_60, g[0].checks), (6, 18));
        assert_eq!(g[0].worst_pct, 59.0);
        assert!(g[0].worst_at.starts_with("a 1 zigzag"), "{}", g[0].worst_at);
        assert_eq!((g[1].controller.as_str(), g[1].met), ("paper+fb", true));
        assert_eq!(g[1].lowest_median_pct, 80.0);
        // A median below 75 % fails even with every cell ≥ 60 %.
        let c = unit("a", 3, vec![row("paper+fb", "circle", 61.0)]);
        let g = goals(&[&a, &c], &r);
        assert!(!g[1].met && g[1].below_60 == 0, "{:?}", g[1]);
        assert_eq!(best_mode(&[&a, &b], &r, false).as_deref(), Some("paper+fb"));
        assert_eq!(best_mode(&[&a, &b], &r, true).as_deref(), Some("paper"));
    }

    #[test]
    fn further_path_sets_are_controllers_of_their_own_but_never_the_headline() {
        let with_sets = ok_with_feedback("trajectory_sets = { large = \"configs/trajectories/large\" }\n");
        let r = cfg(&with_sets).unwrap().recipe;
        assert_eq!(calibrated(&r), ["paper", "paper+fb", "paper@large", "paper+fb@large"]);
        let e = cfg(&with_sets.replace("large =", "\"../up\" =")).unwrap_err();
        assert!(e.contains("recipe.trajectory_sets"), "{e}");
        // The large paths' goals are checked on their own rows; the best mode (the plot, the
        // headline) comes from the shipped paths only, however well the others did.
        let a = unit(
            "a",
            1,
            vec![
                row("paper", "circle", 50.0),
                row("paper+fb", "circle", 70.0),
                row("paper@large", "circle", 80.0),
                row("paper+fb@large", "circle", 95.0),
            ],
        );
        let g = goals(&[&a], &r);
        let met: Vec<(&str, bool)> = g.iter().map(|g| (g.controller.as_str(), g.met)).collect();
        assert_eq!(
            met,
            [
                ("paper", false),
                ("paper+fb", false),
                ("paper@large", true),
                ("paper+fb@large", true)
            ]
        );
        assert_eq!(best_mode(&[&a], &r, false).as_deref(), Some("paper+fb"));
        assert_eq!(best_mode(&[&a], &r, true).as_deref(), Some("paper"));
    }

    #[test]
    fn controller_with_feedback_adds_the_table() {
        let dir = tempfile::tempdir().unwrap();
        let (c, f, o) = (
            dir.path().join("c.toml"),
            dir.path().join("f.toml"),
            dir.path().join("o.toml"),
        );
        std::fs::write(&c, "mode = \"newton\"\nmodel_fwd = \"models/f.onnx\"\n").unwrap();
        std::fs::write(&f, "mode = \"paper\"\n[feedback]\nenabled = true\ngain = 0.8\n").unwrap();
        controller_with_feedback(&c, &f, &o).unwrap();
        let t: toml::Table = toml::from_str(&std::fs::read_to_string(&o).unwrap()).unwrap();
        assert_eq!(t["mode"].as_str(), Some("newton"), "the unit's settings stay");
        assert_eq!(t["model_fwd"].as_str(), Some("models/f.onnx"));
        assert_eq!(t["feedback"]["gain"].as_float(), Some(0.8));
        std::fs::write(&f, "[feedback]\nenabled = false\n").unwrap();
        let e = format!("{:#}", controller_with_feedback(&c, &f, &o).unwrap_err());
        assert!(e.contains("enabled = true"), "{e}");
        std::fs::write(&f, "mode = \"paper\"\n").unwrap();
        let e = format!("{:#}", controller_with_feedback(&c, &f, &o).unwrap_err());
        assert!(e.contains("no [feedback] table"), "{e}");
    }

    #[test]
    fn the_fingerprint_covers_the_files_the_recipe_names() {
        let r = cfg(OK).unwrap().recipe;
        let fam = Family {
            name: "a".into(),
            model: "plant".into(),
            plant: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("configs/plant.toml"),
            tuning_units: Vec::new(),
            heldout_units: vec![1],
        };
        let plan = UnitPlan {
            family: 0,
            unit: 1,
            role: Role::HeldOut,
            dir: PathBuf::new(),
        };
        let fp = |files: &str| unit_fingerprint(&r, files, 1, &fam, &plan).unwrap();
        assert_eq!(
            fp("base\u{1e}[feedback]\ngain = 0.8"),
            fp("base\u{1e}[feedback]\ngain = 0.8")
        );
        // Another feedback gain or base controller: shards made with it are not merged.
        assert_ne!(
            fp("base\u{1e}[feedback]\ngain = 0.8"),
            fp("base\u{1e}[feedback]\ngain = 0.5")
        );
        assert_ne!(fp("base\u{1e}"), fp("other base\u{1e}"));
    }

    #[test]
    fn inverse_architectures_are_validated() {
        let with = |j: &str| OK.replace("archs = [\"tcn\"]", &format!("archs = [\"tcn\"]\ninverse_archs = {j}"));
        let c = cfg(&with("[\"lstm\"]")).unwrap();
        assert_eq!(c.recipe.inverse_archs, ["lstm"]);
        assert_candidate_list_is_validated("inverse_archs");
        let text = with("[\"lstm\"]").replace("[[family]]", "[recipe.per_arch.lstm]\nepochs = 30\n[[family]]");
        assert_eq!(cfg(&text).unwrap().recipe.training("lstm"), (30, None));
    }

    #[test]
    fn judge_architectures_are_validated() {
        let with = |j: &str| OK.replace("archs = [\"tcn\"]", &format!("archs = [\"tcn\"]\njudge_archs = {j}"));
        assert!(cfg(&with("[\"lstm\"]")).is_ok());
        let e = cfg(&with("[\"rnn\"]")).unwrap_err();
        assert!(e.contains("recipe.judge_archs[0]"), "{e}");
        let e = cfg(&with("[\"lstm\", \"lstm\"]")).unwrap_err();
        assert!(e.contains("twice"), "{e}");
        // per_arch may name a judge.
        let text = with("[\"lstm\"]").replace("[[family]]", "[recipe.per_arch.lstm]\nepochs = 30\n[[family]]");
        assert_eq!(cfg(&text).unwrap().recipe.training("lstm"), (30, None));
    }

    #[test]
    fn a_judge_of_a_candidate_architecture_is_trained_apart_with_its_own_seed() {
        let text = OK.replace(
            "archs = [\"tcn\"]",
            "archs = [\"tcn\"]\nforward_archs = [\"lstm\"]\njudge_archs = [\"lstm\"]\ninverse_archs = [\"lstm\"]",
        );
        let c = cfg(&text).unwrap();
        let jobs = c.recipe.training_jobs();
        // step, file, role, seed, direction: one line per trained model.
        let got: Vec<String> = jobs
            .iter()
            .map(|j| format!("{} {} {:?} {:?} {}", j.step, j.file, j.role, j.seed, j.direction))
            .collect();
        assert_eq!(c.recipe.seq_len, 80);
        assert_eq!(
            got,
            [
                "tcn-forward tcn_forward_L80.onnx Forward None forward",
                "tcn-inverse tcn_inverse_L80.onnx Inverse None inverse",
                "lstm-forward lstm_forward_L80.onnx Forward None forward",
                "lstm-forward-judge lstm_forward_judge_L80.onnx Judge Some(1) forward",
                "lstm-inverse lstm_inverse_L80.onnx Inverse None inverse",
            ]
        );
        // The judge's training says its seed; the candidates' do not (their stamps stay).
        let (data, model) = (Path::new("/u/data"), Path::new("/u/models/m.onnx"));
        let judge = c
            .recipe
            .train_args("lstm", "forward", jobs[3].seed, 2, data, model)
            .join(" ");
        assert!(judge.contains("--seed 1"), "{judge}");
        assert!(!c
            .recipe
            .train_args("lstm", "forward", None, 2, data, model)
            .contains(&"--seed".to_string()));
        let c = cfg(&text.replace("epochs = 3", "epochs = 3\njudge_seed = 7")).unwrap();
        assert_eq!(c.recipe.training_jobs()[3].seed, Some(7));
        let e = cfg(&text.replace("epochs = 3", "epochs = 3\njudge_seed = 0")).unwrap_err();
        assert!(e.contains("recipe.judge_seed"), "{e}");
        // A judge of an architecture nobody sends commands with is the one training, as before.
        let c = cfg(&OK.replace("archs = [\"tcn\"]", "archs = [\"tcn\"]\njudge_archs = [\"lstm\"]")).unwrap();
        let judge = &c.recipe.training_jobs()[2];
        assert_eq!(
            (judge.step.as_str(), judge.role, judge.seed),
            ("lstm-forward", ModelRole::Judge, None)
        );
        // forward_archs is validated like inverse_archs.
        assert_candidate_list_is_validated("forward_archs");
    }

    /// `recipe.FIELD` (a list of further candidate architectures) refuses an architecture of
    /// `archs`, an unknown one and one given twice, naming the field.
    fn assert_candidate_list_is_validated(field: &str) {
        let with = |v: &str| OK.replace("archs = [\"tcn\"]", &format!("archs = [\"tcn\"]\n{field} = {v}"));
        let e = cfg(&with("[\"tcn\"]")).unwrap_err();
        assert!(
            e.contains(&format!("recipe.{field}")) && e.contains("both directions"),
            "{e}"
        );
        let e = cfg(&with("[\"gru\"]")).unwrap_err();
        assert!(e.contains(&format!("recipe.{field}[0]")), "{e}");
        let e = cfg(&with("[\"lstm\", \"lstm\"]")).unwrap_err();
        assert!(e.contains("twice"), "{e}");
    }

    #[test]
    fn the_recipe_decimation_reaches_every_training_and_is_validated() {
        let (data, model) = (Path::new("/u/data"), Path::new("/u/models/m.onnx"));
        let args = |c: &TransferConfig| -> Vec<String> {
            c.recipe
                .training_jobs()
                .iter()
                .map(|job| {
                    c.recipe
                        .train_args(&job.arch, job.direction, job.seed, 2, data, model)
                        .join(" ")
                })
                .collect()
        };
        // Absent: auto, as train's own default, and passed so a stamp says which.
        let c = cfg(OK).unwrap();
        assert_eq!(c.recipe.decimation, DecimationRule::Auto);
        assert!(
            args(&c).iter().all(|a| a.contains("--decimation auto")),
            "{:?}",
            args(&c)
        );
        for (key, want) in [
            ("decimation = 4", "--decimation 4"),
            ("decimation = \"auto\"", "--decimation auto"),
        ] {
            let text = OK.replace("epochs = 3", &format!("epochs = 3\n{key}\njudge_archs = [\"tcn\"]"));
            let c = cfg(&text).unwrap();
            let a = args(&c);
            assert_eq!(a.len(), c.recipe.training_jobs().len());
            assert!(a.iter().all(|a| a.contains(want)), "{key}: {a:?}");
        }
        for bad in ["decimation = 0", "decimation = \"four\""] {
            let e = cfg(&OK.replace("epochs = 3", &format!("epochs = 3\n{bad}"))).unwrap_err();
            assert!(e.contains("decimation"), "{bad}: {e}");
        }
        // The shipped paper-protocol recipe is a valid config and lets train decide (4 on its
        // eq. (16) data).
        let shipped =
            std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/transfer-paper-protocol.toml"))
                .unwrap();
        let c = cfg(&shipped).unwrap();
        assert_eq!(
            (c.recipe.decimation, c.recipe.samples, c.recipe.epochs),
            (DecimationRule::Auto, 1802, 30)
        );
        assert_eq!(c.recipe.excitation, ExcitationKind::Paper);
    }

    #[test]
    fn per_arch_training_overrides_only_its_architecture() {
        let text = OK
            .replace("archs = [\"tcn\"]", "archs = [\"tcn\", \"lstm\"]\nearly_stop = 40")
            .replace(
                "[[family]]",
                "[recipe.per_arch.lstm]\nepochs = 30\nearly_stop = 8\n[[family]]",
            );
        let c = cfg(&text).unwrap();
        assert_eq!(c.recipe.training("tcn"), (3, Some(40)));
        assert_eq!(c.recipe.training("lstm"), (30, Some(8)));
        let q = c.recipe.quick();
        assert_eq!((q.training("tcn"), q.training("lstm")), ((2, None), (2, None)));
        // Without `precision` no train step says --precision (their stamps stay as they were).
        let (data, model) = (Path::new("/u/data"), Path::new("/u/models/m.onnx"));
        for a in ["tcn", "lstm"] {
            assert!(!c
                .recipe
                .train_args(a, "forward", None, 2, data, model)
                .contains(&"--precision".to_string()));
        }
        // With it, only that architecture trains in bf16.
        let c = cfg(&text.replace("early_stop = 8\n", "early_stop = 8\nprecision = \"bf16\"\n")).unwrap();
        let lstm = c.recipe.train_args("lstm", "inverse", None, 2, data, model).join(" ");
        assert!(
            lstm.contains("--epochs 30 --early-stop 8 ") && lstm.contains(" --precision bf16"),
            "{lstm}"
        );
        let tcn = c.recipe.train_args("tcn", "inverse", None, 2, data, model).join(" ");
        assert!(!tcn.contains("--precision"), "{tcn}");
        let e = cfg(&text.replace("early_stop = 8\n", "early_stop = 8\nprecision = \"f16\"\n")).unwrap_err();
        assert!(e.contains("f16") && e.contains("precision"), "{e}");
    }

    #[test]
    fn stats_and_reductions() {
        let s = stat(vec![3.0, 1.0, 2.0, f64::NAN, 10.0]).unwrap();
        assert_eq!((s.n, s.min, s.median, s.max), (4, 1.0, 2.5, 10.0));
        let u = Six {
            position_truth: Some(10.0),
            ..Default::default()
        };
        let c = Six {
            position_truth: Some(4.0),
            position_vision: Some(1.0),
            ..Default::default()
        };
        let r = Six::zip(&u, &c, reduction_pct);
        assert_eq!(r.position_truth, Some(60.0));
        assert_eq!(r.position_vision, None);
    }

    #[test]
    fn unit_plant_sets_the_unit() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.toml");
        std::fs::write(&p, "name = \"x\"\n[variation]\nrelative_sd = 0.05\nunit = 3\n").unwrap();
        let t: toml::Table = toml::from_str(&unit_plant_text(&p, 77).unwrap()).unwrap();
        assert_eq!(t["variation"]["unit"].as_integer(), Some(77));
        assert_eq!(t["variation"]["relative_sd"].as_float(), Some(0.05));
        std::fs::write(&p, "name = \"x\"\n").unwrap();
        let t: toml::Table = toml::from_str(&unit_plant_text(&p, 5).unwrap()).unwrap();
        assert_eq!(t["variation"]["unit"].as_integer(), Some(5));
    }
}
