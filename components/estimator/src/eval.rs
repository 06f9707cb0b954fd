//! Accuracy and speed of the estimator against ground truth: seeded random configurations
//! over the workspace are rendered by the synthetic camera (the only source that knows the truth
//! of every frame), estimated, and
//! compared with the truth. Produces an [`EvalReport`] (JSON via serde, a Markdown table,
//! an SVG plot).

use crate::{Estimator, MarkerStatus};
use bowden_camera::SyntheticCamera;
use bowden_interfaces::{marker, JointEstimate, MarkerSet, N_MARKERS};
use bowden_kinematics::{JointsDeg, Robot, JOINT_NAMES, N_JOINTS};
use bowden_latency::{LatencyHistogram, Percentiles};
use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The goals of the estimator (issue 4), checked by [`EvalReport::goal_failures`].
pub const GOAL_CENTRE_RMS_MM: f64 = 0.5;
pub const GOAL_JOINT_RMS_DEG: f64 = 1.0;
pub const GOAL_DETECTION_RATE: f64 = 0.99;
pub const GOAL_P99_US: f64 = 3000.0;

/// A uniformly random configuration within the joint limits whose jaws do not cross.
pub fn random_configuration(robot: &Robot, rng: &mut ChaCha8Rng) -> JointsDeg {
    let lim = &robot.config.limits;
    loop {
        let q: JointsDeg = core::array::from_fn(|j| rng.random_range(lim.q_min_deg[j]..=lim.q_max_deg[j]));
        if robot.check_limits(&q).is_ok() {
            return q;
        }
    }
}

/// What to evaluate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EvalOptions {
    pub frames: u32,
    pub seed: u64,
    /// The IK hint is the truth plus a uniform offset in ±this per joint (the command
    /// differs from the physical angle by the hysteresis); `None`: no hint.
    pub hint_offset_deg: Option<f64>,
}

/// One frame of the evaluation with its worst joint error.
#[derive(Debug, Clone, Serialize)]
pub struct FrameRecord {
    pub index: u64,
    pub q_true_deg: JointsDeg,
    /// NaN where the joint was not reported.
    pub q_est_deg: JointsDeg,
    pub quality: u32,
    pub valid_markers: u32,
    pub max_joint_error_deg: f64,
    pub marker_status: [&'static str; N_MARKERS],
    /// Wall time of `estimate`, µs.
    pub time_us: f64,
}

/// Result of an evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct EvalReport {
    pub options: EvalOptions,
    pub width: u32,
    pub height: u32,
    /// Fraction of frames with all five joints estimated.
    pub detection_rate: f64,
    pub partial_rate: f64,
    pub invalid_rate: f64,
    /// Fraction of frames in which each marker was valid.
    pub marker_detection_rate: [f64; N_MARKERS],
    /// Sphere-centre error over every valid marker of every frame, mm.
    pub centre_error_rms_mm: f64,
    pub centre_error_max_mm: f64,
    pub centre_error_rms_mm_per_marker: [f64; N_MARKERS],
    /// Joint error over the frames where the joint was reported, degrees.
    pub joint_error_rms_deg: [f64; N_JOINTS],
    pub joint_error_max_deg: [f64; N_JOINTS],
    /// The same for the paper's path alone (eq. 6–14 + IK, no joint-space fit).
    pub paper_joint_error_rms_deg: [f64; N_JOINTS],
    pub paper_joint_error_max_deg: [f64; N_JOINTS],
    /// Per-frame `estimate` wall time, µs.
    pub time_p50_us: f64,
    pub time_p99_us: f64,
    pub time_p999_us: f64,
    pub time_max_us: f64,
    /// The frames with the largest joint errors (and every frame not fully estimated), at
    /// most 10.
    pub worst_frames: Vec<FrameRecord>,
    /// Truth and estimate of every frame, for plots.
    #[serde(skip)]
    pub records: Vec<FrameRecord>,
}

/// `value` does not meet "at most `goal`" (NaN: nothing measured, also a miss).
fn misses(value: f64, goal: f64) -> bool {
    value.is_nan() || value > goal
}

#[derive(Default)]
struct Rms {
    ss: f64,
    n: u64,
    max: f64,
}

impl Rms {
    fn add(&mut self, e: f64) {
        self.ss += e * e;
        self.n += 1;
        self.max = self.max.max(e.abs());
    }
    fn rms(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            (self.ss / self.n as f64).sqrt()
        }
    }
    fn max(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            self.max
        }
    }
}

/// Why an evaluation stopped.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The camera could not render frame `frame`.
    #[error("rendering frame {frame} (q = {q_deg:?} deg): {source}")]
    Render {
        frame: u32,
        q_deg: JointsDeg,
        #[source]
        source: bowden_camera::CameraError,
    },
    /// The estimator refused frame `frame` as a whole.
    #[error("frame {frame}: {source}")]
    Frame {
        frame: u32,
        #[source]
        source: crate::EstimatorError,
    },
}

/// Runs the evaluation. `progress` is called after each frame with the number done.
// Long: the evaluation loop with its accumulators (per marker, per joint, timing) in one pass.
pub fn run_eval(
    estimator: &mut Estimator,
    camera: &mut SyntheticCamera,
    opts: &EvalOptions,
    mut progress: impl FnMut(u32),
) -> Result<EvalReport, EvalError> {
    let (w, h) = (camera.width(), camera.height());
    let mut rgb = vec![0u8; w as usize * h as usize * 3];
    let mut depth = vec![0u16; w as usize * h as usize];
    estimator.reserve_frame(w, h);
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let mut times = LatencyHistogram::new();
    let (mut n_valid, mut n_partial, mut n_invalid) = (0u32, 0u32, 0u32);
    let mut marker_found = [0u32; N_MARKERS];
    let mut centre_all = Rms::default();
    let mut centre_per: [Rms; N_MARKERS] = Default::default();
    let mut joint: [Rms; N_JOINTS] = Default::default();
    let mut paper: [Rms; N_JOINTS] = Default::default();
    let mut records = Vec::with_capacity(opts.frames as usize);
    let mut ms = MarkerSet::default();
    let mut je = JointEstimate::default();
    for i in 0..opts.frames {
        let q = random_configuration(estimator.robot(), &mut rng);
        let hint = opts
            .hint_offset_deg
            .map(|d| core::array::from_fn(|k| q[k] + if d > 0.0 { rng.random_range(-d..=d) } else { 0.0 }));
        camera
            .render(&q, i as u64, &mut rgb, &mut depth)
            .map_err(|source| EvalError::Render {
                frame: i,
                q_deg: q,
                source,
            })?;
        let header = camera.header(i as u64, i as u64, 0);
        let t0 = Instant::now();
        estimator
            .estimate(&header, &rgb, &depth, hint, &mut ms, &mut je)
            .map_err(|source| EvalError::Frame { frame: i, source })?;
        let dt_ns = t0.elapsed().as_nanos() as u64;
        times.record(dt_ns);

        let truth = camera.marker_centres_cam_mm(&q);
        for m in 0..N_MARKERS {
            if ms.valid_mask & (1 << m) != 0 {
                marker_found[m] += 1;
                let c = Point3::from(ms.centre_cam_mm[m]);
                let e = (c - truth[m]).norm();
                centre_all.add(e);
                centre_per[m].add(e);
            }
        }
        match je.quality {
            JointEstimate::QUALITY_VALID => n_valid += 1,
            JointEstimate::QUALITY_PARTIAL => n_partial += 1,
            _ => n_invalid += 1,
        }
        let mut q_est = [f64::NAN; N_JOINTS];
        let mut worst: f64 = 0.0;
        for k in 0..N_JOINTS {
            if je.joint_valid_mask & (1 << k) != 0 {
                q_est[k] = je.q_phy_deg[k];
                let e = je.q_phy_deg[k] - q[k];
                joint[k].add(e);
                worst = worst.max(e.abs());
            }
            let qp = estimator.diagnostics().q_paper_deg[k];
            if qp.is_finite() {
                paper[k].add(qp - q[k]);
            }
        }
        let status = estimator.diagnostics().marker_status;
        records.push(FrameRecord {
            index: i as u64,
            q_true_deg: q,
            q_est_deg: q_est,
            quality: je.quality,
            valid_markers: ms.valid_mask.count_ones(),
            max_joint_error_deg: if je.joint_valid_mask == 0 { f64::NAN } else { worst },
            marker_status: status.map(|s: MarkerStatus| s.label()),
            time_us: dt_ns as f64 / 1e3,
        });
        progress(i + 1);
    }
    let n = opts.frames.max(1) as f64;
    let time = times.percentiles();
    let mut worst_frames: Vec<FrameRecord> = records.clone();
    // Incomplete frames first, then by joint error.
    worst_frames.sort_by(|a, b| {
        let key = |r: &FrameRecord| {
            (
                r.quality == JointEstimate::QUALITY_VALID,
                -r.max_joint_error_deg.max(0.0),
            )
        };
        let (ka, kb) = (key(a), key(b));
        ka.0.cmp(&kb.0).then(ka.1.total_cmp(&kb.1)).then(a.index.cmp(&b.index))
    });
    worst_frames.truncate(10);
    Ok(EvalReport {
        options: *opts,
        width: w,
        height: h,
        detection_rate: n_valid as f64 / n,
        partial_rate: n_partial as f64 / n,
        invalid_rate: n_invalid as f64 / n,
        marker_detection_rate: marker_found.map(|c| c as f64 / n),
        centre_error_rms_mm: centre_all.rms(),
        centre_error_max_mm: centre_all.max(),
        centre_error_rms_mm_per_marker: core::array::from_fn(|m| centre_per[m].rms()),
        joint_error_rms_deg: core::array::from_fn(|k| joint[k].rms()),
        joint_error_max_deg: core::array::from_fn(|k| joint[k].max()),
        paper_joint_error_rms_deg: core::array::from_fn(|k| paper[k].rms()),
        paper_joint_error_max_deg: core::array::from_fn(|k| paper[k].max()),
        time_p50_us: Percentiles::us(time.p50_ns),
        time_p99_us: Percentiles::us(time.p99_ns),
        time_p999_us: Percentiles::us(time.p999_ns),
        time_max_us: Percentiles::us(time.max_ns),
        worst_frames,
        records,
    })
}

impl EvalReport {
    /// The goals this run misses, one line each (empty: all met). Timing is included; it
    /// is only meaningful for a release build on an idle core.
    pub fn goal_failures(&self, include_timing: bool) -> Vec<String> {
        let mut out = Vec::new();
        if misses(self.centre_error_rms_mm, GOAL_CENTRE_RMS_MM) {
            out.push(format!(
                "sphere-centre error {:.3} mm RMS > {GOAL_CENTRE_RMS_MM} mm",
                self.centre_error_rms_mm
            ));
        }
        for k in 0..N_JOINTS {
            if misses(self.joint_error_rms_deg[k], GOAL_JOINT_RMS_DEG) {
                out.push(format!(
                    "{} error {:.3} deg RMS > {GOAL_JOINT_RMS_DEG} deg",
                    JOINT_NAMES[k], self.joint_error_rms_deg[k]
                ));
            }
        }
        if misses(-self.detection_rate, -GOAL_DETECTION_RATE) {
            out.push(format!(
                "detection rate {:.2} % < {} %",
                100.0 * self.detection_rate,
                100.0 * GOAL_DETECTION_RATE
            ));
        }
        if include_timing && misses(self.time_p99_us, GOAL_P99_US) {
            out.push(format!("p99 frame time {:.0} us > {GOAL_P99_US} us", self.time_p99_us));
        }
        out
    }

    /// The report as Markdown tables.
    pub fn to_markdown(&self) -> String {
        let f = |v: f64, d: usize| {
            if v.is_finite() {
                format!("{v:.d$}")
            } else {
                "–".into()
            }
        };
        let mut s = String::new();
        s.push_str(&format!(
            "# Estimator evaluation\n\n{} frames of {}×{}, seed {}, hint {}\n\n",
            self.options.frames,
            self.width,
            self.height,
            self.options.seed,
            match self.options.hint_offset_deg {
                Some(d) => format!("truth ± {d}° (uniform)"),
                None => "none".into(),
            }
        ));
        s.push_str("| measure | value | goal |\n|---|---|---|\n");
        s.push_str(&format!(
            "| detection rate (all 5 joints) | {} % | ≥ {} % |\n",
            f(100.0 * self.detection_rate, 2),
            100.0 * GOAL_DETECTION_RATE
        ));
        s.push_str(&format!(
            "| partial / invalid frames | {} % / {} % | |\n",
            f(100.0 * self.partial_rate, 2),
            f(100.0 * self.invalid_rate, 2)
        ));
        s.push_str(&format!(
            "| sphere-centre error RMS / max | {} / {} mm | ≤ {GOAL_CENTRE_RMS_MM} mm RMS |\n",
            f(self.centre_error_rms_mm, 3),
            f(self.centre_error_max_mm, 3)
        ));
        s.push_str(&format!(
            "| frame time p50 / p99 / p99.9 / max | {} / {} / {} / {} µs | p99 ≤ {GOAL_P99_US} µs |\n\n",
            f(self.time_p50_us, 0),
            f(self.time_p99_us, 0),
            f(self.time_p999_us, 0),
            f(self.time_max_us, 0)
        ));
        s.push_str("| joint | RMS error (°) | max error (°) | paper path RMS (°) | paper path max (°) |\n");
        s.push_str("|---|---|---|---|---|\n");
        for k in 0..N_JOINTS {
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} |\n",
                JOINT_NAMES[k],
                f(self.joint_error_rms_deg[k], 3),
                f(self.joint_error_max_deg[k], 3),
                f(self.paper_joint_error_rms_deg[k], 3),
                f(self.paper_joint_error_max_deg[k], 3)
            ));
        }
        s.push_str("\n| marker | detected | centre error RMS (mm) |\n|---|---|---|\n");
        for m in 0..N_MARKERS {
            s.push_str(&format!(
                "| {} | {} % | {} |\n",
                marker::NAMES[m],
                f(100.0 * self.marker_detection_rate[m], 2),
                f(self.centre_error_rms_mm_per_marker[m], 3)
            ));
        }
        let failures = self.goal_failures(true);
        s.push_str(if failures.is_empty() {
            "\nAll goals met.\n"
        } else {
            "\nGoals missed:\n"
        });
        for l in failures {
            s.push_str(&format!("- {l}\n"));
        }
        s
    }

    /// Joint error against the true angle, one panel per joint, as SVG.
    pub fn write_svg(&self, path: &Path) -> Result<(), PlotError> {
        self.draw_svg(path).map_err(|message| PlotError {
            path: path.to_path_buf(),
            message,
        })
    }

    // plotters' errors are generic over the backend; the message is what a user can act on.
    fn draw_svg(&self, path: &Path) -> Result<(), String> {
        use plotters::prelude::*;
        let root = SVGBackend::new(path, (1500, 900)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let root = root
            .titled(
                "estimator: joint error (estimate − truth) vs true angle",
                ("sans-serif", 22),
            )
            .map_err(|e| e.to_string())?;
        let panels = root.split_evenly((2, 3));
        let lim = 2.0f64.max(
            self.joint_error_max_deg
                .iter()
                .filter(|v| v.is_finite())
                .fold(0.0f64, |a, b| a.max(*b))
                .min(20.0)
                * 1.1,
        );
        for k in 0..N_JOINTS {
            let mut chart = ChartBuilder::on(&panels[k])
                .caption(
                    format!("{} (RMS {:.3}°)", JOINT_NAMES[k], self.joint_error_rms_deg[k]),
                    ("sans-serif", 18),
                )
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(50)
                .build_cartesian_2d(-65.0f64..65.0, -lim..lim)
                .map_err(|e| e.to_string())?;
            chart
                .configure_mesh()
                .x_desc("true angle (deg)")
                .y_desc("error (deg)")
                .draw()
                .map_err(|e| e.to_string())?;
            chart
                .draw_series(
                    self.records
                        .iter()
                        .filter(|r| r.q_est_deg[k].is_finite())
                        .map(|r| Circle::new((r.q_true_deg[k], r.q_est_deg[k] - r.q_true_deg[k]), 2, BLUE.filled())),
                )
                .map_err(|e| e.to_string())?;
            for y in [-GOAL_JOINT_RMS_DEG, GOAL_JOINT_RMS_DEG] {
                chart
                    .draw_series(LineSeries::new([(-65.0, y), (65.0, y)], RED.stroke_width(1)))
                    .map_err(|e| e.to_string())?;
            }
        }
        // Sixth panel: centre error per marker.
        let mut chart = ChartBuilder::on(&panels[5])
            .caption("sphere-centre RMS error per marker (mm)", ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d(-0.5f64..6.5, 0.0f64..1.0f64.max(self.centre_error_max_mm.min(5.0)))
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .x_desc("marker")
            .y_desc("RMS error (mm)")
            .draw()
            .map_err(|e| e.to_string())?;
        // Each bar named by its marker (`bowden_interfaces::marker::NAMES`, configs/markers.toml).
        {
            use plotters::style::text_anchor::{HPos, Pos, VPos};
            let style = TextStyle::from(("sans-serif", 15).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
            for (m, name) in marker::NAMES.iter().enumerate() {
                chart
                    .plotting_area()
                    .draw(&(EmptyElement::at((m as f64, 0.0)) + Text::new(name.to_string(), (0, 6), style.clone())))
                    .map_err(|e| e.to_string())?;
            }
        }
        chart
            .draw_series(
                (0..N_MARKERS)
                    .filter(|m| self.centre_error_rms_mm_per_marker[*m].is_finite())
                    .map(|m| {
                        Rectangle::new(
                            [
                                (m as f64 - 0.3, 0.0),
                                (m as f64 + 0.3, self.centre_error_rms_mm_per_marker[m]),
                            ],
                            BLUE.filled(),
                        )
                    }),
            )
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(LineSeries::new(
                [(-0.5, GOAL_CENTRE_RMS_MM), (6.5, GOAL_CENTRE_RMS_MM)],
                RED.stroke_width(1),
            ))
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
        Ok(())
    }
}

/// A plot that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[error("{path}: cannot draw the plot: {message}")]
pub struct PlotError {
    pub path: std::path::PathBuf,
    pub message: String,
}
