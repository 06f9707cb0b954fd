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

/// One column of the paper's Table V: mean ± SD of the total position error (mm) and of the
/// orientation error (°), uncalibrated and calibrated.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PaperTableV {
    pub trajectory: &'static str,
    pub uncalibrated_mm: (f64, f64),
    pub uncalibrated_deg: (f64, f64),
    pub calibrated_mm: (f64, f64),
    pub calibrated_deg: (f64, f64),
}

/// The paper's Table V (Park et al., RA-L 2024; measured by vision on the real robot, 5 repeats,
/// calibrated = Algorithm 1 with the TCN pair, L = 80): random, circle, zigzag and its
/// "Average Value" column.
pub const PAPER_TABLE_V: [PaperTableV; 4] = [
    PaperTableV {
        trajectory: "random",
        uncalibrated_mm: (11.86, 6.8),
        uncalibrated_deg: (24.74, 13.9),
        calibrated_mm: (5.47, 3.5),
        calibrated_deg: (10.41, 5.9),
    },
    PaperTableV {
        trajectory: "circle",
        uncalibrated_mm: (13.46, 5.4),
        uncalibrated_deg: (33.88, 15.2),
        calibrated_mm: (4.96, 3.1),
        calibrated_deg: (10.65, 5.1),
    },
    PaperTableV {
        trajectory: "zigzag",
        uncalibrated_mm: (16.16, 9.4),
        uncalibrated_deg: (34.89, 18.1),
        calibrated_mm: (5.64, 3.3),
        calibrated_deg: (12.58, 5.9),
    },
    PaperTableV {
        trajectory: "average",
        uncalibrated_mm: (13.70, 7.2),
        uncalibrated_deg: (31.17, 15.7),
        calibrated_mm: (5.29, 3.3),
        calibrated_deg: (11.21, 5.6),
    },
];

/// The "bowden vs the paper" section of `report.md`: bowden's mean tip position / orientation
/// errors (vision and truth, every controller) beside the paper's Table V, with the reductions
/// against the uncalibrated controller and why the absolute figures differ.
pub fn paper_comparison(s: &Summary) -> String {
    let cols: Vec<String> = s
        .trajectories
        .iter()
        .cloned()
        .chain(std::iter::once("average".to_string()))
        .collect();
    let paper = |t: &str| PAPER_TABLE_V.iter().find(|p| p.trajectory == t);
    let pair = |mm: f64, deg: f64| format!("{mm:.2} mm / {deg:.2}°");
    let red = |pos: f64, rot: f64| format!("{pos:+.1} % / {rot:+.1} %");
    let mut out = String::new();
    let _ = writeln!(out, "## bowden vs the paper (Table V)\n");
    let _ = writeln!(
        out,
        "Mean tip position error / mean orientation error on each unseen path, and the reduction of each \
         calibrated controller against the uncalibrated one (+ = better). The paper's rows are its Table V \
         (the real robot, measured by vision, 5 repeats; calibrated = Algorithm 1 with its TCN pair). \
         bowden's rows are this report's controllers (`paper`: Algorithm 1, `newton`: the Gauss–Newton refinement), \
         measured by vision (as the paper did) and by the simulator's truth. \
         \"average\" pools every point of every path of this run, as the paper's \"Average Value\" column \
         does; \"—\" marks a path the paper did not run.\n"
    );
    let _ = write!(out, "| | ");
    let _ = writeln!(out, "{} |", cols.join(" | "));
    let _ = writeln!(out, "|---|{}", "---|".repeat(cols.len()));
    let row = |label: &str, f: &dyn Fn(&str) -> Option<String>| -> String {
        let cells: Vec<String> = cols.iter().map(|t| f(t).unwrap_or_else(|| "—".into())).collect();
        format!("| {label} | {} |\n", cells.join(" | "))
    };
    out += &row("paper: uncalibrated", &|t| {
        paper(t).map(|p| pair(p.uncalibrated_mm.0, p.uncalibrated_deg.0))
    });
    out += &row("paper: calibrated", &|t| {
        paper(t).map(|p| pair(p.calibrated_mm.0, p.calibrated_deg.0))
    });
    out += &row("paper: reduction", &|t| {
        paper(t).map(|p| {
            red(
                reduction_pct(p.uncalibrated_mm.0, p.calibrated_mm.0),
                reduction_pct(p.uncalibrated_deg.0, p.calibrated_deg.0),
            )
        })
    });
    for (by, by_truth) in [("vision", false), ("truth", true)] {
        let task = |t: &str, c: &str| {
            s.cell(t, c)
                .map(|x| if by_truth { x.task_truth } else { x.task_vision })
        };
        for c in &s.controllers {
            out += &row(&format!("bowden: {c} ({by})"), &|t| {
                task(t, c).map(|e| pair(e.pos_mean_mm, e.rot_mean_deg))
            });
            if c != "uncalibrated" {
                out += &row(
                    &format!("bowden: {c} reduction ({by})"),
                    &|t| match (task(t, "uncalibrated"), task(t, c)) {
                        (Some(u), Some(e)) => Some(red(
                            reduction_pct(u.pos_mean_mm, e.pos_mean_mm),
                            reduction_pct(u.rot_mean_deg, e.rot_mean_deg),
                        )),
                        _ => None,
                    },
                );
            }
        }
    }
    let _ = writeln!(out, "\nWhy the absolute figures differ:\n");
    if let Some(u) = s.cell("average", "uncalibrated") {
        let _ = writeln!(
            out,
            "- **Path size.** The uncalibrated robot misses this run's paths by {:.2} mm / {:.2}° on \
             average (vision), the paper's by 13.70 mm / 31.17°. The absolute errors scale with how far and \
             how much the robot must bend and reverse; the relative reduction is the comparable figure.",
            u.task_vision.pos_mean_mm, u.task_vision.rot_mean_deg
        );
    }
    let _ = writeln!(
        out,
        "- **The paths.** bowden's default paths (`configs/trajectories/`) are smaller than the paper's: \
         the default plant's uncalibrated error on them is 6.4 mm / 11.7°. \
         `configs/trajectories/large/` holds the same three kinds made as large as the simulated robot can \
         follow (uncalibrated 11.7 mm / 22.7° on the default plant): \
         `bowden evaluate --trajectories-dir configs/trajectories/large`.\n\
         - **A simulated plant.** The robot here is a tendon-sheath model tuned so that its command vs \
         physical statistics on the eq. (16) dataset lie in the range of the paper's Table IV; it is not the \
         paper's robot, and the models are trained and evaluated \
         on that one simulated unit. What the model leaves out (temperature, wear, contact, slack unless a \
         plant file asks for it) cannot hurt the controller here.\n\
         - **Measurement.** bowden's vision is a synthetic RGBD camera and the same estimator; its error \
         against the truth is what separates the vision and truth rows. The paper's calibrated error also \
         holds its real camera's estimation error, which no controller removes.\n\
         - **The controller.** bowden's calibrated rows are the controller named in the header (its models \
         trained on mixed excitation, with the safe refinement); the paper's is Algorithm 1 with TCNs trained \
         on eq. (16) data alone (`docs/results/paper-protocol/` runs that protocol here)."
    );
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
    // The side-by-side with the paper is appended: what comes before it is `markdown` unchanged.
    let text = markdown(summary, header) + "\n" + &paper_comparison(summary);
    std::fs::write(&md, text).map_err(|source| EvalError::Io {
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
        files.extend(crate::figures::fig12(robot, runs, t, dir)?);
        files.extend(crate::figures::fig13(runs, t, dir)?);
    }
    Ok(files)
}
