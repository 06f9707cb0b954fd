//! `bowden train` end to end: dataset → windows → training → ONNX → tract check → report
//! (JSON) and loss-curve plot (SVG).

use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::ProgressBar;
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use crate::arch::Direction;
use crate::dataset::{Dataset, DatasetError};
use crate::onnx::{ModelFile, OnnxError, TractModel};
use crate::spacing::{auto_decimation, DecimationChoice, DecimationRule};
use crate::train::{train, EpochStats, TrainConfig, TrainError, TrainOutcome};
use crate::windows::{overall_rmse, PhySource, SplitConfig, WindowError, WindowSet};

/// Largest |tract − fused| output (degrees) accepted for an exported model.
pub const EXPORT_TOLERANCE_DEG: f64 = 1e-4;

#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    #[error("{dir}: {source}")]
    Window {
        dir: PathBuf,
        #[source]
        source: WindowError,
    },
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error(transparent)]
    Onnx(#[from] OnnxError),
    #[error("{path}: cannot write: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("{path}: plot: {what}")]
    Plot { path: PathBuf, what: String },
    #[error("{dir}: --decimation auto needs two consecutive training commands that differ; give a number instead")]
    NoCommandSteps { dir: PathBuf },
    #[error(
        "{path}: the exported model differs from the trained one by {diff_deg:.3e} deg (tolerance {EXPORT_TOLERANCE_DEG:e})"
    )]
    ExportMismatch { path: PathBuf, diff_deg: f64 },
}

/// What a dataset contributed to a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DataSummary {
    pub dir: String,
    pub csv_fnv1a64: String,
    pub samples: usize,
    pub invalid_samples: usize,
    pub train_windows: usize,
    pub val_windows: usize,
    /// Windows dropped because they straddle the train/validation boundary.
    pub purged_windows: usize,
    pub phy_source: PhySource,
    pub split: SplitConfig,
}

/// A sample window and the exported model's output for it (as the PyTorch fixtures have),
/// so a consumer can check its loader.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExportCheck {
    pub onnx: String,
    /// Largest |tract − fused| over the checked windows, degrees.
    pub max_abs_diff_deg: f64,
    pub windows_checked: usize,
    pub input_q_seq_deg: Vec<Vec<f32>>,
    pub output_q_deg: Vec<f32>,
}

/// The JSON report of one training run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    pub format: String,
    pub config: TrainConfig,
    pub joints: usize,
    pub params: usize,
    pub tcn_blocks: usize,
    pub data: DataSummary,
    pub norm_in_mean: Vec<f64>,
    pub norm_in_sd: Vec<f64>,
    pub norm_out_mean: Vec<f64>,
    pub norm_out_sd: Vec<f64>,
    /// The untrained model's validation loss and RMSE (the "epoch 0" of the curves).
    pub initial_val_loss: f64,
    pub initial_val_rmse_deg: f64,
    pub epochs: Vec<EpochStats>,
    pub epochs_run: usize,
    pub stopped_early: bool,
    /// 1-based.
    pub best_epoch: usize,
    pub best_val_rmse_deg: f64,
    pub best_val_rmse_per_joint_deg: Vec<f64>,
    /// The raw hysteresis on the same validation windows: predicting the target by the
    /// newest input (q_phy = q_cmd).
    pub identity_val_rmse_deg: f64,
    pub identity_val_rmse_per_joint_deg: Vec<f64>,
    pub train_seconds: f64,
    pub mean_epoch_seconds: f64,
    pub export: Option<ExportCheck>,
    /// `--decimation auto`: what it chose (`config.decimation`) and from what. Absent when the
    /// decimation was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub decimation_auto: Option<DecimationChoice>,
}

pub const REPORT_FORMAT: &str = "bowden-train-report/1";

/// Builds the report of an outcome.
pub fn make_report(
    data: &WindowSet,
    summary: DataSummary,
    cfg: &TrainConfig,
    out: &TrainOutcome,
    secs: f64,
) -> TrainReport {
    let identity = data.identity_rmse_deg(&data.val);
    let best = out.best();
    TrainReport {
        format: REPORT_FORMAT.into(),
        config: cfg.clone(),
        joints: data.joints,
        params: out.model.spec.param_count(),
        tcn_blocks: out.model.spec.tcn_blocks(),
        data: summary,
        norm_in_mean: data.norm_in.mean.clone(),
        norm_in_sd: data.norm_in.sd.clone(),
        norm_out_mean: data.norm_out.mean.clone(),
        norm_out_sd: data.norm_out.sd.clone(),
        initial_val_loss: out.initial_val_loss,
        initial_val_rmse_deg: out.initial_val_rmse_deg,
        epochs_run: out.epochs.len(),
        stopped_early: out.stopped_early,
        best_epoch: out.best_epoch,
        best_val_rmse_deg: best.val_rmse_deg,
        best_val_rmse_per_joint_deg: best.val_rmse_per_joint_deg.clone(),
        identity_val_rmse_deg: overall_rmse(&identity),
        identity_val_rmse_per_joint_deg: identity,
        train_seconds: secs,
        mean_epoch_seconds: out.epochs.iter().map(|e| e.seconds).sum::<f64>() / out.epochs.len().max(1) as f64,
        epochs: out.epochs.clone(),
        export: None,
        decimation_auto: None,
    }
}

/// The decimation `rule` gives for the training rows of the dataset in `dir`: the number
/// itself, or what [`auto_decimation`] decides from the commands (returned as well).
pub fn resolve_decimation(
    dir: &Path,
    rule: DecimationRule,
    split: SplitConfig,
    phy: PhySource,
) -> Result<(usize, Option<DecimationChoice>), LearnError> {
    match rule {
        DecimationRule::Fixed(n) => Ok((n, None)),
        DecimationRule::Auto => {
            let (ds, _) = Dataset::read_dir(dir)?;
            let window_error = |source| LearnError::Window {
                dir: dir.to_path_buf(),
                source,
            };
            let rows = WindowSet::build(&ds, Direction::Forward, 1, split, phy)
                .map_err(window_error)?
                .train;
            let choice =
                auto_decimation(&ds, &rows).ok_or_else(|| LearnError::NoCommandSteps { dir: dir.to_path_buf() })?;
            Ok((choice.decimation, Some(choice)))
        }
    }
}

/// Loads a dataset directory and makes its windows.
pub fn load_windows(
    dir: &Path,
    cfg: &TrainConfig,
    split: SplitConfig,
    phy: PhySource,
) -> Result<(WindowSet, DataSummary), LearnError> {
    let (ds, manifest) = Dataset::read_dir(dir)?;
    let window_error = |source| LearnError::Window {
        dir: dir.to_path_buf(),
        source,
    };
    let mut ws = WindowSet::build(&ds, cfg.direction, cfg.seq_len, split, phy).map_err(window_error)?;
    ws.set_decimation(cfg.decimation).map_err(window_error)?;
    let summary = DataSummary {
        dir: dir.display().to_string(),
        csv_fnv1a64: manifest.csv_fnv1a64,
        samples: ds.len(),
        invalid_samples: ws.invalid_samples,
        train_windows: ws.train.len(),
        val_windows: ws.val.len(),
        purged_windows: ws.purged,
        phy_source: phy,
        split,
    };
    Ok((ws, summary))
}

/// Paths written next to a model: `NAME.onnx` → `NAME.report.json`, `NAME.loss.svg`.
pub fn sidecar_paths(onnx: &Path) -> (PathBuf, PathBuf) {
    (onnx.with_extension("report.json"), onnx.with_extension("loss.svg"))
}

/// Exports `model` to `path`, loads it back with tract and compares it with the fused
/// forward pass on up to `n_check` validation windows.
pub fn export_and_check(
    model: &ModelFile,
    data: &WindowSet,
    path: &Path,
    n_check: usize,
) -> Result<ExportCheck, LearnError> {
    model.save(path)?;
    let (l, j) = (model.spec.seq_len, model.spec.joints);
    let tract = TractModel::load(path, l, j)?;
    let stride = (data.val.len() / n_check.max(1)).max(1);
    let ids: Vec<usize> = data.val.iter().step_by(stride).take(n_check).copied().collect();
    let mut windows = Vec::with_capacity(ids.len() * l * j);
    for &t in &ids {
        windows.extend(data.window_deg(t).iter().map(|&v| v as f32));
    }
    let fused = model.predict_deg(&windows, ids.len());
    let mut max_diff = 0.0f64;
    let mut first_out = Vec::new();
    for (i, _) in ids.iter().enumerate() {
        let out = tract.run(&windows[i * l * j..(i + 1) * l * j])?;
        for k in 0..j {
            max_diff = max_diff.max((out[k] as f64 - fused[i * j + k] as f64).abs());
        }
        if i == 0 {
            first_out = out;
        }
    }
    if max_diff > EXPORT_TOLERANCE_DEG {
        return Err(LearnError::ExportMismatch {
            path: path.to_path_buf(),
            diff_deg: max_diff,
        });
    }
    Ok(ExportCheck {
        onnx: path.display().to_string(),
        max_abs_diff_deg: max_diff,
        windows_checked: ids.len(),
        input_q_seq_deg: windows[..l * j].chunks(j).map(|c| c.to_vec()).collect(),
        output_q_deg: first_out,
    })
}

/// `bowden train`: trains, exports `out_onnx`, checks it with tract, and writes the report
/// and the loss plot beside it. The histories' decimation is the one `decimation` gives for
/// this dataset ([`resolve_decimation`]), in place of `cfg.decimation`; the report's config
/// holds the one used, and `decimation_auto` why, when it was chosen.
pub fn train_to_files(
    data_dir: &Path,
    cfg: &TrainConfig,
    decimation: DecimationRule,
    split: SplitConfig,
    phy: PhySource,
    out_onnx: &Path,
    progress: Option<&ProgressBar>,
) -> Result<TrainReport, LearnError> {
    let (max_decimation, decimation_auto) = resolve_decimation(data_dir, decimation, split, phy)?;
    let cfg = &TrainConfig {
        decimation: max_decimation,
        ..cfg.clone()
    };
    let (ws, summary) = load_windows(data_dir, cfg, split, phy)?;
    let t0 = Instant::now();
    let outcome = train(&ws, cfg, progress)?;
    let secs = t0.elapsed().as_secs_f64();
    let mut report = make_report(&ws, summary, cfg, &outcome, secs);
    report.decimation_auto = decimation_auto;
    report.export = Some(export_and_check(&outcome.model, &ws, out_onnx, 16)?);
    let (json_path, svg_path) = sidecar_paths(out_onnx);
    write_json(&json_path, &report)?;
    plot_loss(&svg_path, &report)?;
    Ok(report)
}

pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), LearnError> {
    let text = serde_json::to_string_pretty(value).map_err(|source| LearnError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| LearnError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    std::fs::write(path, text + "\n").map_err(|source| LearnError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
pub(crate) enum LegendMark {
    Line(RGBColor, u32),
    Dot(RGBColor),
}

/// Height of a legend strip, px.
pub(crate) const LEGEND_STRIP_PX: u32 = 30;

/// A legend laid out left to right on its own strip above the panels, so it never covers data.
pub(crate) fn legend_strip<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    items: &[(String, LegendMark)],
) -> Result<(), String> {
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    const FONT_PX: u32 = 14;
    let style = TextStyle::from(("sans-serif", FONT_PX).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let y = area.dim_in_pixel().1 as i32 / 2;
    let mut x = 60i32;
    for (label, mark) in items {
        match *mark {
            LegendMark::Line(c, w) => area.draw(&PathElement::new(vec![(x, y), (x + 24, y)], c.stroke_width(w))),
            LegendMark::Dot(c) => area.draw(&Circle::new((x + 12, y), 5, c.filled())),
        }
        .map_err(|e| e.to_string())?;
        area.draw(&Text::new(label.clone(), (x + 32, y), style.clone()))
            .map_err(|e| e.to_string())?;
        x += 32 + (label.chars().count() as f64 * 0.6 * FONT_PX as f64).ceil() as i32 + 24;
    }
    Ok(())
}

/// Two panels: training and validation loss (normalised MSE, log scale) and validation
/// RMSE in degrees with the identity baseline; the best epoch marked. The legend is a strip
/// above both panels.
pub fn plot_loss(path: &Path, r: &TrainReport) -> Result<(), LearnError> {
    let err = |e: String| LearnError::Plot {
        path: path.to_path_buf(),
        what: e,
    };
    let n = r.epochs.len().max(2);
    let root = SVGBackend::new(path, (1000, 420 + LEGEND_STRIP_PX)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (legend, root) = root.split_vertically(LEGEND_STRIP_PX);
    legend_strip(
        &legend,
        &[
            ("train loss".into(), LegendMark::Line(BLUE, 2)),
            ("validation loss / RMSE".into(), LegendMark::Line(RED, 2)),
            ("identity (raw hysteresis)".into(), LegendMark::Line(BLACK, 1)),
            ("best epoch".into(), LegendMark::Dot(GREEN)),
        ],
    )
    .map_err(err)?;
    let (left, right) = root.split_horizontally(500);
    let losses: Vec<f64> = r
        .epochs
        .iter()
        .flat_map(|e| [e.train_loss, e.val_loss])
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    let lo = losses.iter().copied().fold(f64::INFINITY, f64::min).max(1e-12);
    let hi = losses.iter().copied().fold(0.0, f64::max).max(lo * 10.0);
    let title = format!("{} {} L={} — loss", r.config.arch, r.config.direction, r.config.seq_len);
    let mut chart = ChartBuilder::on(&left)
        .caption(title, ("sans-serif", 16))
        .margin(12)
        .x_label_area_size(32)
        .y_label_area_size(60)
        .build_cartesian_2d(1usize..n, (lo * 0.8..hi * 1.25).log_scale())
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("epoch")
        .y_desc("MSE (normalised)")
        .y_label_formatter(&|v| format!("{v:.3}"))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (color, pick) in [
        (BLUE, (|e: &EpochStats| e.train_loss) as fn(&EpochStats) -> f64),
        (RED, |e: &EpochStats| e.val_loss),
    ] {
        chart
            .draw_series(LineSeries::new(
                r.epochs.iter().map(|e| (e.epoch, pick(e))),
                color.stroke_width(2),
            ))
            .map_err(|e| err(e.to_string()))?;
    }

    let rmse_hi = r
        .epochs
        .iter()
        .map(|e| e.val_rmse_deg)
        .fold(r.identity_val_rmse_deg, f64::max)
        * 1.1;
    let mut chart = ChartBuilder::on(&right)
        .caption(
            format!("validation RMSE (best {:.2}° @ {})", r.best_val_rmse_deg, r.best_epoch),
            ("sans-serif", 16),
        )
        .margin(12)
        .x_label_area_size(32)
        .y_label_area_size(50)
        .build_cartesian_2d(1usize..n, 0.0..rmse_hi.max(1e-6))
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("epoch")
        .y_desc("deg")
        .draw()
        .map_err(|e| err(e.to_string()))?;
    chart
        .draw_series(LineSeries::new(
            r.epochs.iter().map(|e| (e.epoch, e.val_rmse_deg)),
            RED.stroke_width(2),
        ))
        .map_err(|e| err(e.to_string()))?;
    chart
        .draw_series(LineSeries::new(
            [(1, r.identity_val_rmse_deg), (n, r.identity_val_rmse_deg)],
            BLACK.stroke_width(1),
        ))
        .map_err(|e| err(e.to_string()))?;
    chart
        .draw_series(std::iter::once(Circle::new(
            (r.best_epoch, r.best_val_rmse_deg),
            5,
            GREEN.filled(),
        )))
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}
