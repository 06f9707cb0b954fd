//! `bowden sweep`: the paper's study of architectures × sequence lengths × directions over
//! several seeds (their Fig. 10): one training per configuration, run in parallel (one
//! configuration per thread), each finished run saved as its own JSON so an interrupted
//! sweep resumes where it stopped; then mean ± SD of the best validation RMSE per
//! (architecture, TCN block, L, direction) as Markdown, JSON and SVG.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use crate::arch::{Arch, Direction, ModelSpec, TcnBlock};
use crate::dataset::Dataset;
use crate::report::{write_json, LearnError};
use crate::train::{train, TrainConfig};
use crate::windows::{overall_rmse, PhySource, SplitConfig, WindowSet};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepConfig {
    pub archs: Vec<Arch>,
    pub seq_lens: Vec<usize>,
    /// Seeds 0 .. seeds−1.
    pub seeds: u64,
    pub directions: Vec<Direction>,
    /// Variants run for the TCN-based architectures.
    pub tcn_blocks: Vec<TcnBlock>,
    pub epochs: usize,
    pub early_stop: Option<usize>,
    pub split: SplitConfig,
    pub phy_source: PhySource,
    /// Configurations trained at once.
    pub jobs: usize,
}

/// One configuration of the sweep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct RunKey {
    pub arch: Arch,
    /// `None` for architectures without a TCN.
    pub tcn_block: Option<TcnBlock>,
    pub direction: Direction,
    pub seq_len: usize,
    pub seed: u64,
}

impl RunKey {
    pub fn model_label(&self) -> String {
        match self.tcn_block {
            Some(b) => format!("{} ({})", self.arch, b),
            None => self.arch.to_string(),
        }
    }

    fn file_name(&self) -> String {
        let model = match self.tcn_block {
            Some(b) => format!("{}-{}", self.arch, b),
            None => self.arch.to_string(),
        };
        format!("{model}_{}_L{}_s{}.json", self.direction, self.seq_len, self.seed)
    }
}

/// The saved result of one run (`runs/<key>.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunResult {
    pub key: RunKey,
    /// What makes the result reusable: same data, epochs, stopping, split and source.
    pub data_fnv1a64: String,
    pub epochs: usize,
    pub early_stop: Option<usize>,
    pub split: SplitConfig,
    pub phy_source: PhySource,
    pub params: usize,
    pub best_epoch: usize,
    pub epochs_run: usize,
    pub best_val_rmse_deg: f64,
    pub best_val_rmse_per_joint_deg: Vec<f64>,
    pub identity_val_rmse_deg: f64,
    pub val_rmse_curve_deg: Vec<f64>,
    pub seconds: f64,
}

/// Mean ± SD over seeds of one (model, direction, L).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupStats {
    pub model: String,
    pub arch: Arch,
    pub tcn_block: Option<TcnBlock>,
    pub direction: Direction,
    pub seq_len: usize,
    pub params: usize,
    pub n: usize,
    pub mean_rmse_deg: f64,
    /// Sample SD (n − 1); 0 for a single seed.
    pub sd_rmse_deg: f64,
    pub runs_rmse_deg: Vec<f64>,
    pub identity_rmse_deg: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepSummary {
    pub format: String,
    pub config: SweepConfig,
    pub data: String,
    pub runs: usize,
    pub reused: usize,
    pub groups: Vec<GroupStats>,
    /// Per direction, the models ordered by mean RMSE at each L (best first).
    pub ranking: BTreeMap<String, BTreeMap<usize, Vec<String>>>,
    pub markdown: String,
}

pub fn sweep_keys(cfg: &SweepConfig) -> Vec<RunKey> {
    let mut keys = Vec::new();
    for &arch in &cfg.archs {
        let blocks: Vec<Option<TcnBlock>> = if arch.has_tcn() {
            cfg.tcn_blocks.iter().map(|&b| Some(b)).collect()
        } else {
            vec![None]
        };
        for &direction in &cfg.directions {
            for &seq_len in &cfg.seq_lens {
                for &tcn_block in &blocks {
                    for seed in 0..cfg.seeds {
                        keys.push(RunKey {
                            arch,
                            tcn_block,
                            direction,
                            seq_len,
                            seed,
                        });
                    }
                }
            }
        }
    }
    keys
}

fn reusable(path: &Path, key: &RunKey, cfg: &SweepConfig, data_hash: &str) -> Option<RunResult> {
    let text = std::fs::read_to_string(path).ok()?;
    let r: RunResult = serde_json::from_str(&text).ok()?;
    (r.key == *key
        && r.data_fnv1a64 == data_hash
        && r.epochs == cfg.epochs
        && r.early_stop == cfg.early_stop
        && r.split == cfg.split
        && r.phy_source == cfg.phy_source)
        .then_some(r)
}

/// Runs (or resumes) a sweep over the dataset in `data_dir`, writing into `out_dir`.
pub fn run_sweep(
    data_dir: &Path,
    out_dir: &Path,
    cfg: &SweepConfig,
    progress: bool,
) -> Result<SweepSummary, LearnError> {
    let (ds, manifest) = Dataset::read_dir(data_dir)?;
    let runs_dir = out_dir.join("runs");
    std::fs::create_dir_all(&runs_dir).map_err(|source| LearnError::Io {
        path: runs_dir.clone(),
        source,
    })?;
    let keys = sweep_keys(cfg);
    let mut done: BTreeMap<RunKey, RunResult> = BTreeMap::new();
    let mut pending = Vec::new();
    for k in &keys {
        match reusable(&runs_dir.join(k.file_name()), k, cfg, &manifest.csv_fnv1a64) {
            Some(r) => {
                done.insert(*k, r);
            }
            None => pending.push(*k),
        }
    }
    let reused = done.len();
    // Windows per (direction, L), shared read-only by the workers.
    let mut windows: BTreeMap<(Direction, usize), WindowSet> = BTreeMap::new();
    for k in &pending {
        if let std::collections::btree_map::Entry::Vacant(e) = windows.entry((k.direction, k.seq_len)) {
            let w = WindowSet::build(&ds, k.direction, k.seq_len, cfg.split, cfg.phy_source).map_err(|source| {
                LearnError::Window {
                    dir: data_dir.to_path_buf(),
                    source,
                }
            })?;
            e.insert(w);
        }
    }
    let pb = if progress {
        let pb = ProgressBar::new(keys.len() as u64);
        pb.set_style(
            ProgressStyle::with_template("sweep [{bar:30}] {pos}/{len} runs {elapsed_precise} ETA {eta} {msg}")
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        pb
    } else {
        ProgressBar::hidden()
    };
    pb.set_position(reused as u64);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<RunResult>> = Mutex::new(Vec::new());
    let first_error: Mutex<Option<LearnError>> = Mutex::new(None);
    let jobs = cfg.jobs.clamp(1, pending.len().max(1));
    std::thread::scope(|s| {
        for _ in 0..jobs {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::SeqCst);
                let Some(k) = pending.get(i).copied() else { break };
                if first_error.lock().map(|e| e.is_some()).unwrap_or(true) {
                    break;
                }
                let res = run_one(&k, cfg, &windows[&(k.direction, k.seq_len)], &manifest.csv_fnv1a64)
                    .and_then(|r| write_json(&runs_dir.join(k.file_name()), &r).map(|_| r));
                match res {
                    Ok(r) => {
                        pb.set_message(format!(
                            "{} {} L={} s{}: {:.3}°",
                            k.model_label(),
                            k.direction,
                            k.seq_len,
                            k.seed,
                            r.best_val_rmse_deg
                        ));
                        pb.inc(1);
                        if let Ok(mut v) = results.lock() {
                            v.push(r);
                        }
                    }
                    Err(e) => {
                        if let Ok(mut slot) = first_error.lock() {
                            slot.get_or_insert(e);
                        }
                    }
                }
            });
        }
    });
    pb.finish();
    if let Some(e) = first_error.into_inner().ok().flatten() {
        return Err(e);
    }
    for r in results.into_inner().unwrap_or_default() {
        done.insert(r.key, r);
    }
    let summary = summarise(cfg, &data_dir.display().to_string(), &done, reused);
    write_json(&out_dir.join("sweep.json"), &summary)?;
    let md_path = out_dir.join("sweep.md");
    std::fs::write(&md_path, &summary.markdown).map_err(|source| LearnError::Io { path: md_path, source })?;
    plot_sweep(&out_dir.join("sweep.svg"), &summary)?;
    Ok(summary)
}

fn run_one(k: &RunKey, cfg: &SweepConfig, data: &WindowSet, data_hash: &str) -> Result<RunResult, LearnError> {
    let mut tc = TrainConfig::paper(k.arch, k.direction, k.seq_len, cfg.epochs, k.seed);
    tc.tcn_block = k.tcn_block.unwrap_or_default();
    tc.early_stop = cfg.early_stop;
    tc.threads = 1; // one configuration per core
    let t0 = Instant::now();
    let out = train(data, &tc, None)?;
    let best = out.best();
    Ok(RunResult {
        key: *k,
        data_fnv1a64: data_hash.to_string(),
        epochs: cfg.epochs,
        early_stop: cfg.early_stop,
        split: cfg.split,
        phy_source: cfg.phy_source,
        params: ModelSpec::new(k.arch, k.seq_len, data.joints, tc.tcn_block).param_count(),
        best_epoch: out.best_epoch,
        epochs_run: out.epochs.len(),
        best_val_rmse_deg: best.val_rmse_deg,
        best_val_rmse_per_joint_deg: best.val_rmse_per_joint_deg.clone(),
        identity_val_rmse_deg: overall_rmse(&data.identity_rmse_deg(&data.val)),
        val_rmse_curve_deg: out.epochs.iter().map(|e| e.val_rmse_deg).collect(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Mean and sample SD.
pub fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len().max(1) as f64;
    let mean = v.iter().sum::<f64>() / n;
    let sd = if v.len() > 1 {
        (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    (mean, sd)
}

pub fn summarise(cfg: &SweepConfig, data: &str, done: &BTreeMap<RunKey, RunResult>, reused: usize) -> SweepSummary {
    let mut groups: BTreeMap<(Direction, String, usize), Vec<&RunResult>> = BTreeMap::new();
    for (k, r) in done {
        groups
            .entry((k.direction, k.model_label(), k.seq_len))
            .or_default()
            .push(r);
    }
    let stats: Vec<GroupStats> = groups
        .iter()
        .map(|((direction, model, seq_len), rs)| {
            let v: Vec<f64> = rs.iter().map(|r| r.best_val_rmse_deg).collect();
            let (mean, sd) = mean_sd(&v);
            GroupStats {
                model: model.clone(),
                arch: rs[0].key.arch,
                tcn_block: rs[0].key.tcn_block,
                direction: *direction,
                seq_len: *seq_len,
                params: rs[0].params,
                n: v.len(),
                mean_rmse_deg: mean,
                sd_rmse_deg: sd,
                runs_rmse_deg: v,
                identity_rmse_deg: rs[0].identity_val_rmse_deg,
            }
        })
        .collect();
    let mut ranking: BTreeMap<String, BTreeMap<usize, Vec<String>>> = BTreeMap::new();
    for d in &cfg.directions {
        for &l in &cfg.seq_lens {
            let mut at: Vec<&GroupStats> = stats.iter().filter(|g| g.direction == *d && g.seq_len == l).collect();
            at.sort_by(|a, b| a.mean_rmse_deg.total_cmp(&b.mean_rmse_deg));
            ranking
                .entry(d.to_string())
                .or_default()
                .insert(l, at.iter().map(|g| g.model.clone()).collect());
        }
    }
    let markdown = markdown_table(cfg, data, &stats);
    SweepSummary {
        format: "bowden-sweep/1".into(),
        config: cfg.clone(),
        data: data.into(),
        runs: done.len(),
        reused,
        groups: stats,
        ranking,
        markdown,
    }
}

fn markdown_table(cfg: &SweepConfig, data: &str, stats: &[GroupStats]) -> String {
    let mut s = format!(
        "# Sweep: best validation RMSE (deg), mean ± SD over {} seed(s)\n\n\
         Data `{data}`, {} epochs{}, split {:.0}/{:.0} in {} contiguous block(s), physical angles from {:?}.\n\
         Identity = the raw hysteresis (predicting the target by the newest input).\n",
        cfg.seeds,
        cfg.epochs,
        cfg.early_stop.map_or(String::new(), |p| format!(" (early stop {p})")),
        (1.0 - cfg.split.val_fraction) * 100.0,
        cfg.split.val_fraction * 100.0,
        cfg.split.val_blocks,
        cfg.phy_source
    );
    let lens = &cfg.seq_lens;
    for d in &cfg.directions {
        s.push_str(&format!(
            "\n## {d}\n\n| model | params @ L={} |",
            lens.last().copied().unwrap_or(0)
        ));
        for l in lens {
            s.push_str(&format!(" L = {l} |"));
        }
        s.push_str("\n|---|---:|");
        for _ in lens {
            s.push_str("---:|");
        }
        s.push('\n');
        let mut models: Vec<String> = stats
            .iter()
            .filter(|g| g.direction == *d)
            .map(|g| g.model.clone())
            .collect();
        models.dedup();
        let mut seen = std::collections::BTreeSet::new();
        models.retain(|m| seen.insert(m.clone()));
        for m in &models {
            let params = stats
                .iter()
                .filter(|g| g.direction == *d && &g.model == m)
                .max_by_key(|g| g.seq_len)
                .map_or(0, |g| g.params);
            s.push_str(&format!("| {m} | {params} |"));
            for &l in lens {
                let best_here = stats
                    .iter()
                    .filter(|g| g.direction == *d && g.seq_len == l)
                    .map(|g| g.mean_rmse_deg)
                    .fold(f64::INFINITY, f64::min);
                match stats
                    .iter()
                    .find(|g| g.direction == *d && &g.model == m && g.seq_len == l)
                {
                    Some(g) if g.mean_rmse_deg == best_here => {
                        s.push_str(&format!(" **{:.2} ± {:.2}** |", g.mean_rmse_deg, g.sd_rmse_deg))
                    }
                    Some(g) => s.push_str(&format!(" {:.2} ± {:.2} |", g.mean_rmse_deg, g.sd_rmse_deg)),
                    None => s.push_str(" – |"),
                }
            }
            s.push('\n');
        }
        s.push_str("| identity | 0 |");
        for &l in lens {
            match stats.iter().find(|g| g.direction == *d && g.seq_len == l) {
                Some(g) => s.push_str(&format!(" {:.2} |", g.identity_rmse_deg)),
                None => s.push_str(" – |"),
            }
        }
        s.push('\n');
    }
    s
}

/// One panel per direction: mean RMSE against L per model, with ±SD bars; one colour per model
/// in every panel, the legend a strip above the panels.
pub fn plot_sweep(path: &Path, summary: &SweepSummary) -> Result<(), LearnError> {
    use crate::report::{legend_strip, LegendMark, LEGEND_STRIP_PX};
    let err = |e: String| LearnError::Plot {
        path: PathBuf::from(path),
        what: e,
    };
    let dirs = &summary.config.directions;
    let width = 560 * dirs.len().max(1) as u32;
    let root = SVGBackend::new(path, (width, 440 + LEGEND_STRIP_PX)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let (legend, root) = root.split_vertically(LEGEND_STRIP_PX);
    let panels = root.split_evenly((1, dirs.len().max(1)));
    let lens = &summary.config.seq_lens;
    let (lmin, lmax) = (
        lens.iter().copied().min().unwrap_or(0) as f64,
        lens.iter().copied().max().unwrap_or(1) as f64,
    );
    let palette = [
        BLUE,
        RED,
        GREEN,
        MAGENTA,
        CYAN,
        BLACK,
        RGBColor(230, 140, 0),
        RGBColor(120, 60, 20),
    ];
    // Models in order of appearance over every direction: the same colour in every panel.
    let mut models: Vec<String> = Vec::new();
    for g in &summary.groups {
        if !models.contains(&g.model) {
            models.push(g.model.clone());
        }
    }
    let colour = |m: &str| palette[models.iter().position(|x| x == m).unwrap_or(0) % palette.len()];
    let mut items: Vec<(String, LegendMark)> = models
        .iter()
        .map(|m| (m.clone(), LegendMark::Line(colour(m), 2)))
        .collect();
    items.push(("identity (raw hysteresis)".into(), LegendMark::Line(BLACK, 1)));
    legend_strip(&legend, &items).map_err(err)?;
    for (panel, d) in panels.iter().zip(dirs) {
        let gs: Vec<&GroupStats> = summary.groups.iter().filter(|g| g.direction == *d).collect();
        let ymax = gs
            .iter()
            .map(|g| (g.mean_rmse_deg + g.sd_rmse_deg).max(g.identity_rmse_deg))
            .fold(0.0, f64::max)
            * 1.1;
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{d} model: validation RMSE"), ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(32)
            .y_label_area_size(50)
            .build_cartesian_2d((lmin - 5.0)..(lmax + 5.0), 0.0..ymax.max(1e-6))
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("sequence length L")
            .y_desc("deg")
            .draw()
            .map_err(|e| err(e.to_string()))?;
        for m in &models {
            let color = colour(m);
            let mut pts: Vec<&GroupStats> = gs.iter().copied().filter(|g| &g.model == m).collect();
            if pts.is_empty() {
                continue;
            }
            pts.sort_by_key(|g| g.seq_len);
            chart
                .draw_series(LineSeries::new(
                    pts.iter().map(|g| (g.seq_len as f64, g.mean_rmse_deg)),
                    color.stroke_width(2),
                ))
                .map_err(|e| err(e.to_string()))?;
            chart
                .draw_series(pts.iter().map(|g| {
                    let x = g.seq_len as f64;
                    PathElement::new(
                        vec![
                            (x, g.mean_rmse_deg - g.sd_rmse_deg),
                            (x, g.mean_rmse_deg + g.sd_rmse_deg),
                        ],
                        color.stroke_width(1),
                    )
                }))
                .map_err(|e| err(e.to_string()))?;
            chart
                .draw_series(
                    pts.iter()
                        .map(|g| Circle::new((g.seq_len as f64, g.mean_rmse_deg), 3, color.filled())),
                )
                .map_err(|e| err(e.to_string()))?;
        }
        let mut ident: Vec<(f64, f64)> = gs.iter().map(|g| (g.seq_len as f64, g.identity_rmse_deg)).collect();
        ident.sort_by(|a, b| a.0.total_cmp(&b.0));
        ident.dedup_by(|a, b| a.0 == b.0);
        chart
            .draw_series(LineSeries::new(ident, BLACK.stroke_width(1)))
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}
