//! Aggregation of runs into the paper's Table V and Table VI, and the report files: Markdown,
//! JSON and SVG plots (desired vs reached path, error along the path; Fig. 12/13).

use crate::metrics::{ee_pose, joint_errors, pose_from_estimate, reduction_pct, task_errors, JointErrors, TaskErrors};
use crate::{EvalError, RunRecord};
use bowden_kinematics::{JointsDeg, Robot, JOINT_NAMES, N_JOINTS};
use plotters::prelude::*;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Table V and VI of one (trajectory, controller), pooled over its repeats.
#[derive(Debug, Clone, Serialize)]
pub struct Cell {
    pub trajectory: String,
    pub controller: String,
    pub repeats: usize,
    /// Measured by the vision estimate (as the paper did); invalid estimates are left out.
    pub task_vision: TaskErrors,
    pub joint_vision: JointErrors,
    /// Measured by the simulator's truth.
    pub task_truth: TaskErrors,
    pub joint_truth: JointErrors,
    pub invalid_estimates: usize,
    pub mean_refine_iterations: f64,
}

/// Everything a report holds.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub trajectories: Vec<String>,
    pub controllers: Vec<String>,
    pub cells: Vec<Cell>,
    /// Per controller, pooled over all trajectories ("Average Value" of Table V).
    pub average: Vec<Cell>,
}

impl Summary {
    pub fn cell(&self, trajectory: &str, controller: &str) -> Option<&Cell> {
        self.cells
            .iter()
            .chain(&self.average)
            .find(|c| c.trajectory == trajectory && c.controller == controller)
    }
}

/// Table V and VI of `runs` pooled into one cell labelled (`trajectory`, `controller`).
/// `invalid_estimates` is the sum of the runs' own counts.
pub fn pool(robot: &Robot, trajectory: &str, controller: &str, runs: &[&RunRecord]) -> Cell {
    let mut task_v = Vec::new();
    let mut task_t = Vec::new();
    let mut joint_v: Vec<(JointsDeg, JointsDeg)> = Vec::new();
    let mut joint_t: Vec<(JointsDeg, JointsDeg)> = Vec::new();
    let (mut invalid, mut iters, mut n) = (0, 0u64, 0u64);
    for r in runs {
        invalid += r.invalid_estimates;
        for p in &r.points {
            let desired = ee_pose(robot, &p.q_desired_deg);
            task_t.push((desired, ee_pose(robot, &p.q_true_deg)));
            joint_t.push((p.q_desired_deg, p.q_true_deg));
            if let (Some(q), Some((pos, quat))) = (p.q_est_deg, p.ee_est) {
                if let Some(pose) = pose_from_estimate(&pos, &quat) {
                    task_v.push((desired, pose));
                    joint_v.push((p.q_desired_deg, q));
                }
            }
            iters += u64::from(p.refine_iterations);
            n += 1;
        }
    }
    Cell {
        trajectory: trajectory.into(),
        controller: controller.into(),
        repeats: runs.len(),
        task_vision: task_errors(&task_v),
        joint_vision: joint_errors(&joint_v),
        task_truth: task_errors(&task_t),
        joint_truth: joint_errors(&joint_t),
        invalid_estimates: invalid,
        mean_refine_iterations: if n == 0 { 0.0 } else { iters as f64 / n as f64 },
    }
}

/// Pools the runs by (trajectory, controller) and over all trajectories.
pub fn summarise(robot: &Robot, runs: &[RunRecord]) -> Summary {
    let mut trajectories: Vec<String> = Vec::new();
    let mut controllers: Vec<String> = Vec::new();
    for r in runs {
        if !trajectories.contains(&r.trajectory) {
            trajectories.push(r.trajectory.clone());
        }
        if !controllers.contains(&r.controller) {
            controllers.push(r.controller.clone());
        }
    }
    let mut cells = Vec::new();
    for t in &trajectories {
        for c in &controllers {
            let sel: Vec<&RunRecord> = runs
                .iter()
                .filter(|r| &r.trajectory == t && &r.controller == c)
                .collect();
            if !sel.is_empty() {
                cells.push(pool(robot, t, c, &sel));
            }
        }
    }
    let average = controllers
        .iter()
        .map(|c| {
            let sel: Vec<&RunRecord> = runs.iter().filter(|r| &r.controller == c).collect();
            pool(robot, "average", c, &sel)
        })
        .collect();
    Summary {
        trajectories,
        controllers,
        cells,
        average,
    }
}

fn table_v(s: &Summary, by_truth: bool) -> String {
    let cols: Vec<(String, String)> = s
        .trajectories
        .iter()
        .chain(std::iter::once(&"average".to_string()))
        .flat_map(|t| s.controllers.iter().map(move |c| (t.clone(), c.clone())))
        .collect();
    let mut out = String::new();
    let _ = write!(out, "| MAE on unseen trajectory |");
    for (t, c) in &cols {
        let _ = write!(out, " {t}: {c} |");
    }
    let _ = write!(out, "\n|---|");
    for _ in &cols {
        let _ = write!(out, "---|");
    }
    out.push('\n');
    type Row = (&'static str, fn(&TaskErrors) -> String);
    let rows: [Row; 5] = [
        ("X error [mm]", |e| format!("{:.2}", e.x_mae_mm)),
        ("Y error [mm]", |e| format!("{:.2}", e.y_mae_mm)),
        ("Z error [mm]", |e| format!("{:.2}", e.z_mae_mm)),
        ("Total position error [mm]", |e| {
            format!("{:.2} ± {:.1}", e.pos_mean_mm, e.pos_sd_mm)
        }),
        ("Orientation error [°]", |e| {
            format!("{:.2} ± {:.1}", e.rot_mean_deg, e.rot_sd_deg)
        }),
    ];
    for (name, f) in rows {
        let _ = write!(out, "| {name} |");
        for (t, c) in &cols {
            let cell = s
                .cell(t, c)
                .map(|x| if by_truth { &x.task_truth } else { &x.task_vision });
            let _ = write!(out, " {} |", cell.map(f).unwrap_or_default());
        }
        out.push('\n');
    }
    // Reduction of every controller against the uncalibrated one.
    if s.controllers.iter().any(|c| c == "uncalibrated") {
        for (name, pick) in [
            ("Position error reduction vs uncalibrated (+ = better)", 0usize),
            ("Orientation error reduction vs uncalibrated (+ = better)", 1usize),
        ] {
            let _ = write!(out, "| {name} |");
            for (t, c) in &cols {
                let get = |ctrl: &str| {
                    s.cell(t, ctrl).map(|x| {
                        let e = if by_truth { &x.task_truth } else { &x.task_vision };
                        if pick == 0 {
                            e.pos_mean_mm
                        } else {
                            e.rot_mean_deg
                        }
                    })
                };
                let txt = match (get("uncalibrated"), get(c)) {
                    (Some(u), Some(v)) if c != "uncalibrated" => format!("{:+.1} %", reduction_pct(u, v)),
                    _ => String::new(),
                };
                let _ = write!(out, " {txt} |");
            }
            out.push('\n');
        }
    }
    out
}

fn table_vi(s: &Summary, trajectory: &str, by_truth: bool) -> String {
    let mut out = String::from("| controller | |");
    for n in JOINT_NAMES {
        let _ = write!(out, " {n} [°] |");
    }
    out.push_str("\n|---|---|");
    for _ in 0..N_JOINTS {
        out.push_str("---|");
    }
    out.push('\n');
    for c in &s.controllers {
        if let Some(cell) = s.cell(trajectory, c) {
            let j = if by_truth {
                &cell.joint_truth
            } else {
                &cell.joint_vision
            };
            for (label, v) in [("MAE", &j.mae_deg), ("SD", &j.sd_deg)] {
                let _ = write!(out, "| {c} | {label} |");
                for x in v {
                    let _ = write!(out, " {x:.2} |");
                }
                out.push('\n');
            }
        }
    }
    out
}

/// The Markdown report.
pub fn markdown(s: &Summary, header: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# Tracking on unseen trajectories\n\n{header}\n");
    let _ = writeln!(
        out,
        "## Table V — task space, measured by vision (as the paper did)\n\n{}",
        table_v(s, false)
    );
    let _ = writeln!(out, "## Table V — task space, simulator truth\n\n{}", table_v(s, true));
    for t in s.trajectories.iter().chain(std::iter::once(&"average".to_string())) {
        let _ = writeln!(
            out,
            "## Table VI — joint errors, {t} trajectory, vision\n\n{}",
            table_vi(s, t, false)
        );
        let _ = writeln!(
            out,
            "## Table VI — joint errors, {t} trajectory, truth\n\n{}",
            table_vi(s, t, true)
        );
    }
    let _ = writeln!(out, "## Estimates and refinement\n");
    let _ = writeln!(out, "| trajectory | controller | points | invalid vision estimates | mean refinement iterations |\n|---|---|---|---|---|");
    for c in &s.cells {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {:.1} |",
            c.trajectory, c.controller, c.task_truth.n, c.invalid_estimates, c.mean_refine_iterations
        );
    }
    out
}

fn plot_err(e: &dyn std::fmt::Display, path: &Path) -> EvalError {
    EvalError::Run {
        what: path.display().to_string(),
        message: e.to_string(),
    }
}

const COLOURS: [RGBColor; 4] = [
    RGBColor(200, 40, 40),
    RGBColor(30, 110, 200),
    RGBColor(20, 150, 60),
    RGBColor(150, 80, 180),
];

/// Event markers (vertical lines): black, orange, grey.
const MARKER_COLOURS: [RGBColor; 3] = [RGBColor(0, 0, 0), RGBColor(230, 130, 0), RGBColor(120, 120, 120)];

type Range = std::ops::Range<f64>;

/// One SVG line chart: an optional black reference line and coloured series, with a legend.
fn line_plot(
    file: &Path,
    size: (u32, u32),
    caption: &str,
    axes: (&str, &str),
    ranges: (Range, Range),
    reference: Option<(&str, &[(f64, f64)])>,
    series: &[(String, Vec<(f64, f64)>)],
) -> Result<(), EvalError> {
    line_plot_marked(
        file,
        size,
        caption,
        axes,
        ranges,
        reference,
        series,
        &[],
        SeriesLabelPosition::MiddleRight,
    )
}

/// [`line_plot`] with vertical marker lines at the given x values, each in the legend (events on
/// a time axis: a slip, the start of creep), and the legend where it is asked for.
#[allow(clippy::too_many_arguments)]
pub(crate) fn line_plot_marked(
    file: &Path,
    size: (u32, u32),
    caption: &str,
    (x_desc, y_desc): (&str, &str),
    (x_range, y_range): (Range, Range),
    reference: Option<(&str, &[(f64, f64)])>,
    series: &[(String, Vec<(f64, f64)>)],
    markers: &[(String, f64)],
    legend: SeriesLabelPosition,
) -> Result<(), EvalError> {
    let (y_lo, y_hi) = (y_range.start, y_range.end);
    let err = |e: &dyn std::fmt::Display| plot_err(e, file);
    let root = SVGBackend::new(file, size).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(x_range, y_range)
        .map_err(|e| err(&e))?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .draw()
        .map_err(|e| err(&e))?;
    if let Some((name, line)) = reference {
        chart
            .draw_series(LineSeries::new(line.iter().copied(), BLACK.stroke_width(3)))
            .map_err(|e| err(&e))?
            .label(name)
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.stroke_width(3)));
    }
    for (i, (name, x)) in markers.iter().enumerate() {
        let c = MARKER_COLOURS[i % MARKER_COLOURS.len()];
        chart
            .draw_series(LineSeries::new([(*x, y_lo), (*x, y_hi)], c.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    for (i, (name, v)) in series.iter().enumerate() {
        let c = COLOURS[i % COLOURS.len()];
        chart
            .draw_series(LineSeries::new(v.iter().copied(), c.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(legend)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))
}

/// Fig. 12-style plots of one trajectory: desired vs reached tip path (y–z projection, across
/// the manipulator's axis) and the position error along the path, for repeat 0 of each
/// controller (simulator truth). Returns the files written.
pub fn plots(robot: &Robot, runs: &[RunRecord], trajectory: &str, dir: &Path) -> Result<Vec<PathBuf>, EvalError> {
    let sel: Vec<&RunRecord> = runs
        .iter()
        .filter(|r| r.trajectory == trajectory && r.repeat == 0)
        .collect();
    let Some(first) = sel.first() else {
        return Ok(Vec::new());
    };
    let tip = |q: &JointsDeg| ee_pose(robot, q).translation.vector;
    let desired: Vec<(f64, f64)> = first
        .points
        .iter()
        .map(|p| tip(&p.q_desired_deg))
        .map(|v| (v.y, v.z))
        .collect();
    let mut all: Vec<(f64, f64)> = desired.clone();
    let reached: Vec<(String, Vec<(f64, f64)>)> = sel
        .iter()
        .map(|r| {
            let v: Vec<(f64, f64)> = r
                .points
                .iter()
                .map(|p| tip(&p.q_true_deg))
                .map(|v| (v.y, v.z))
                .collect();
            all.extend(&v);
            (r.controller.clone(), v)
        })
        .collect();
    let (mut y0, mut y1, mut z0, mut z1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (y, z) in &all {
        y0 = y0.min(*y);
        y1 = y1.max(*y);
        z0 = z0.min(*z);
        z1 = z1.max(*z);
    }
    let pad = 2.0;
    let path_file = dir.join(format!("path_{trajectory}.svg"));
    line_plot(
        &path_file,
        (760, 640),
        &format!("{trajectory}: desired vs reached tip path (truth, repeat 0)"),
        ("y [mm]", "z [mm]"),
        ((y0 - pad)..(y1 + pad), (z0 - pad)..(z1 + pad)),
        Some(("desired", &desired)),
        &reached,
    )?;
    let err_file = dir.join(format!("error_{trajectory}.svg"));
    let series: Vec<(String, Vec<(f64, f64)>)> = sel
        .iter()
        .map(|r| {
            let v = r
                .points
                .iter()
                .enumerate()
                .map(|(i, p)| (i as f64, (tip(&p.q_true_deg) - tip(&p.q_desired_deg)).norm()))
                .collect();
            (r.controller.clone(), v)
        })
        .collect();
    let n = first.points.len().max(2) as f64;
    let ymax = series
        .iter()
        .flat_map(|(_, v)| v.iter().map(|p| p.1))
        .fold(1.0f64, f64::max)
        * 1.1;
    line_plot(
        &err_file,
        (900, 420),
        &format!("{trajectory}: tip position error along the path (truth)"),
        ("trajectory point (model step)", "position error [mm]"),
        (0.0..n, 0.0..ymax),
        None,
        &series,
    )?;
    Ok(vec![path_file, err_file])
}

/// Writes `report.md`, `report.json` (summary and every run) and the plots into `dir`.
pub fn write_report(
    robot: &Robot,
    runs: &[RunRecord],
    summary: &Summary,
    header: &str,
    dir: &Path,
) -> Result<Vec<PathBuf>, EvalError> {
    std::fs::create_dir_all(dir).map_err(|source| EvalError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files = Vec::new();
    let md = dir.join("report.md");
    std::fs::write(&md, markdown(summary, header)).map_err(|source| EvalError::Io {
        path: md.clone(),
        source,
    })?;
    files.push(md);
    let json = dir.join("report.json");
    let value = serde_json::json!({ "summary": summary, "runs": runs });
    std::fs::write(&json, serde_json::to_string_pretty(&value).unwrap_or_default()).map_err(|source| {
        EvalError::Io {
            path: json.clone(),
            source,
        }
    })?;
    files.push(json);
    for t in &summary.trajectories {
        files.extend(plots(robot, runs, t, dir)?);
    }
    Ok(files)
}
