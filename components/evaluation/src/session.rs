//! Long tracking sessions through cable slack (`bowden evaluate --session MINUTES`): the unseen
//! trajectories played one after another in a loop through ONE lockstep pipeline, so the plant
//! is never restarted and its simulated time, creep and slips carry over the whole session; the
//! error over time per window of simulated time, per controller, and how much of the calibrated
//! controllers' gain over `uncalibrated` the slack takes away (docs/architecture.md §8).
//!
//! [`plan`] lays the loop out as one long path (home → first trajectory, then every trajectory
//! joined to the next by the dataset-step moves `connect` gives, lap after lap, until the
//! session's simulated time is used up); [`crate::run_trajectory`] runs it like any trajectory;
//! [`analyse`] cuts the measured points into windows and laps and pools them with
//! [`crate::report::pool`] (the same Table V/VI figures as `bowden evaluate`); [`write`] writes
//! `session.md`, `session.json` and the plots.

use crate::metrics::reduction_pct;
use crate::report::{line_plot_marked, pool, Cell};
use crate::{EvalError, PointRecord, RunRecord};
use bowden_kinematics::{JointsDeg, Robot, N_JOINTS};
use plotters::prelude::SeriesLabelPosition;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What a measured point of the loop is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct PointLabel {
    /// Lap of the loop, from 0.
    pub lap: u32,
    /// Index of the trajectory in [`SessionPlan::trajectories`]; `None` for the moves joining
    /// one trajectory's end to the next one's start (tracked, not scored).
    pub trajectory: Option<usize>,
}

/// The session's whole path, as one trajectory for [`crate::run_trajectory`].
#[derive(Debug, Clone)]
pub struct SessionPlan {
    pub trajectories: Vec<String>,
    /// Home → the first trajectory's start (held, not measured).
    pub approach: Vec<JointsDeg>,
    /// Every measured point, lap after lap.
    pub q_path: Vec<JointsDeg>,
    pub labels: Vec<PointLabel>,
    /// Measured points of one whole lap (trajectories and joining moves).
    pub lap_points: usize,
    /// Simulated time of one lap, s.
    pub lap_s: f64,
    /// Simulated time the session lasts (its last point's end), s.
    pub duration_s: f64,
}

/// Lays out a session of at most `duration_s` of simulated time: the trajectories in order,
/// looped, every point held `settle_ticks` ticks of `tick_ns` after one warm-up tick and the
/// approach from home, as [`crate::run_trajectory`] runs them. `connect(a, b)` is the move from
/// a to b at the dataset step (its points other than a and b are used).
pub fn plan(
    trajectories: &[(String, Vec<JointsDeg>)],
    duration_s: f64,
    settle_ticks: u32,
    tick_ns: u64,
    connect: &dyn Fn(&JointsDeg, &JointsDeg) -> Vec<JointsDeg>,
) -> Result<SessionPlan, EvalError> {
    let bad = |message: String| EvalError::Run {
        what: "session".into(),
        message,
    };
    if trajectories.is_empty() || trajectories.iter().any(|(_, q)| q.is_empty()) {
        return Err(bad("every trajectory of a session needs at least one point".into()));
    }
    let inner = |a: &JointsDeg, b: &JointsDeg| -> Vec<JointsDeg> {
        connect(a, b).into_iter().filter(|p| p != a && p != b).collect()
    };
    let first = trajectories[0].1[0];
    let approach = inner(&[0.0; N_JOINTS], &first);
    // One lap: every trajectory, each followed by the move to the next (the last to the first).
    let mut lap: Vec<(JointsDeg, Option<usize>)> = Vec::new();
    for (k, (_, q)) in trajectories.iter().enumerate() {
        lap.extend(q.iter().map(|p| (*p, Some(k))));
        let next = trajectories[(k + 1) % trajectories.len()].1[0];
        let last = q[q.len() - 1];
        lap.extend(inner(&last, &next).into_iter().map(|p| (p, None)));
    }
    let hold_ns = u64::from(settle_ticks.max(1)) * tick_ns.max(1);
    let start_ns = tick_ns.max(1) + approach.len() as u64 * hold_ns;
    let end_ns = (duration_s.max(0.0) * 1e9).round() as u64;
    let fits = end_ns.saturating_sub(start_ns) / hold_ns;
    if fits == 0 {
        return Err(bad(format!(
            "{duration_s} s of simulated time does not reach the first point ({:.1} s after the approach)",
            (start_ns + hold_ns) as f64 * 1e-9
        )));
    }
    let n = usize::try_from(fits).unwrap_or(usize::MAX).min(10_000_000);
    let mut q_path = Vec::with_capacity(n);
    let mut labels = Vec::with_capacity(n);
    for i in 0..n {
        let (q, trajectory) = lap[i % lap.len()];
        q_path.push(q);
        labels.push(PointLabel {
            lap: (i / lap.len()) as u32,
            trajectory,
        });
    }
    Ok(SessionPlan {
        trajectories: trajectories.iter().map(|(n, _)| n.clone()).collect(),
        approach,
        q_path,
        labels,
        lap_points: lap.len(),
        lap_s: lap.len() as f64 * hold_ns as f64 * 1e-9,
        duration_s: (start_ns + n as u64 * hold_ns) as f64 * 1e-9,
    })
}

/// The slack the plant file configures, as the session reports it.
#[derive(Debug, Clone, Default, Serialize)]
pub struct SlackEvents {
    /// When slack first appears (creep start or the first slip), s; `None`: no slack.
    pub onset_s: Option<f64>,
    /// Marked on the plots and listed in the report: (what, simulated time s).
    pub marks: Vec<(String, f64)>,
    /// One line saying what the plant file does (e.g. "w1–w4 creep 6 mm/h from 120 s").
    pub description: String,
}

/// One controller in one window (or one stretch of the summary).
#[derive(Debug, Clone, Serialize)]
pub struct WindowCell {
    pub controller: String,
    /// Table V/VI of the window's scored points, pooled over repeats.
    pub cell: Cell,
    /// 1 − calibrated / uncalibrated tip position error by truth (absent for `uncalibrated`, or
    /// without it in the session).
    pub gain_position_truth: Option<f64>,
    pub gain_orientation_truth: Option<f64>,
    pub gain_position_vision: Option<f64>,
}

/// One window of simulated time.
#[derive(Debug, Clone, Serialize)]
pub struct Window {
    pub index: usize,
    pub t_start_s: f64,
    pub t_end_s: f64,
    /// Scored points in the window per run.
    pub points: usize,
    pub cells: Vec<WindowCell>,
}

/// A stretch of the session the summary compares (before slack, at the end).
#[derive(Debug, Clone, Serialize)]
pub struct Stretch {
    /// E.g. "laps 0–1 (t 0.6–99.5 s)".
    pub label: String,
    pub t_start_s: f64,
    pub t_end_s: f64,
    pub points: usize,
    pub cells: Vec<WindowCell>,
}

/// Per controller: what the slack did to it.
#[derive(Debug, Clone, Serialize)]
pub struct ControllerSummary {
    pub controller: String,
    pub before: Cell,
    pub end: Cell,
    /// Gains over uncalibrated (tip position by truth) before the slack and at the end, and the
    /// loss: before − end (a fraction of the uncalibrated error) and that loss relative to the
    /// gain before.
    pub gain_before: Option<f64>,
    pub gain_end: Option<f64>,
    pub gain_lost: Option<f64>,
    pub gain_lost_relative: Option<f64>,
    /// The worst window after the onset: its index and tip position error by truth, mm.
    pub worst_window_after_onset: Option<(usize, f64)>,
}

/// Everything a session report holds.
#[derive(Debug, Clone, Serialize)]
pub struct SessionSummary {
    pub controllers: Vec<String>,
    pub trajectories: Vec<String>,
    pub duration_s: f64,
    pub window_s: f64,
    pub lap_points: usize,
    pub lap_s: f64,
    pub slack: SlackEvents,
    pub before: Stretch,
    pub end: Stretch,
    pub summary: Vec<ControllerSummary>,
    pub windows: Vec<Window>,
}

/// A session's measured point with its time and place in the loop (report.json).
#[derive(Debug, Clone, Serialize)]
pub struct SessionPoint {
    pub t_s: f64,
    pub lap: u32,
    /// The trajectory's name, or `None` for a joining move (not scored).
    pub trajectory: Option<String>,
    #[serde(flatten)]
    pub record: PointRecord,
}

/// The points of `runs` (one per controller and repeat, all of `plan`) selected by `keep`
/// (point index, label, t_s), pooled per controller into cells labelled `label`, with the gains.
fn cells_where(
    robot: &Robot,
    plan: &SessionPlan,
    runs: &[RunRecord],
    controllers: &[String],
    label: &str,
    keep: &dyn Fn(usize, &PointLabel, f64) -> bool,
) -> (usize, Vec<WindowCell>) {
    let mut points = 0;
    let mut cells: Vec<WindowCell> = controllers
        .iter()
        .map(|c| {
            let subsets: Vec<RunRecord> = runs
                .iter()
                .filter(|r| &r.controller == c)
                .map(|r| {
                    let pts: Vec<PointRecord> = r
                        .points
                        .iter()
                        .enumerate()
                        .filter(|(i, p)| plan.labels[*i].trajectory.is_some() && keep(*i, &plan.labels[*i], t_s(p)))
                        .map(|(_, p)| *p)
                        .collect();
                    RunRecord {
                        trajectory: label.into(),
                        controller: c.clone(),
                        repeat: r.repeat,
                        seed: r.seed,
                        invalid_estimates: pts.iter().filter(|p| p.q_est_deg.is_none()).count(),
                        points: pts,
                        ticks: 0,
                    }
                })
                .collect();
            if let Some(first) = subsets.first() {
                points = first.points.len();
            }
            let refs: Vec<&RunRecord> = subsets.iter().collect();
            WindowCell {
                controller: c.clone(),
                cell: pool(robot, label, c, &refs),
                gain_position_truth: None,
                gain_orientation_truth: None,
                gain_position_vision: None,
            }
        })
        .collect();
    let uncal = cells
        .iter()
        .find(|w| w.controller == "uncalibrated")
        .map(|w| w.cell.clone());
    if let Some(u) = uncal {
        for w in cells.iter_mut().filter(|w| w.controller != "uncalibrated") {
            let gain = |before: f64, after: f64, n: usize| (n > 0).then(|| reduction_pct(before, after) / 100.0);
            let (ut, ct) = (&u.task_truth, &w.cell.task_truth);
            let (uv, cv) = (&u.task_vision, &w.cell.task_vision);
            w.gain_position_truth = gain(ut.pos_mean_mm, ct.pos_mean_mm, ct.n.min(ut.n));
            w.gain_orientation_truth = gain(ut.rot_mean_deg, ct.rot_mean_deg, ct.n.min(ut.n));
            w.gain_position_vision = gain(uv.pos_mean_mm, cv.pos_mean_mm, cv.n.min(uv.n));
        }
    }
    (points, cells)
}

fn t_s(p: &PointRecord) -> f64 {
    p.t_sim_ns as f64 * 1e-9
}

/// Cuts the session's runs into windows of `window_s` and compares the stretch before the
/// slack with the end of the session.
///
/// - Windows: (k·W, (k+1)·W] by the plant's simulated time at each measurement.
/// - Before slack: the whole laps measured entirely before the onset, or, without one, every
///   point before it; without slack at all, the first lap.
/// - End: the last whole lap (the same points as any whole lap before it) when it starts after
///   the onset and is not lap 0, else the last window.
///
/// Only the trajectories' points are scored; the moves joining them are tracked but left out.
// Long: the session's windows, stretches and summary computed in one pass over the recorded points.
pub fn analyse(
    robot: &Robot,
    plan: &SessionPlan,
    runs: &[RunRecord],
    window_s: f64,
    slack: &SlackEvents,
) -> Result<SessionSummary, EvalError> {
    let bad = |message: String| EvalError::Run {
        what: "session".into(),
        message,
    };
    if !(window_s.is_finite() && window_s > 0.0) {
        return Err(bad(format!(
            "the window must be a positive number of seconds, got {window_s}"
        )));
    }
    if let Some(r) = runs.iter().find(|r| r.points.len() != plan.q_path.len()) {
        return Err(bad(format!(
            "{}/{}: {} points measured, the session has {}",
            r.controller,
            r.repeat,
            r.points.len(),
            plan.q_path.len()
        )));
    }
    let mut controllers: Vec<String> = Vec::new();
    for r in runs {
        if !controllers.contains(&r.controller) {
            controllers.push(r.controller.clone());
        }
    }
    let Some(times) = runs.first().map(|r| r.points.iter().map(t_s).collect::<Vec<f64>>()) else {
        return Err(bad("no runs".into()));
    };
    let window_of = |t: f64| ((t / window_s).ceil() as usize).saturating_sub(1);
    let n_windows = times.last().map_or(0, |&t| window_of(t) + 1);
    let mut windows = Vec::new();
    for k in 0..n_windows {
        let (points, cells) = cells_where(robot, plan, runs, &controllers, &format!("window {k}"), &|_, _, t| {
            window_of(t) == k
        });
        if points == 0 {
            continue;
        }
        windows.push(Window {
            index: k,
            t_start_s: k as f64 * window_s,
            t_end_s: (k + 1) as f64 * window_s,
            points,
            cells,
        });
    }

    // Laps played to the end, and when a lap's last point is measured.
    let whole_laps = plan.q_path.len() / plan.lap_points.max(1);
    let lap_end = |lap: usize| times[((lap + 1) * plan.lap_points).min(times.len()) - 1];
    let onset = slack.onset_s;
    let before_laps = match onset {
        Some(t0) => (0..whole_laps).take_while(|&l| lap_end(l) < t0).count(),
        None => whole_laps.min(1),
    };
    let stretch = |label: String, keep: &dyn Fn(usize, &PointLabel, f64) -> bool| -> Stretch {
        let (points, cells) = cells_where(robot, plan, runs, &controllers, &label, keep);
        let sel: Vec<f64> = times
            .iter()
            .enumerate()
            .filter(|(i, &t)| plan.labels[*i].trajectory.is_some() && keep(*i, &plan.labels[*i], t))
            .map(|(_, &t)| t)
            .collect();
        Stretch {
            label,
            t_start_s: sel.first().copied().unwrap_or(0.0),
            t_end_s: sel.last().copied().unwrap_or(0.0),
            points,
            cells,
        }
    };
    let laps_label = |a: usize, b: usize| {
        if a == b {
            format!("lap {a}")
        } else {
            format!("laps {a}–{b}")
        }
    };
    let before = if before_laps > 0 {
        let n = before_laps;
        stretch(format!("{} before the slack", laps_label(0, n - 1)), &|_, l, _| {
            (l.lap as usize) < n
        })
    } else if let Some(t0) = onset {
        stretch("every point before the slack (less than a lap)".into(), &|_, _, t| {
            t < t0
        })
    } else {
        stretch("lap 0 (less than a whole lap)".into(), &|_, l, _| l.lap == 0)
    };
    // The first point of a lap is measured one hold after the previous lap's last.
    let lap_start = |lap: usize| times[(lap * plan.lap_points).min(times.len() - 1)];
    let slack_from = onset.unwrap_or(f64::NEG_INFINITY);
    let last_lap = whole_laps
        .checked_sub(1)
        .filter(|&l| l > 0 && lap_start(l) >= slack_from);
    let end = if let Some(last) = last_lap {
        stretch(format!("{}, the last whole lap", laps_label(last, last)), &|_, l, _| {
            l.lap as usize == last
        })
    } else {
        let last = n_windows.saturating_sub(1);
        stretch(format!("window {last}, the last"), &|_, _, t| window_of(t) == last)
    };
    let t_onset = onset.unwrap_or(f64::INFINITY);
    let summary = controllers
        .iter()
        .map(|c| {
            let find = |s: &Stretch| s.cells.iter().find(|w| &w.controller == c).cloned();
            let (b, e) = (find(&before), find(&end));
            let gain_before = b.as_ref().and_then(|w| w.gain_position_truth);
            let gain_end = e.as_ref().and_then(|w| w.gain_position_truth);
            let gain_lost = gain_before.zip(gain_end).map(|(b, e)| b - e);
            let worst = windows
                .iter()
                .filter(|w| w.t_end_s > t_onset)
                .filter_map(|w| {
                    w.cells
                        .iter()
                        .find(|x| &x.controller == c)
                        .map(|x| (w.index, x.cell.task_truth.pos_mean_mm))
                })
                .fold(None, |acc: Option<(usize, f64)>, x| match acc {
                    Some(a) if a.1 >= x.1 => Some(a),
                    _ => Some(x),
                });
            ControllerSummary {
                controller: c.clone(),
                before: b.map(|w| w.cell).unwrap_or_else(|| pool(robot, "before", c, &[])),
                end: e.map(|w| w.cell).unwrap_or_else(|| pool(robot, "end", c, &[])),
                gain_before,
                gain_end,
                gain_lost,
                gain_lost_relative: gain_lost
                    .zip(gain_before)
                    .and_then(|(l, b)| (b.abs() > 1e-12).then_some(l / b)),
                worst_window_after_onset: worst,
            }
        })
        .collect();
    Ok(SessionSummary {
        controllers,
        trajectories: plan.trajectories.clone(),
        duration_s: plan.duration_s,
        window_s,
        lap_points: plan.lap_points,
        lap_s: plan.lap_s,
        slack: slack.clone(),
        before,
        end,
        summary,
        windows,
    })
}

fn pct(v: Option<f64>) -> String {
    v.map(|g| format!("{:+.1} %", 100.0 * g)).unwrap_or_default()
}

fn joint_mean(j: &crate::metrics::JointErrors) -> f64 {
    j.mae_deg.iter().sum::<f64>() / N_JOINTS as f64
}

/// The summary table (rows: controllers), by truth or by vision.
fn summary_table(s: &SessionSummary, by_truth: bool) -> String {
    let mut out = String::from(
        "| controller | before: position [mm] | before: orientation [°] | before: joint MAE [°] | end: position [mm] | end: orientation [°] | end: joint MAE [°] |",
    );
    if by_truth {
        out.push_str(
            " gain before | gain at end | gain lost (points) | gain lost (share) | worst window after onset [mm] |",
        );
    }
    out.push_str("\n|---|---|---|---|---|---|---|");
    if by_truth {
        out.push_str("---|---|---|---|---|");
    }
    out.push('\n');
    for c in &s.summary {
        let (tb, te) = if by_truth {
            (&c.before.task_truth, &c.end.task_truth)
        } else {
            (&c.before.task_vision, &c.end.task_vision)
        };
        let (jb, je) = if by_truth {
            (&c.before.joint_truth, &c.end.joint_truth)
        } else {
            (&c.before.joint_vision, &c.end.joint_vision)
        };
        let _ = write!(
            out,
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            c.controller,
            tb.pos_mean_mm,
            tb.rot_mean_deg,
            joint_mean(jb),
            te.pos_mean_mm,
            te.rot_mean_deg,
            joint_mean(je)
        );
        if by_truth {
            let worst = c
                .worst_window_after_onset
                .map(|(k, e)| format!("{e:.2} (window {k})"))
                .unwrap_or_default();
            let _ = write!(
                out,
                " {} | {} | {} | {} | {worst} |",
                pct(c.gain_before),
                pct(c.gain_end),
                c.gain_lost.map(|g| format!("{:.1}", 100.0 * g)).unwrap_or_default(),
                c.gain_lost_relative
                    .map(|g| format!("{:.0} %", 100.0 * g))
                    .unwrap_or_default(),
            );
        }
        out.push('\n');
    }
    out
}

/// Which figure of a window cell a table shows.
#[derive(Clone, Copy)]
enum Metric {
    Position,
    Orientation,
    Joints,
}

/// Error over time: rows windows, columns controllers (then the gains for position by truth).
fn window_table(s: &SessionSummary, metric: Metric, by_truth: bool) -> String {
    let gains = matches!(metric, Metric::Position);
    let calibrated: Vec<&String> = s.controllers.iter().filter(|c| *c != "uncalibrated").collect();
    let with_gain = gains && s.controllers.iter().any(|c| c == "uncalibrated");
    let mut out = String::from("| window | t [s] |");
    for c in &s.controllers {
        let _ = write!(out, " {c} |");
    }
    if with_gain {
        for c in &calibrated {
            let _ = write!(out, " gain {c} |");
        }
    }
    out.push_str("\n|---|---|");
    for _ in &s.controllers {
        out.push_str("---|");
    }
    if with_gain {
        for _ in &calibrated {
            out.push_str("---|");
        }
    }
    out.push('\n');
    for w in &s.windows {
        let marks: Vec<&str> = s
            .slack
            .marks
            .iter()
            .filter(|(_, t)| *t >= w.t_start_s && *t < w.t_end_s)
            .map(|(m, _)| m.as_str())
            .collect();
        let note = if marks.is_empty() {
            String::new()
        } else {
            format!(" ({})", marks.join("; "))
        };
        let _ = write!(out, "| {} | {:.0}–{:.0}{note} |", w.index, w.t_start_s, w.t_end_s);
        for c in &s.controllers {
            let v = w.cells.iter().find(|x| &x.controller == c).map(|x| {
                let cell = &x.cell;
                let (t, j) = if by_truth {
                    (&cell.task_truth, &cell.joint_truth)
                } else {
                    (&cell.task_vision, &cell.joint_vision)
                };
                match metric {
                    Metric::Position => t.pos_mean_mm,
                    Metric::Orientation => t.rot_mean_deg,
                    Metric::Joints => joint_mean(j),
                }
            });
            let _ = write!(out, " {} |", v.map(|v| format!("{v:.2}")).unwrap_or_default());
        }
        if with_gain {
            for c in &calibrated {
                let g = w.cells.iter().find(|x| &x.controller == *c).and_then(|x| {
                    if by_truth {
                        x.gain_position_truth
                    } else {
                        x.gain_position_vision
                    }
                });
                let _ = write!(out, " {} |", pct(g));
            }
        }
        out.push('\n');
    }
    out
}

/// The Markdown report of a session.
pub fn markdown(s: &SessionSummary, header: &str) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "# Tracking session through cable slack\n\n{header}\n");
    let onset = s
        .slack
        .onset_s
        .map(|t| format!("slack from {t:.1} s"))
        .unwrap_or_else(|| "no slack configured".into());
    let _ = writeln!(
        out,
        "Plant: {} ({onset}). {:.1} s simulated in windows of {:.0} s; the loop {} takes {} points, {:.1} s a lap \
         (the moves joining the trajectories are tracked, not scored). Gain = 1 − calibrated / uncalibrated \
         tip position error in the same stretch; gain lost = gain before − gain at the end (points of the \
         uncalibrated error) and that as a share of the gain before.\n",
        s.slack.description,
        s.duration_s,
        s.window_s,
        s.trajectories.join(" → "),
        s.lap_points,
        s.lap_s
    );
    let _ = writeln!(
        out,
        "Before: {} (t {:.1}–{:.1} s, {} scored points). End: {} (t {:.1}–{:.1} s, {} scored points).\n",
        s.before.label,
        s.before.t_start_s,
        s.before.t_end_s,
        s.before.points,
        s.end.label,
        s.end.t_start_s,
        s.end.t_end_s,
        s.end.points
    );
    let _ = writeln!(
        out,
        "## Before and after the slack — simulator truth\n\n{}",
        summary_table(s, true)
    );
    let _ = writeln!(
        out,
        "## Before and after the slack — vision\n\n{}",
        summary_table(s, false)
    );
    for (by_truth, by) in [(true, "simulator truth"), (false, "vision")] {
        for (metric, what) in [
            (Metric::Position, "tip position error [mm]"),
            (Metric::Orientation, "orientation error [°]"),
            (Metric::Joints, "joint MAE [°], mean of q1..q5"),
        ] {
            let _ = writeln!(
                out,
                "## Error over time — {what}, {by}\n\n{}",
                window_table(s, metric, by_truth)
            );
        }
    }
    out
}

/// Writes `session.md`, `session.json` (summary, windows and every point with its time) and
/// the plots `session_error.svg` (tip position error by truth per window, per controller) and
/// `session_gain.svg` (the calibrated controllers' gain per window) into `dir`.
// Long: one report: table, plots and JSON written in order.
pub fn write(
    s: &SessionSummary,
    plan: &SessionPlan,
    runs: &[RunRecord],
    header: &str,
    dir: &Path,
) -> Result<Vec<PathBuf>, EvalError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| EvalError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let mut files = Vec::new();
    let md = dir.join("session.md");
    std::fs::write(&md, markdown(s, header)).map_err(io(&md))?;
    files.push(md);

    #[derive(Serialize)]
    struct SessionRun<'a> {
        controller: &'a str,
        repeat: u32,
        seed: u64,
        ticks: u64,
        invalid_estimates: usize,
        points: Vec<SessionPoint>,
    }
    let session_runs: Vec<SessionRun> = runs
        .iter()
        .map(|r| SessionRun {
            controller: &r.controller,
            repeat: r.repeat,
            seed: r.seed,
            ticks: r.ticks,
            invalid_estimates: r.invalid_estimates,
            points: r
                .points
                .iter()
                .zip(&plan.labels)
                .map(|(p, l)| SessionPoint {
                    t_s: t_s(p),
                    lap: l.lap,
                    trajectory: l.trajectory.map(|k| plan.trajectories[k].clone()),
                    record: *p,
                })
                .collect(),
        })
        .collect();
    let json = dir.join("session.json");
    let value = serde_json::json!({ "header": header, "summary": s, "runs": session_runs });
    std::fs::write(&json, serde_json::to_string_pretty(&value).unwrap_or_default()).map_err(io(&json))?;
    files.push(json);

    let t_max = s.duration_s.max(1.0);
    let markers: Vec<(String, f64)> = s.slack.marks.clone();
    // One line per controller, in the same colour on both plots.
    let series = |f: &dyn Fn(&WindowCell) -> Option<f64>| -> Vec<(String, Vec<(f64, f64)>)> {
        s.controllers
            .iter()
            .map(|c| {
                let v: Vec<(f64, f64)> = s
                    .windows
                    .iter()
                    .filter_map(|w| {
                        let x = w.cells.iter().find(|x| &x.controller == c)?;
                        f(x).map(|y| (0.5 * (w.t_start_s + w.t_end_s), y))
                    })
                    .collect();
                (c.clone(), v)
            })
            .collect()
    };
    let err = series(&|x| Some(x.cell.task_truth.pos_mean_mm));
    let ymax = err
        .iter()
        .flat_map(|(_, v)| v.iter().map(|p| p.1))
        .fold(1.0f64, f64::max)
        * 1.15;
    let err_file = dir.join("session_error.svg");
    line_plot_marked(
        &err_file,
        (960, 460),
        &format!("tip position error per {:.0} s window (truth)", s.window_s),
        ("simulated time [s]", "position error [mm]"),
        (0.0..t_max, 0.0..ymax),
        None,
        &err,
        &markers,
        SeriesLabelPosition::MiddleLeft,
    )?;
    files.push(err_file);
    // Uncalibrated is the 0 % line the gains are measured from.
    let gain = series(&|x| {
        if x.controller == "uncalibrated" {
            Some(0.0)
        } else {
            x.gain_position_truth.map(|g| 100.0 * g)
        }
    });
    let has_gain = s.controllers.iter().any(|c| c == "uncalibrated") && s.controllers.len() > 1;
    if has_gain {
        let (lo, hi) = gain
            .iter()
            .flat_map(|(_, v)| v.iter().map(|p| p.1))
            .fold((0.0f64, 100.0f64), |(lo, hi), y| (lo.min(y), hi.max(y)));
        let gain_file = dir.join("session_gain.svg");
        line_plot_marked(
            &gain_file,
            (960, 460),
            &format!(
                "gain over uncalibrated per {:.0} s window (truth, position)",
                s.window_s
            ),
            ("simulated time [s]", "1 − calibrated / uncalibrated [%]"),
            (0.0..t_max, (lo - 5.0)..(hi + 5.0)),
            None,
            &gain,
            &markers,
            SeriesLabelPosition::MiddleLeft,
        )?;
        files.push(gain_file);
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straight(a: &JointsDeg, b: &JointsDeg) -> Vec<JointsDeg> {
        // a, the midpoint, b.
        vec![*a, core::array::from_fn(|j| 0.5 * (a[j] + b[j])), *b]
    }

    #[test]
    fn the_plan_loops_the_trajectories_with_joining_moves_until_the_time_is_up() {
        let t = vec![
            ("a".to_string(), vec![[1.0; 5], [2.0; 5]]),
            ("b".to_string(), vec![[3.0; 5]]),
        ];
        // 100 ms ticks, 5 per point: one warm-up tick + the approach (1 point) = 0.6 s, then
        // 0.5 s per point; a lap is a1 a2 (a→b move) b1 (b→a move) = 5 points = 2.5 s.
        let p = plan(&t, 6.0, 5, 100_000_000, &straight).unwrap();
        assert_eq!(p.approach, vec![[0.5; 5]]);
        assert_eq!(p.lap_points, 5);
        assert!((p.lap_s - 2.5).abs() < 1e-12);
        assert_eq!(p.q_path.len(), 10, "(6.0 − 0.6) / 0.5 = 10.8 → 10 points");
        assert!((p.duration_s - 5.6).abs() < 1e-9);
        assert_eq!(&p.q_path[..5], &[[1.0; 5], [2.0; 5], [2.5; 5], [3.0; 5], [2.0; 5]]);
        assert_eq!(p.q_path[5], [1.0; 5]);
        let traj: Vec<Option<usize>> = p.labels.iter().map(|l| l.trajectory).collect();
        assert_eq!(&traj[..5], &[Some(0), Some(0), None, Some(1), None]);
        assert_eq!(p.labels[5].lap, 1);
        assert!(
            plan(&t, 0.9, 5, 100_000_000, &straight).is_err(),
            "too short for one point"
        );
        assert!(plan(&[("x".into(), vec![])], 60.0, 5, 100_000_000, &straight).is_err());
    }

    fn point(t_ns: u64, err_deg: f64) -> PointRecord {
        PointRecord {
            q_desired_deg: [10.0, 0.0, 0.0, 5.0, -5.0],
            q_cmd_deg: [0.0; 5],
            q_true_deg: [10.0 + err_deg, 0.0, 0.0, 5.0, -5.0],
            q_est_deg: None,
            ee_est: None,
            q_predicted_deg: None,
            refine_iterations: 0,
            t_sim_ns: t_ns,
        }
    }

    #[test]
    fn windows_stretches_and_the_lost_gain() {
        let robot = Robot::paper_default();
        let t = vec![("a".to_string(), vec![[10.0, 0.0, 0.0, 5.0, -5.0]; 4])];
        let same = |a: &JointsDeg, b: &JointsDeg| vec![*a, *b];
        // 1 s per point (10 ticks of 100 ms), 4 points a lap, 16 points.
        let p = plan(&t, 16.9, 10, 100_000_000, &same).unwrap();
        assert_eq!((p.lap_points, p.q_path.len()), (4, 16));
        // Uncalibrated 4° off throughout; calibrated 1° off before t = 8 s, 2° after.
        let times: Vec<u64> = (0..16).map(|i| (1 + 10 + 10 * (i + 1)) * 100_000_000).collect();
        let run = |c: &str, f: &dyn Fn(u64) -> f64| RunRecord {
            trajectory: "session".into(),
            controller: c.into(),
            repeat: 0,
            seed: 1,
            points: times.iter().map(|&t| point(t, f(t))).collect(),
            invalid_estimates: 16,
            ticks: 0,
        };
        let runs = vec![
            run("uncalibrated", &|_| 4.0),
            run("newton", &|t| if t < 8_000_000_000 { 1.0 } else { 2.0 }),
        ];
        let slack = SlackEvents {
            onset_s: Some(8.0),
            marks: vec![("slip".into(), 8.0)],
            description: "test".into(),
        };
        let s = analyse(&robot, &p, &runs, 4.0, &slack).unwrap();
        // Points at 2.1, 3.1, …, 17.1 s: windows (0,4], (4,8], … up to (16,20].
        assert_eq!(s.windows.len(), 5);
        assert_eq!(s.windows[0].points, 2);
        // Lap 0 (2.1–5.1 s) is whole and before 8 s; lap 1 ends at 9.1 s: after the onset.
        assert_eq!(s.before.label, "lap 0 before the slack");
        assert_eq!(s.end.label, "lap 3, the last whole lap");
        let n = s.summary.iter().find(|c| c.controller == "newton").unwrap();
        // Error scales with the joint error on q1 (a pure rotation of the tip about the base):
        // 1° / 4° → gain 0.75, 2° / 4° → 0.5, lost 0.25 = a third of the gain before.
        assert!((n.gain_before.unwrap() - 0.75).abs() < 1e-3, "{:?}", n.gain_before);
        assert!((n.gain_end.unwrap() - 0.5).abs() < 1e-3, "{:?}", n.gain_end);
        assert!((n.gain_lost_relative.unwrap() - 1.0 / 3.0).abs() < 1e-2);
        let md = markdown(&s, "header");
        assert!(md.contains("| 2 | 8–12 (slip) |"), "{md}");
        assert!(md.contains("gain newton"));

        // Slack from 14.5 s: laps 0–2 come before it, lap 3 (from 14.1 s) straddles it, so the
        // end is the last window.
        let late = SlackEvents {
            onset_s: Some(14.5),
            ..slack
        };
        let s = analyse(&robot, &p, &runs, 4.0, &late).unwrap();
        assert_eq!(s.before.label, "laps 0–2 before the slack");
        assert_eq!(s.end.label, "window 4, the last");
        assert_eq!((s.end.t_start_s, s.end.points), (16.1, 2));
    }
}
