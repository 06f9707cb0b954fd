//! The study's configuration (`configs/transfer.toml`): families, units and the recipe.

use super::*;

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
pub(super) enum ModelRole {
    /// A forward model the controller may use (`tune --forward`).
    Forward,
    /// `tune --inverse`.
    Inverse,
    /// Rates the candidates only (`tune --judge`).
    Judge,
}

/// One `bowden train` of a unit's recipe.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct TrainJob {
    pub(super) arch: String,
    pub(super) direction: &'static str,
    pub(super) role: ModelRole,
    /// `train --seed` (None: its default, 0).
    pub(super) seed: Option<u64>,
    /// The model's file name in the unit's models directory.
    pub(super) file: String,
    /// The step's name after `train-` (round suffix apart).
    pub(super) step: String,
}

pub(super) fn default_judge_seed() -> u64 {
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
pub(super) fn fb_name(c: &str) -> String {
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

pub(super) fn path_safe(s: &str) -> bool {
    !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.')
        && s != "."
        && s != ".."
}

impl TransferConfig {
    // Long: one flat list of independent checks, each naming its field.
    pub(super) fn validate(&self) -> std::result::Result<(), String> {
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
    pub(super) fn training(&self, arch: &str) -> (usize, Option<usize>) {
        match self.per_arch.get(arch) {
            Some(o) => (o.epochs.unwrap_or(self.epochs), o.early_stop.or(self.early_stop)),
            None => (self.epochs, self.early_stop),
        }
    }

    /// `train --precision` for `arch` (f32 unless its `per_arch` table says otherwise).
    pub(super) fn precision(&self, arch: &str) -> Precision {
        self.per_arch.get(arch).and_then(|o| o.precision).unwrap_or_default()
    }

    /// Every model the recipe trains, in order: each of `archs` forward and inverse, then
    /// `forward_archs`, the judges, `inverse_archs`. A judge of an architecture that is also a
    /// forward candidate is a second training with `judge_seed`, in a file of its own.
    pub(super) fn training_jobs(&self) -> Vec<TrainJob> {
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
    pub(super) fn is_forward_candidate(&self, arch: &str) -> bool {
        self.archs.iter().chain(&self.forward_archs).any(|a| a == arch)
    }

    /// The `bowden train` arguments of one model of the recipe (`seed`: `train --seed`, left
    /// to its default 0 when `None`, so the steps of recipes without judges' seeds keep their
    /// stamps).
    pub(super) fn train_args(
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
    pub(super) fn quick(&self) -> Recipe {
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
pub(super) fn find_root(start: &Path) -> Option<PathBuf> {
    start
        .ancestors()
        .find(|d| d.join("Cargo.toml").is_file())
        .map(Path::to_path_buf)
}

pub(super) fn absolute(p: &Path) -> PathBuf {
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
pub(super) fn resolve(p: &Path, cfg_dir: &Path, root: Option<&Path>) -> PathBuf {
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
pub(super) fn plant_family_label(plant: &Path) -> Option<String> {
    let v: toml::Table = toml::from_str(&std::fs::read_to_string(plant).ok()?).ok()?;
    match v.get("family")? {
        toml::Value::String(s) => Some(s.clone()),
        toml::Value::Table(t) => t.get("name")?.as_str().map(str::to_string),
        _ => None,
    }
}

pub(super) fn file_stem(p: &Path) -> String {
    p.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "plant".into())
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub(super) enum Role {
    Tuning,
    HeldOut,
}

impl Role {
    pub(super) fn label(self) -> &'static str {
        match self {
            Role::Tuning => "tuning",
            Role::HeldOut => "held-out",
        }
    }
}

/// One family as resolved for this run.
#[derive(Debug, Clone, Serialize)]
pub(super) struct Family {
    pub(super) name: String,
    /// The plant file's own family label (or its file stem).
    pub(super) model: String,
    pub(super) plant: PathBuf,
    pub(super) tuning_units: Vec<u64>,
    pub(super) heldout_units: Vec<u64>,
}

/// One unit to run.
#[derive(Debug, Clone)]
pub(super) struct UnitPlan {
    pub(super) family: usize,
    pub(super) unit: u64,
    pub(super) role: Role,
    pub(super) dir: PathBuf,
}
