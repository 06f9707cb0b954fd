//! `bowden score`: a trained model on a dataset's validation windows — RMSE and MAE per joint
//! and pooled, against identity (the raw hysteresis: predicting the target by the newest
//! input), in the data's units (degrees), as a table, JSON and a plot of predicted against
//! measured over time.
//!
//! The windows are `train`'s: the split, the source of the physical angles and the history
//! decimation come from the model's training report (`NAME.report.json` beside it) when it is
//! there, and the RMSE is computed by the same forward pass in the same chunks as `train`'s
//! validation figure, so the two agree to the last bit on the data the model was trained on.

use crate::dataset::Dataset;
use crate::onnx::ModelFile;
use crate::report::{sidecar_paths, LearnError, TrainReport};
use crate::train::{rmse_per_joint_deg, TrainConfig};
use crate::windows::{overall_rmse, PhySource, SplitConfig, WindowSet};
use serde::Serialize;
use std::path::Path;

/// Which windows a model is scored on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScoreSettings {
    pub split: SplitConfig,
    pub phy: PhySource,
    /// Largest history decimation of the windows (`train --decimation`).
    pub decimation: usize,
    /// Chunk size of the validation pass (`train --batch-size`, at least 32).
    pub batch_size: usize,
    /// Where these came from: the training report's path, or "given".
    pub from: String,
}

impl ScoreSettings {
    /// `train`'s settings for the model at `onnx`, from its training report, if it has one.
    pub fn of_model(onnx: &Path) -> Result<Option<Self>, LearnError> {
        let (json, _) = sidecar_paths(onnx);
        let Ok(text) = std::fs::read_to_string(&json) else {
            return Ok(None);
        };
        let r: TrainReport = serde_json::from_str(&text).map_err(|source| LearnError::Json {
            path: json.clone(),
            source,
        })?;
        Ok(Some(Self {
            split: r.data.split,
            phy: r.data.phy_source,
            decimation: r.config.decimation,
            batch_size: r.config.batch_size,
            from: json.display().to_string(),
        }))
    }

    /// `train`'s defaults (the paper's 80/20 contiguous split on the vision estimate).
    pub fn given(split: SplitConfig, phy: PhySource, decimation: usize) -> Self {
        let paper = TrainConfig::paper(crate::Architecture::Tcn, crate::Direction::Forward, 80, 1, 0);
        Self {
            split,
            phy,
            decimation,
            batch_size: paper.batch_size,
            from: "given".into(),
        }
    }
}

/// The figures of one model.
#[derive(Debug, Clone, Serialize)]
pub struct Score {
    pub model: String,
    pub architecture: String,
    pub direction: String,
    pub seq_len: usize,
    pub data: String,
    pub settings: ScoreSettings,
    pub windows: usize,
    pub rmse_deg: f64,
    pub rmse_per_joint_deg: Vec<f64>,
    pub mae_deg: f64,
    pub mae_per_joint_deg: Vec<f64>,
    pub identity_rmse_deg: f64,
    pub identity_rmse_per_joint_deg: Vec<f64>,
    pub identity_mae_deg: f64,
    pub identity_mae_per_joint_deg: Vec<f64>,
    /// The best validation RMSE the training report quotes, for comparison.
    pub train_report_val_rmse_deg: Option<f64>,
}

/// Measured and predicted values over the validation windows, in time order (for the plot).
#[derive(Debug, Clone, Default)]
pub struct ScoreSeries {
    /// Per joint.
    pub measured_deg: Vec<Vec<f64>>,
    pub predicted_deg: Vec<Vec<f64>>,
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Scores the model at `onnx` on the dataset directory `data_dir`.
pub fn score(onnx: &Path, data_dir: &Path, s: &ScoreSettings) -> Result<(Score, ScoreSeries), LearnError> {
    let model = ModelFile::load(onnx)?;
    let (ds, _) = Dataset::read_dir(data_dir)?;
    let window_error = |source| LearnError::Window {
        dir: data_dir.to_path_buf(),
        source,
    };
    let mut ws = WindowSet::build(&ds, model.direction, model.spec.seq_len, s.split, s.phy).map_err(window_error)?;
    ws.set_decimation(s.decimation).map_err(window_error)?;
    // The model's own normalisation (on its training data it is the one fitted here).
    let ws = ws
        .with_normalisers(model.norm_in.clone(), model.norm_out.clone())
        .map_err(window_error)?;
    let ids = ws.val.clone();
    let rmse = rmse_per_joint_deg(&model, &ws, &ids, s.batch_size)?;
    let (l, j) = (model.spec.seq_len, model.spec.joints);
    let mut series = ScoreSeries {
        measured_deg: vec![Vec::with_capacity(ids.len()); j],
        predicted_deg: vec![Vec::with_capacity(ids.len()); j],
    };
    let (mut abs, mut id_abs) = (vec![0.0f64; j], vec![0.0f64; j]);
    let mut windows = Vec::with_capacity(256 * l * j);
    let mut ordered = ids.clone();
    ordered.sort_unstable();
    for chunk in ordered.chunks(256) {
        windows.clear();
        for &t in chunk {
            windows.extend(ws.window_deg(t).iter().map(|&v| v as f32));
        }
        let pred = model.predict_deg(&windows, chunk.len());
        for (i, &t) in chunk.iter().enumerate() {
            let (target, newest) = (&ws.target_deg[t * j..(t + 1) * j], &ws.input_deg[t * j..(t + 1) * j]);
            for k in 0..j {
                let p = pred[i * j + k] as f64;
                abs[k] += (p - target[k]).abs();
                id_abs[k] += (newest[k] - target[k]).abs();
                series.measured_deg[k].push(target[k]);
                series.predicted_deg[k].push(p);
            }
        }
    }
    let n = ids.len().max(1) as f64;
    let mae: Vec<f64> = abs.iter().map(|a| a / n).collect();
    let id_mae: Vec<f64> = id_abs.iter().map(|a| a / n).collect();
    let id_rmse = ws.identity_rmse_deg(&ids);
    let train_rmse = std::fs::read_to_string(sidecar_paths(onnx).0)
        .ok()
        .and_then(|t| serde_json::from_str::<TrainReport>(&t).ok())
        .map(|r| r.best_val_rmse_deg);
    Ok((
        Score {
            model: onnx.display().to_string(),
            architecture: model.spec.arch.to_string(),
            direction: model.direction.to_string(),
            seq_len: l,
            data: data_dir.display().to_string(),
            settings: s.clone(),
            windows: ids.len(),
            rmse_deg: overall_rmse(&rmse),
            rmse_per_joint_deg: rmse,
            mae_deg: mean(&mae),
            mae_per_joint_deg: mae,
            identity_rmse_deg: overall_rmse(&id_rmse),
            identity_rmse_per_joint_deg: id_rmse,
            identity_mae_deg: mean(&id_mae),
            identity_mae_per_joint_deg: id_mae,
            train_report_val_rmse_deg: train_rmse,
        },
        series,
    ))
}

/// The table of several scores (one row per model and per joint, then pooled).
pub fn to_markdown(scores: &[Score]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    for sc in scores {
        let _ = writeln!(
            s,
            "{} ({} {} L={}) on {}: {} validation windows ({}, split {} × {:.0} %, {}, decimation {})\n",
            sc.model,
            sc.architecture,
            sc.direction,
            sc.seq_len,
            sc.data,
            sc.windows,
            if sc.settings.from == "given" {
                "settings given".to_string()
            } else {
                format!("settings of {}", sc.settings.from)
            },
            sc.settings.split.val_blocks,
            sc.settings.split.val_fraction * 100.0,
            sc.settings.phy,
            sc.settings.decimation
        );
        let _ = writeln!(
            s,
            "| joint | RMSE (deg) | MAE (deg) | identity RMSE | identity MAE |\n|---|---:|---:|---:|---:|"
        );
        for k in 0..sc.rmse_per_joint_deg.len() {
            let _ = writeln!(
                s,
                "| q{} | {:.3} | {:.3} | {:.3} | {:.3} |",
                k + 1,
                sc.rmse_per_joint_deg[k],
                sc.mae_per_joint_deg[k],
                sc.identity_rmse_per_joint_deg[k],
                sc.identity_mae_per_joint_deg[k]
            );
        }
        let _ = writeln!(
            s,
            "| pooled | {:.3} | {:.3} | {:.3} | {:.3} |",
            sc.rmse_deg, sc.mae_deg, sc.identity_rmse_deg, sc.identity_mae_deg
        );
        if let Some(t) = sc.train_report_val_rmse_deg {
            let _ = writeln!(s, "\n`train` reported {t:.3}° for this model's best epoch.");
        }
        s.push('\n');
    }
    s
}

/// Predicted against measured over the validation windows, one panel per joint.
pub fn plot(path: &Path, sc: &Score, series: &ScoreSeries) -> Result<(), LearnError> {
    use plotters::prelude::*;
    let err = |e: String| LearnError::Plot {
        path: path.to_path_buf(),
        what: e,
    };
    let j = series.measured_deg.len();
    let panel_h = 200u32;
    let root = SVGBackend::new(path, (1000, panel_h * j as u32 + 40)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (title, body) = root.split_vertically(40);
    title
        .draw(&Text::new(
            format!(
                "{} {} L={}: measured (black) and predicted (red) on {} validation windows; RMSE {:.3}° (identity {:.3}°)",
                sc.architecture, sc.direction, sc.seq_len, sc.windows, sc.rmse_deg, sc.identity_rmse_deg
            ),
            (10, 12),
            ("sans-serif", 14),
        ))
        .map_err(|e| err(e.to_string()))?;
    for (k, area) in body.split_evenly((j, 1)).iter().enumerate() {
        let (m, p) = (&series.measured_deg[k], &series.predicted_deg[k]);
        let lo = m.iter().chain(p).copied().fold(f64::INFINITY, f64::min);
        let hi = m.iter().chain(p).copied().fold(f64::NEG_INFINITY, f64::max);
        let (lo, hi) = if lo.is_finite() && hi > lo {
            (lo, hi)
        } else {
            (-1.0, 1.0)
        };
        let mut chart = ChartBuilder::on(area)
            .margin(6)
            .x_label_area_size(22)
            .y_label_area_size(50)
            .build_cartesian_2d(0..m.len().max(1), lo..hi)
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .y_desc(format!("q{} (deg)", k + 1))
            .disable_x_mesh()
            .draw()
            .map_err(|e| err(e.to_string()))?;
        chart
            .draw_series(LineSeries::new(m.iter().enumerate().map(|(i, &v)| (i, v)), BLACK))
            .map_err(|e| err(e.to_string()))?;
        chart
            .draw_series(LineSeries::new(p.iter().enumerate().map(|(i, &v)| (i, v)), RED))
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))
}
