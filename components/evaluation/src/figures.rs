//! The paper's Fig. 12 and Fig. 13 from `bowden evaluate`'s runs (repeat 0 of every controller),
//! written beside `report.md`:
//!
//! - `fig12_<trajectory>.svg` (Fig. 12): the desired tip path against the reached one, by vision
//!   (the estimator's end-effector pose, as the paper measured) and by the simulator's truth (FK
//!   of the plant's true q), in the three views x–y, x–z and y–z, one row per controller; below,
//!   the tip position and orientation errors along the path, every controller, vision and truth.
//! - `fig13_<trajectory>.svg` (Fig. 13; the paper's is the zigzag path): the forceps angles q4 and
//!   q5, desired against reached (vision and truth) along the path, one row per controller, and
//!   below their absolute errors.
//!
//! Each figure's legend is a strip above its panels, so it never covers data.

use crate::metrics::{ee_pose, pose_distance, pose_from_estimate};
use crate::{EvalError, RunRecord};
use bowden_kinematics::Robot;
use nalgebra::Isometry3;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::{Path, PathBuf};

/// One colour per controller, in the order the runs name them (uncalibrated first: red).
pub(crate) const CONTROLLER_COLOURS: [RGBColor; 4] = [
    RGBColor(200, 40, 40),
    RGBColor(30, 110, 200),
    RGBColor(20, 150, 60),
    RGBColor(150, 80, 180),
];

/// How a legend entry is drawn.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Swatch {
    /// A solid line.
    Line(RGBColor),
    /// A dashed line.
    Dashed(RGBColor),
    /// A hollow circle (a marker per point).
    Ring(RGBColor),
}

/// A legend laid out left to right on its own strip (above the panels, off the data).
pub(crate) fn legend_strip<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    items: &[(String, Swatch)],
) -> Result<(), String> {
    const FONT_PX: u32 = 15;
    let style = TextStyle::from(("sans-serif", FONT_PX).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let y = area.dim_in_pixel().1 as i32 / 2;
    let mut x = 14i32;
    for (label, swatch) in items {
        match *swatch {
            Swatch::Line(c) => area
                .draw(&PathElement::new(vec![(x, y), (x + 26, y)], c.stroke_width(2)))
                .map_err(|e| e.to_string())?,
            Swatch::Dashed(c) => {
                for k in 0..3 {
                    area.draw(&PathElement::new(
                        vec![(x + 10 * k, y), (x + 10 * k + 6, y)],
                        c.stroke_width(2),
                    ))
                    .map_err(|e| e.to_string())?;
                }
            }
            Swatch::Ring(c) => area
                .draw(&Circle::new((x + 13, y), 4, c.stroke_width(1)))
                .map_err(|e| e.to_string())?,
        }
        area.draw(&Text::new(label.clone(), (x + 34, y), style.clone()))
            .map_err(|e| e.to_string())?;
        // A generous width estimate of sans-serif text (SVG cannot measure it).
        x += 34 + (label.chars().count() as f64 * 0.6 * FONT_PX as f64).ceil() as i32 + 26;
    }
    Ok(())
}

fn plot_err(e: impl std::fmt::Display, path: &Path) -> EvalError {
    EvalError::Run {
        what: path.display().to_string(),
        message: e.to_string(),
    }
}

/// A figure's canvas: white, titled, with its legend strip on top; the area below it.
fn canvas<'a>(
    file: &'a Path,
    size: (u32, u32),
    title: &str,
    legend_h: u32,
    items: &[(String, Swatch)],
) -> Result<DrawingArea<SVGBackend<'a>, Shift>, EvalError> {
    let e = |x: String| plot_err(x, file);
    let root = SVGBackend::new(file, size).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(x.to_string()))?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(|x| e(x.to_string()))?;
    let (legend, rest) = root.split_vertically(legend_h);
    legend_strip(&legend, items).map_err(e)?;
    Ok(rest)
}

/// Repeat 0 of every controller on `trajectory`, in the runs' order.
fn repeat0<'a>(runs: &'a [RunRecord], trajectory: &str) -> Vec<&'a RunRecord> {
    runs.iter()
        .filter(|r| r.trajectory == trajectory && r.repeat == 0)
        .collect()
}

/// Legend entries common to both figures: desired, one colour per controller, and how truth and
/// vision are drawn.
fn legend_items(sel: &[&RunRecord], vision: &str) -> Vec<(String, Swatch)> {
    let mut items = vec![("desired".to_string(), Swatch::Line(BLACK))];
    for (i, r) in sel.iter().enumerate() {
        items.push((
            r.controller.clone(),
            Swatch::Line(CONTROLLER_COLOURS[i % CONTROLLER_COLOURS.len()]),
        ));
    }
    let grey = RGBColor(90, 90, 90);
    items.push(("reached by truth (solid)".into(), Swatch::Line(grey)));
    items.push((format!("reached by vision ({vision})"), Swatch::Ring(grey)));
    items.push(("error by vision (dashed)".into(), Swatch::Dashed(grey)));
    items
}

/// A range covering `values` with `pad` on either side (and at least `min_span` wide).
fn span(values: impl Iterator<Item = f64>, pad: f64, min_span: f64) -> std::ops::Range<f64> {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return -1.0..1.0;
    }
    let mid = 0.5 * (lo + hi);
    let half = (0.5 * (hi - lo) + pad).max(0.5 * min_span);
    (mid - half)..(mid + half)
}

/// Points of one series, (x, y) in data coordinates.
type Series = Vec<(f64, f64)>;

/// Draws one line chart panel: `lines` solid (coloured), `rings` as hollow circles, `dashed` as
/// dashed lines; no legend (the figure's strip has it).
#[allow(clippy::too_many_arguments)]
fn panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    caption: &str,
    (x_desc, y_desc): (&str, &str),
    (xr, yr): (std::ops::Range<f64>, std::ops::Range<f64>),
    lines: &[(RGBColor, u32, Series)],
    dashed: &[(RGBColor, Series)],
    rings: &[(RGBColor, Series)],
) -> Result<(), String> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 17))
        .margin(10)
        .x_label_area_size(38)
        .y_label_area_size(52)
        .build_cartesian_2d(xr, yr)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(|e| e.to_string())?;
    for (c, w, v) in lines {
        chart
            .draw_series(LineSeries::new(v.iter().copied(), c.stroke_width(*w)))
            .map_err(|e| e.to_string())?;
    }
    for (c, v) in dashed {
        chart
            .draw_series(DashedLineSeries::new(v.iter().copied(), 9, 5, c.stroke_width(1)))
            .map_err(|e| e.to_string())?;
    }
    for (c, v) in rings {
        chart
            .draw_series(v.iter().map(|p| Circle::new(*p, 3, c.stroke_width(1))))
            .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// Per point of one run: desired pose, reached by truth, reached by vision (when valid).
type Poses = Vec<(Isometry3<f64>, Isometry3<f64>, Option<Isometry3<f64>>)>;

fn poses(robot: &Robot, run: &RunRecord) -> Poses {
    run.points
        .iter()
        .map(|p| {
            let vision = match (p.q_est_deg, p.ee_est) {
                (Some(_), Some((pos, quat))) => pose_from_estimate(&pos, &quat),
                _ => None,
            };
            (ee_pose(robot, &p.q_desired_deg), ee_pose(robot, &p.q_true_deg), vision)
        })
        .collect()
}

/// One projection of a tip path: name, axis labels (horizontal, vertical), component indices.
type View = (&'static str, (&'static str, &'static str), (usize, usize));

/// The three projections of a tip path.
const VIEWS: [View; 3] = [
    ("x–y", ("x [mm]", "y [mm]"), (0, 1)),
    ("x–z", ("x [mm]", "z [mm]"), (0, 2)),
    ("y–z", ("y [mm]", "z [mm]"), (1, 2)),
];

/// Fig. 12 of one trajectory (see the module docs): `fig12_<trajectory>.svg` in `dir`, or
/// nothing when no run of it has a repeat 0.
// Long: one figure of the paper (Fig. 12) drawn panel by panel.
pub fn fig12(robot: &Robot, runs: &[RunRecord], trajectory: &str, dir: &Path) -> Result<Option<PathBuf>, EvalError> {
    let sel = repeat0(runs, trajectory);
    if sel.is_empty() {
        return Ok(None);
    }
    let file = dir.join(format!("fig12_{trajectory}.svg"));
    let all: Vec<Poses> = sel.iter().map(|r| poses(robot, r)).collect();
    // Every view of every row on the same scale: equal spans on both axes, so the shapes are
    // not distorted and the rows compare.
    let pick = |k: usize| -> Vec<f64> {
        all.iter()
            .flatten()
            .flat_map(|(d, t, v)| {
                let mut out = vec![d.translation.vector[k], t.translation.vector[k]];
                out.extend(v.map(|v| v.translation.vector[k]));
                out
            })
            .collect()
    };
    let comps = [pick(0), pick(1), pick(2)];
    let widest = comps
        .iter()
        .map(|c| {
            let r = span(c.iter().copied(), 0.0, 0.0);
            r.end - r.start
        })
        .fold(0.0f64, f64::max);
    let view_range = |k: usize| span(comps[k].iter().copied(), 0.08 * widest + 1.0, 0.0);
    let square = |a: usize, b: usize| {
        let (ra, rb) = (view_range(a), view_range(b));
        let s = (ra.end - ra.start).max(rb.end - rb.start);
        let centre = |r: &std::ops::Range<f64>| 0.5 * (r.start + r.end);
        let (ca, cb) = (centre(&ra), centre(&rb));
        ((ca - 0.5 * s)..(ca + 0.5 * s), (cb - 0.5 * s)..(cb + 0.5 * s))
    };
    let rows = sel.len() as u32;
    let (w, title_h, legend_h, row_h, err_h) = (1440u32, 44u32, 36u32, 440u32, 400u32);
    let h = title_h + legend_h + rows * row_h + err_h;
    let e = |x: String| plot_err(x, &file);
    {
        let rest = canvas(
            &file,
            (w, h),
            &format!("{trajectory}: desired vs reached tip path, by vision and by truth (repeat 0) — Fig. 12"),
            legend_h,
            &legend_items(&sel, "○ per point"),
        )?;
        let (paths, errors) = rest.split_vertically(rows * row_h);
        let cells = paths.split_evenly((rows as usize, 3));
        for (i, (run, ps)) in sel.iter().zip(&all).enumerate() {
            let c = CONTROLLER_COLOURS[i % CONTROLLER_COLOURS.len()];
            for (v, (name, axes, (a, b))) in VIEWS.iter().enumerate() {
                let proj = |iso: &Isometry3<f64>| (iso.translation.vector[*a], iso.translation.vector[*b]);
                let desired: Vec<(f64, f64)> = ps.iter().map(|(d, _, _)| proj(d)).collect();
                let truth: Vec<(f64, f64)> = ps.iter().map(|(_, t, _)| proj(t)).collect();
                let vision: Vec<(f64, f64)> = ps.iter().filter_map(|(_, _, v)| v.as_ref().map(proj)).collect();
                panel(
                    &cells[i * 3 + v],
                    &format!("{}: {name} view", run.controller),
                    *axes,
                    square(*a, *b),
                    &[(BLACK, 2, desired), (c, 2, truth)],
                    &[],
                    &[(c, vision)],
                )
                .map_err(e)?;
            }
        }
        // Errors along the path: position and orientation, truth solid, vision dashed.
        let halves = errors.split_evenly((1, 2));
        let n = sel.iter().map(|r| r.points.len()).max().unwrap_or(0).max(2) as f64;
        for (k, (what, unit)) in [("tip position error", "mm"), ("orientation error", "°")]
            .into_iter()
            .enumerate()
        {
            let value = |d: &Isometry3<f64>, r: &Isometry3<f64>| {
                let (_, pos, rot) = pose_distance(d, r);
                if k == 0 {
                    pos
                } else {
                    rot
                }
            };
            let mut lines = Vec::new();
            let mut dashed = Vec::new();
            for (i, ps) in all.iter().enumerate() {
                let c = CONTROLLER_COLOURS[i % CONTROLLER_COLOURS.len()];
                let truth: Vec<(f64, f64)> = ps
                    .iter()
                    .enumerate()
                    .map(|(j, (d, t, _))| (j as f64, value(d, t)))
                    .collect();
                let vision: Vec<(f64, f64)> = ps
                    .iter()
                    .enumerate()
                    .filter_map(|(j, (d, _, v))| v.as_ref().map(|v| (j as f64, value(d, v))))
                    .collect();
                lines.push((c, 2, truth));
                dashed.push((c, vision));
            }
            let top = lines
                .iter()
                .flat_map(|l| l.2.iter().map(|p| p.1))
                .chain(dashed.iter().flat_map(|l| l.1.iter().map(|p| p.1)))
                .filter(|v| v.is_finite())
                .fold(1.0f64, f64::max)
                * 1.08;
            panel(
                &halves[k],
                &format!("{what} along the path (truth solid, vision dashed)"),
                ("trajectory point (model step)", &format!("{what} [{unit}]")),
                (0.0..n, 0.0..top),
                &lines,
                &dashed,
                &[],
            )
            .map_err(e)?;
        }
        rest.present().map_err(|x| e(x.to_string()))?;
    }
    Ok(Some(file))
}

/// Fig. 13 of one trajectory (see the module docs): `fig13_<trajectory>.svg` in `dir`, or
/// nothing when no run of it has a repeat 0.
pub fn fig13(runs: &[RunRecord], trajectory: &str, dir: &Path) -> Result<Option<PathBuf>, EvalError> {
    const JOINTS: [(usize, &str); 2] = [(3, "q4"), (4, "q5")];
    let sel = repeat0(runs, trajectory);
    if sel.is_empty() {
        return Ok(None);
    }
    let file = dir.join(format!("fig13_{trajectory}.svg"));
    let n = sel.iter().map(|r| r.points.len()).max().unwrap_or(0).max(2) as f64;
    let angles = span(
        sel.iter().flat_map(|r| {
            r.points.iter().flat_map(|p| {
                JOINTS.iter().flat_map(move |(j, _)| {
                    [p.q_desired_deg[*j], p.q_true_deg[*j]]
                        .into_iter()
                        .chain(p.q_est_deg.map(|q| q[*j]))
                })
            })
        }),
        2.0,
        4.0,
    );
    let err_top = sel
        .iter()
        .flat_map(|r| {
            r.points.iter().flat_map(|p| {
                JOINTS.iter().flat_map(move |(j, _)| {
                    [(p.q_true_deg[*j] - p.q_desired_deg[*j]).abs()]
                        .into_iter()
                        .chain(p.q_est_deg.map(|q| (q[*j] - p.q_desired_deg[*j]).abs()))
                })
            })
        })
        .filter(|v| v.is_finite())
        .fold(1.0f64, f64::max)
        * 1.08;
    let rows = sel.len() as u32;
    let (w, title_h, legend_h, row_h, err_h) = (1400u32, 44u32, 36u32, 330u32, 360u32);
    let h = title_h + legend_h + rows * row_h + err_h;
    let e = |x: String| plot_err(x, &file);
    {
        let rest = canvas(
            &file,
            (w, h),
            &format!("{trajectory}: forceps angles q4, q5, desired vs reached (repeat 0) — Fig. 13"),
            legend_h,
            &legend_items(&sel, "○ per point"),
        )?;
        let (tracks, errors) = rest.split_vertically(rows * row_h);
        let cells = tracks.split_evenly((rows as usize, 2));
        for (i, run) in sel.iter().enumerate() {
            let c = CONTROLLER_COLOURS[i % CONTROLLER_COLOURS.len()];
            for (k, (j, name)) in JOINTS.iter().enumerate() {
                let series = |f: &dyn Fn(&crate::PointRecord) -> Option<f64>| -> Vec<(f64, f64)> {
                    run.points
                        .iter()
                        .enumerate()
                        .filter_map(|(x, p)| f(p).map(|y| (x as f64, y)))
                        .collect()
                };
                let desired = series(&|p| Some(p.q_desired_deg[*j]));
                let truth = series(&|p| Some(p.q_true_deg[*j]));
                let vision = series(&|p| p.q_est_deg.map(|q| q[*j]));
                panel(
                    &cells[i * 2 + k],
                    &format!("{}: {name}", run.controller),
                    ("trajectory point (model step)", &format!("{name} [°]")),
                    (0.0..n, angles.clone()),
                    &[(BLACK, 2, desired), (c, 2, truth)],
                    &[],
                    &[(c, vision)],
                )
                .map_err(e)?;
            }
        }
        let halves = errors.split_evenly((1, 2));
        for (k, (j, name)) in JOINTS.iter().enumerate() {
            let mut lines = Vec::new();
            let mut dashed = Vec::new();
            for (i, run) in sel.iter().enumerate() {
                let c = CONTROLLER_COLOURS[i % CONTROLLER_COLOURS.len()];
                let pts = run.points.iter().enumerate();
                lines.push((
                    c,
                    2,
                    pts.clone()
                        .map(|(x, p)| (x as f64, (p.q_true_deg[*j] - p.q_desired_deg[*j]).abs()))
                        .collect(),
                ));
                dashed.push((
                    c,
                    pts.filter_map(|(x, p)| p.q_est_deg.map(|q| (x as f64, (q[*j] - p.q_desired_deg[*j]).abs())))
                        .collect(),
                ));
            }
            panel(
                &halves[k],
                &format!("{name} error |reached − desired| (truth solid, vision dashed)"),
                ("trajectory point (model step)", &format!("{name} error [°]")),
                (0.0..n, 0.0..err_top),
                &lines,
                &dashed,
                &[],
            )
            .map_err(e)?;
        }
        rest.present().map_err(|x| e(x.to_string()))?;
    }
    Ok(Some(file))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn span_pads_and_keeps_a_minimum_width() {
        let r = span([1.0, 3.0].into_iter(), 1.0, 0.0);
        assert!((r.start - 0.0).abs() < 1e-12 && (r.end - 4.0).abs() < 1e-12);
        let r = span([2.0, 2.0].into_iter(), 0.0, 4.0);
        assert!((r.start - 0.0).abs() < 1e-12 && (r.end - 4.0).abs() < 1e-12);
        assert_eq!(span(std::iter::empty(), 1.0, 0.0), -1.0..1.0);
        assert_eq!(span([f64::NAN].into_iter(), 1.0, 0.0), -1.0..1.0);
    }
}
