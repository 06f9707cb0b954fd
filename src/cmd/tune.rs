//! `bowden tune`: the controller config for a new robot, chosen from its validation data
//! (bowden-tuning). A thin wrapper: parse, load, call, write.

use anyhow::{Context, Result};
use bowden_compensator::{ControllerConfig, Mode};
use bowden_kinematics::Robot;
use bowden_learning::dataset::Dataset;
use bowden_learning::windows::SplitConfig;
use bowden_tuning::{config_toml, tune, TuneOptions};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct TuneArgs {
    /// Dataset directory the models were trained on (dataset.csv + manifest.json).
    #[arg(long)]
    pub data: PathBuf,
    /// Forward models to choose from (comma-separated .onnx files).
    #[arg(long, value_delimiter = ',', required = true)]
    pub forward: Vec<PathBuf>,
    /// Inverse models to choose from (comma-separated .onnx files).
    #[arg(long, value_delimiter = ',', required = true)]
    pub inverse: Vec<PathBuf>,
    /// Forward models that only rate the candidates (e.g. an accurate LSTM judging the TCN pair
    /// a 1 kHz controller must use).
    #[arg(long, value_delimiter = ',')]
    pub judge: Vec<PathBuf>,
    /// Controller config whose other settings (limits, budget, load check, …) are kept. Configs
    /// and models are found as given, under $BOWDEN_HOME, or built in (`bowden shipped`).
    #[arg(long, default_value = "configs/controller.toml")]
    pub base: PathBuf,
    /// Robot description (joint limits the compensator clamps to).
    #[arg(long, default_value = "configs/robot.toml")]
    pub robot: PathBuf,
    /// The controller config to write; the report goes beside it as NAME.tune.json.
    #[arg(long)]
    pub out: PathBuf,
    /// Overwrite an existing --out.
    #[arg(long)]
    pub force: bool,
    /// Validation steps replayed per candidate.
    #[arg(long, default_value_t = 1000)]
    pub max_steps: usize,
    /// Modes to consider (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "paper,newton",
          value_parser = super::typed_of::<Mode>(&["paper", "newton"]), ignore_case = true)]
    pub modes: Vec<Mode>,
    /// Newton prior weights μ to try (σ_f/σ_i of each pair is always added).
    #[arg(long, value_delimiter = ',', default_value = "0,0.5,1,2")]
    pub prior_weights: Vec<f64>,
    /// Fraction of samples the models were validated on (as `train --val-fraction`).
    #[arg(long, default_value_t = 0.2)]
    pub val_fraction: f64,
    /// Contiguous validation blocks (as `train --val-blocks`).
    #[arg(long, default_value_t = 1)]
    pub val_blocks: usize,
}

#[derive(Subcommand)]
pub enum Command {
    /// Choose the controller settings for a robot from its validation data: the history
    /// step, the model pair, the mode and newton's prior weight; write the controller config.
    Tune(TuneArgs),
}

pub fn run(c: Command) -> Result<()> {
    match c {
        Command::Tune(a) => run_tune(a),
    }
}

/// How a model path should appear in the written config: relative to the config's directory
/// when the model lies under it, else relative to that directory's parent (the repository-root
/// convention the compensator also resolves: `configs/x.toml` naming `models/m.onnx`), else
/// absolute.
fn shown_path(model: &Path, out_dir: &Path) -> Result<String> {
    let abs = std::fs::canonicalize(model).with_context(|| format!("{}", model.display()))?;
    let dir = std::fs::canonicalize(out_dir).unwrap_or_else(|_| out_dir.to_path_buf());
    if let Ok(p) = abs.strip_prefix(&dir) {
        return Ok(p.display().to_string());
    }
    if let Some(Ok(p)) = dir.parent().map(|root| abs.strip_prefix(root)) {
        return Ok(p.display().to_string());
    }
    Ok(abs.display().to_string())
}

fn run_tune(mut a: TuneArgs) -> Result<()> {
    super::refuse_overwrite(&[a.out.clone(), a.out.with_extension("tune.json")], a.force, "--out")?;
    super::dataset_dir("--data", &a.data)?;
    let home = |p: &PathBuf, flag: &str| crate::home::path(p).with_context(|| flag.to_string());
    a.base = home(&a.base, "--base")?;
    a.robot = home(&a.robot, "--robot")?;
    for (models, flag) in [
        (&mut a.forward, "--forward"),
        (&mut a.inverse, "--inverse"),
        (&mut a.judge, "--judge"),
    ] {
        for m in models.iter_mut() {
            *m = home(m, flag)?;
        }
    }
    let modes = a.modes.clone();
    let robot = Robot::load(&a.robot)?;
    let base_text = std::fs::read_to_string(&a.base).with_context(|| format!("--base {}", a.base.display()))?;
    let base = ControllerConfig::parse(&base_text, &a.base)?;
    let (ds, _) = Dataset::read_dir(&a.data).with_context(|| format!("--data {}", a.data.display()))?;
    let opts = TuneOptions {
        split: SplitConfig {
            val_fraction: a.val_fraction,
            val_blocks: a.val_blocks,
        },
        max_steps: a.max_steps,
        modes,
        prior_weights: a.prior_weights.clone(),
        judges: a.judge.clone(),
    };
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template("tune [{bar:40}] {pos}/{len} candidates  eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    let outcome = tune(&ds, &a.forward, &a.inverse, &base, &robot, &opts, &mut |done, total| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    })?;
    bar.finish_and_clear();
    let out_dir = a
        .out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(out_dir).with_context(|| format!("{}", out_dir.display()))?;
    let text = config_toml(
        &base_text,
        &outcome,
        &shown_path(&outcome.model_fwd, out_dir)?,
        &shown_path(&outcome.model_inv, out_dir)?,
    )?;
    // The written file must load as it will be used.
    ControllerConfig::parse(&text, &a.out).context("the written config does not validate (a bug)")?;
    std::fs::write(&a.out, &text).with_context(|| format!("{}", a.out.display()))?;
    let json = a.out.with_extension("tune.json");
    std::fs::write(&json, serde_json::to_string_pretty(&outcome.report)? + "\n")
        .with_context(|| format!("{}", json.display()))?;
    let r = &outcome.report;
    print!(
        "{}",
        text.lines()
            .take_while(|l| l.starts_with('#'))
            .map(|l| format!("{l}\n"))
            .collect::<String>()
    );
    println!(
        "wrote {} (mode {}, step {:.3}°) and {}",
        a.out.display(),
        r.chosen_mode,
        r.step_deg,
        json.display()
    );
    // By how much the choice won: a hair's breadth on the validation stretch says little about
    // other paths (issue #43).
    if let Some(line) = r.margin_line() {
        println!("{line}");
    }
    // The chosen models by `train`'s (and `bowden score`'s) definition of validation RMSE, so
    // the figure a user compares is the same everywhere: tune's own replay scores above use its
    // split, which need not be the one a model was trained with.
    for m in [&outcome.model_fwd, &outcome.model_inv] {
        let settings = bowden_learning::score::ScoreSettings::of_model(m)?.unwrap_or_else(|| {
            bowden_learning::score::ScoreSettings::given(
                SplitConfig {
                    val_fraction: a.val_fraction,
                    val_blocks: a.val_blocks,
                },
                Default::default(),
                1,
            )
        });
        let (sc, _) = bowden_learning::score::score(m, &a.data, &settings)
            .with_context(|| format!("scoring {} as `bowden score` does", m.display()))?;
        println!(
            "{} {}: validation RMSE {:.3}° (identity {:.3}°) on {} windows by train's definition ({})",
            sc.direction,
            m.display(),
            sc.rmse_deg,
            sc.identity_rmse_deg,
            sc.windows,
            if settings.from == "given" {
                "tune's split".to_string()
            } else {
                format!("settings of {}", settings.from)
            }
        );
    }
    Ok(())
}
