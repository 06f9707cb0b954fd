//! `bowden plant characterize`: the paper's dataset protocol (§IV-B) on the simulated plant.
//!
//! The eq. (16) commands are sent one by one as cable displacements (eq. 5); after each the
//! plant is held for the paper's 0.5 s pause and q_phy is read. Per joint this gives the
//! figures of the paper's Table IV (mean absolute error and standard deviation between
//! q_phy and q_cmd) and the hysteresis loops of its Fig. 9b (q_cmd against q_phy, q1 and q3).
//!
//! Two further figures tell a hysteresis from an offset or a lag:
//! - loop width: in 10° bins of q_cmd, the mean q_phy reached while the joint was last moving
//!   down minus the mean reached while it was moving up (about the overall regression line);
//!   0 for an offset or a gain;
//! - lag residual: the RMS residual of the best affine fit q_phy(t) ≈ a·q_cmd(t − k) + b over
//!   lags k = 0…5 samples; ≈ 0 for a constant offset, a gain, or a pure lag.

use serde::Serialize;
use std::path::Path;

use bowden_kinematics::{JointsDeg, Robot, JOINT_NAMES, N_JOINTS};
use bowden_trajectory::dataset_commands;

use crate::config::PlantConfig;
use crate::plant::{Plant, PlantBuildError, PlantError};

/// Table IV of the paper: (MAE, SD) per joint, degrees.
pub const PAPER_TABLE_IV: [(f64, f64); N_JOINTS] = [
    (16.31, 11.59),
    (10.09, 7.67),
    (11.21, 7.56),
    (12.02, 8.91),
    (13.84, 10.37),
];

/// The range the simulated plant must reproduce on every joint: MAE 10–16°, SD 7–11°.
pub const TARGET_MAE_DEG: (f64, f64) = (10.0, 16.0);
pub const TARGET_SD_DEG: (f64, f64) = (7.0, 11.0);

/// Why [`characterize`] (or [`joint_reach_deg`]) stopped: the plant could not be built for the
/// requested unit, or it refused a command.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CharacterizeError {
    #[error(transparent)]
    Build(#[from] PlantBuildError),
    #[error(transparent)]
    Step(#[from] PlantError),
}

/// How to run the protocol.
#[derive(Debug, Clone, Serialize)]
pub struct CharacterizeOptions {
    /// Random configurations of eq. (16) (the paper: 1,802).
    pub n_configs: usize,
    /// Seed of the eq. (16) commands.
    pub dataset_seed: u64,
    /// Seed of the plant instance (its manufacturing variation).
    pub plant_seed: u64,
    /// Hold per command, s (the paper: 0.5).
    pub pause_s: f64,
    /// Simulation step, s.
    pub dt_s: f64,
}

impl Default for CharacterizeOptions {
    fn default() -> Self {
        Self {
            n_configs: bowden_trajectory::PAPER_DATASET_CONFIGS,
            dataset_seed: 1,
            plant_seed: 1,
            pause_s: 0.5,
            dt_s: 0.01,
        }
    }
}

/// Figures of one joint over the whole run, degrees.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct JointStats {
    pub joint: String,
    /// Mean of |q_phy − q_cmd| (Table IV's MAE).
    pub mae_deg: f64,
    /// Standard deviation (population) of |q_phy − q_cmd| (Table IV's SD, read as the SD of the
    /// absolute error, which is what its magnitude next to the MAE implies).
    pub sd_abs_deg: f64,
    /// Mean and standard deviation of the signed error q_phy − q_cmd.
    pub mean_signed_deg: f64,
    pub sd_signed_deg: f64,
    pub rmse_deg: f64,
    pub max_abs_deg: f64,
    /// Direction-dependent width of the loop (see the module docs and [`loop_width_deg`]).
    pub loop_width_deg: f64,
    /// Residual of the best offset/gain/lag explanation (see the module docs).
    pub lag_residual_deg: f64,
    /// Slope of the least-squares line q_phy ≈ a·q_cmd + b (1 = no gain loss).
    pub fit_slope: f64,
    /// Range of q_phy this joint reaches when its command sweeps its whole limit range with the
    /// other joints at zero (see [`joint_reach_deg`]): what a compensator can ask of it.
    pub reach_deg: (f64, f64),
    /// The paper's Table IV for this joint.
    pub paper_mae_deg: f64,
    pub paper_sd_deg: f64,
}

/// The result of a characterization run.
#[derive(Debug, Clone, Serialize)]
pub struct Characterization {
    pub plant: String,
    pub options: CharacterizeOptions,
    pub n_commands: usize,
    pub joints: Vec<JointStats>,
    /// Whether every joint's MAE and SD lie in the paper's range (10–16°, 7–11°).
    pub in_paper_range: bool,
    #[serde(skip)]
    pub q_cmd_deg: Vec<JointsDeg>,
    #[serde(skip)]
    pub q_phy_deg: Vec<JointsDeg>,
}

/// Commands shown by Fig. 9a (the paper plotted 550 of its 30,707 pairs).
pub const FIG_9A_SAMPLES: usize = 550;

/// Bin size of the Fig. 9b density panels, degrees.
const DENSITY_BIN_DEG: f64 = 2.0;

/// Where [`Characterization::write_loop_plot`] writes Fig. 9a beside the loop plot `plot`:
/// `<stem>_timeseries.svg` in the same directory.
pub fn timeseries_path(plot: &Path) -> std::path::PathBuf {
    let stem = plot
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "plant_loops".into());
    plot.with_file_name(format!("{stem}_timeseries.svg"))
}

/// A plot that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("{path}: cannot write the plot: {message}")]
pub struct PlotError {
    pub path: std::path::PathBuf,
    pub message: String,
}

/// Runs the protocol: eq. (16) commands, each held `pause_s`, q_phy read at the end of the hold.
/// `progress(done, total)` is called after every command.
pub fn characterize(
    robot: &Robot,
    config: &PlantConfig,
    options: &CharacterizeOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Characterization, CharacterizeError> {
    let commands = dataset_commands(robot, options.n_configs, options.dataset_seed);
    let mut plant = Plant::try_new(robot, config, options.plant_seed)?;
    let mut q_phy = Vec::with_capacity(commands.len());
    for (k, q_cmd) in commands.iter().enumerate() {
        plant.settle_joints(q_cmd, options.pause_s, options.dt_s)?;
        q_phy.push(plant.q_phy_deg());
        progress(k + 1, commands.len());
    }
    let mut result = Characterization::from_samples(config.name.clone(), options.clone(), commands, q_phy);
    let reach = joint_reach_deg(robot, config, options.plant_seed, options.pause_s, options.dt_s)?;
    for (j, r) in result.joints.iter_mut().zip(reach) {
        j.reach_deg = r;
    }
    Ok(result)
}

/// For each joint, the q_phy reached at the ends of a sweep of its command from one limit to the
/// other and back (3° steps, each held `pause_s`; the other joints at zero, the other jaw held
/// open at its limit so the jaws do not meet). Hysteresis and stretch keep q_phy inside the
/// command range: this is the range a compensator can actually reach.
pub fn joint_reach_deg(
    robot: &Robot,
    config: &PlantConfig,
    plant_seed: u64,
    pause_s: f64,
    dt_s: f64,
) -> Result<[(f64, f64); N_JOINTS], CharacterizeError> {
    let lim = &robot.config.limits;
    let mut out = [(0.0, 0.0); N_JOINTS];
    for (j, r) in out.iter_mut().enumerate() {
        let mut plant = Plant::try_new(robot, config, plant_seed)?;
        let mut q = [0.0; N_JOINTS];
        match j {
            3 => q[4] = lim.q_max_deg[4],
            4 => q[3] = lim.q_min_deg[3],
            _ => {}
        }
        let (lo, hi) = (lim.q_min_deg[j], lim.q_max_deg[j]);
        let n = ((hi - lo) / 3.0).ceil() as usize;
        let mut go = |plant: &mut Plant, from: f64, to: f64| -> Result<f64, PlantError> {
            for k in 0..=n {
                q[j] = from + (to - from) * k as f64 / n as f64;
                plant.settle_joints(&robot.clamp_to_limits(&q), pause_s, dt_s)?;
            }
            Ok(plant.q_phy_deg()[j])
        };
        go(&mut plant, 0.0, lo)?;
        let top = go(&mut plant, lo, hi)?;
        let bottom = go(&mut plant, hi, lo)?;
        *r = (bottom, top);
    }
    Ok(out)
}

impl Characterization {
    /// Statistics of paired command / physical samples.
    pub fn from_samples(
        plant: String,
        options: CharacterizeOptions,
        q_cmd_deg: Vec<JointsDeg>,
        q_phy_deg: Vec<JointsDeg>,
    ) -> Self {
        let joints: Vec<JointStats> = (0..N_JOINTS)
            .map(|j| {
                let cmd: Vec<f64> = q_cmd_deg.iter().map(|q| q[j]).collect();
                let phy: Vec<f64> = q_phy_deg.iter().map(|q| q[j]).collect();
                joint_stats(j, &cmd, &phy)
            })
            .collect();
        let in_paper_range = joints.iter().all(|s| {
            (TARGET_MAE_DEG.0..=TARGET_MAE_DEG.1).contains(&s.mae_deg)
                && (TARGET_SD_DEG.0..=TARGET_SD_DEG.1).contains(&s.sd_abs_deg)
        });
        Self {
            plant,
            options,
            n_commands: q_cmd_deg.len(),
            joints,
            in_paper_range,
            q_cmd_deg,
            q_phy_deg,
        }
    }

    /// Table IV style Markdown table, with the paper's figures beside ours.
    pub fn markdown_table(&self) -> String {
        let mut s = String::new();
        s.push_str(&format!(
            "Plant `{}`: {} commands from {} random configurations (eq. 16, dataset seed {}, plant seed {}), \
             each held {} s (dt {} s).\n\
             MAE = mean |q_phy − q_cmd|; SD = standard deviation of |q_phy − q_cmd| (population). Degrees.\n\
             slope: least-squares q_phy ≈ slope·q_cmd + b; loop width: q_phy moving down − moving up at the same \
             q_cmd; lag residual: what no offset, gain or lag of ≤ 5 samples explains; reach: q_phy at the ends \
             of a limit-to-limit sweep of that joint alone.\n\n",
            self.plant,
            self.n_commands,
            self.options.n_configs,
            self.options.dataset_seed,
            self.options.plant_seed,
            self.options.pause_s,
            self.options.dt_s
        ));
        s.push_str(
            "| joint | MAE | SD | paper MAE | paper SD | mean signed | SD signed | max | slope | loop width | lag residual | reach |\n",
        );
        s.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
        for j in &self.joints {
            s.push_str(&format!(
                "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:+.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:+.1} … {:+.1} |\n",
                j.joint,
                j.mae_deg,
                j.sd_abs_deg,
                j.paper_mae_deg,
                j.paper_sd_deg,
                j.mean_signed_deg,
                j.sd_signed_deg,
                j.max_abs_deg,
                j.fit_slope,
                j.loop_width_deg,
                j.lag_residual_deg,
                j.reach_deg.0,
                j.reach_deg.1
            ));
        }
        s.push_str(&format!(
            "\nPaper range (MAE {}–{}°, SD {}–{}° on every joint): {}\n",
            TARGET_MAE_DEG.0,
            TARGET_MAE_DEG.1,
            TARGET_SD_DEG.0,
            TARGET_SD_DEG.1,
            if self.in_paper_range { "yes" } else { "NO" }
        ));
        s
    }

    /// Fig. 9b style hysteresis loops, SVG: q_cmd against q_phy for q1 and q3 over the whole run
    /// as a density (top: thousands of overlapping loops would be a solid blob as lines) and
    /// over the first 400 commands with every sample marked (bottom). Also writes Fig. 9a beside
    /// it, as [`timeseries_path`]`(path)` (see [`Self::write_timeseries_plot`]).
    pub fn write_loop_plot(&self, path: &Path) -> Result<(), PlotError> {
        self.write_density_loops(path)?;
        self.write_timeseries_plot(&timeseries_path(path), FIG_9A_SAMPLES)
    }

    /// Fig. 9a style, SVG: command and physical angle of every joint (one panel each) over the
    /// first `n` commands of the run (the paper plotted 550 of its 30,707 pairs).
    pub fn write_timeseries_plot(&self, path: &Path, n: usize) -> Result<(), PlotError> {
        use plotters::prelude::*;
        use plotters::style::text_anchor::{HPos, Pos, VPos};
        let err = |e: &dyn std::fmt::Display| PlotError {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let n = n.min(self.q_cmd_deg.len());
        let (w, panel_h, legend_h) = (1400u32, 230u32, 34u32);
        let root = SVGBackend::new(path, (w, 50 + legend_h + panel_h * N_JOINTS as u32)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let root = root
            .titled(
                &format!(
                    "Command and physical joint angles, first {n} of {} commands, plant `{}` (Fig. 9a)",
                    self.q_cmd_deg.len(),
                    self.plant
                ),
                ("sans-serif", 22),
            )
            .map_err(|e| err(&e))?;
        let (legend, rest) = root.split_vertically(legend_h);
        // The legend on its own strip, off the data.
        let style = TextStyle::from(("sans-serif", 15).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
        let y = legend_h as i32 / 2;
        for (x, label, color, width) in [
            (20, "q_cmd (command)", BLACK, 1),
            (240, "q_phy (physical, settled)", RGBColor(200, 40, 40), 2),
        ] {
            legend
                .draw(&PathElement::new(vec![(x, y), (x + 26, y)], color.stroke_width(width)))
                .map_err(|e| err(&e))?;
            legend
                .draw(&Text::new(label, (x + 34, y), style.clone()))
                .map_err(|e| err(&e))?;
        }
        for (j, panel) in rest.split_evenly((N_JOINTS, 1)).iter().enumerate() {
            let (lo, hi) = self.q_cmd_deg[..n]
                .iter()
                .chain(&self.q_phy_deg[..n])
                .map(|q| q[j])
                .fold((-5.0f64, 5.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
            let pad = 0.06 * (hi - lo);
            let mut chart = ChartBuilder::on(panel)
                .margin(8)
                .x_label_area_size(if j + 1 == N_JOINTS { 36 } else { 18 })
                .y_label_area_size(56)
                .build_cartesian_2d(0.0..n.max(2) as f64, (lo - pad)..(hi + pad))
                .map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .light_line_style(WHITE.mix(0.0))
                .x_desc(if j + 1 == N_JOINTS { "command index" } else { "" })
                .y_desc(format!("{} [deg]", JOINT_NAMES[j]))
                .draw()
                .map_err(|e| err(&e))?;
            chart
                .draw_series(LineSeries::new(
                    (0..n).map(|k| (k as f64, self.q_cmd_deg[k][j])),
                    BLACK.stroke_width(1),
                ))
                .map_err(|e| err(&e))?;
            chart
                .draw_series(LineSeries::new(
                    (0..n).map(|k| (k as f64, self.q_phy_deg[k][j])),
                    RGBColor(200, 40, 40).stroke_width(2),
                ))
                .map_err(|e| err(&e))?;
        }
        root.present().map_err(|e| err(&e))?;
        Ok(())
    }

    fn write_density_loops(&self, path: &Path) -> Result<(), PlotError> {
        use plotters::prelude::*;
        let err = |e: &dyn std::fmt::Display| PlotError {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        let root = SVGBackend::new(path, (1200, 1100)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(&e))?;
        let root = root
            .titled(
                &format!(
                    "Hysteresis loops, plant `{}`: q_cmd vs q_phy (eq. 16 commands, settled {} s; Fig. 9b)",
                    self.plant, self.options.pause_s
                ),
                ("sans-serif", 22),
            )
            .map_err(|e| err(&e))?;
        let panels = root.split_evenly((2, 2));
        let lim = |j: usize| {
            let m = self
                .q_cmd_deg
                .iter()
                .chain(self.q_phy_deg.iter())
                .map(|q| q[j].abs())
                .fold(10.0f64, f64::max);
            (m / 10.0).ceil() * 10.0
        };
        let first = self.q_cmd_deg.len().min(400);
        for (panel, (j, n, marks)) in panels.iter().zip([
            (0, self.q_cmd_deg.len(), false),
            (2, self.q_cmd_deg.len(), false),
            (0, first, true),
            (2, first, true),
        ]) {
            let m = lim(j);
            let caption = if marks {
                format!("{}: first {} commands", JOINT_NAMES[j], n)
            } else {
                format!(
                    "{}: all {} commands, density ({}° bins, darker = more)",
                    JOINT_NAMES[j], n, DENSITY_BIN_DEG
                )
            };
            let mut chart = ChartBuilder::on(panel)
                .caption(caption, ("sans-serif", 18))
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(50)
                .build_cartesian_2d(-m..m, -m..m)
                .map_err(|e| err(&e))?;
            chart
                .configure_mesh()
                .x_desc(format!("{} command [deg]", JOINT_NAMES[j]))
                .y_desc(format!("{} physical [deg]", JOINT_NAMES[j]))
                .draw()
                .map_err(|e| err(&e))?;
            chart
                .draw_series(LineSeries::new([(-m, -m), (m, m)], BLACK.mix(0.5)))
                .map_err(|e| err(&e))?;
            let pts = (0..n).map(|k| (self.q_cmd_deg[k][j], self.q_phy_deg[k][j]));
            let color = if j == 0 { BLUE } else { RED };
            if marks {
                chart
                    .draw_series(LineSeries::new(pts.clone(), color.mix(0.6)))
                    .map_err(|e| err(&e))?;
                chart
                    .draw_series(pts.map(|p| Circle::new(p, 2, color.filled())))
                    .map_err(|e| err(&e))?;
            } else {
                // Every sample counted in a DENSITY_BIN_DEG square; shade ∝ log(1 + count).
                let mut bins: std::collections::BTreeMap<(i64, i64), u32> = Default::default();
                for (c, p) in pts {
                    let key = (
                        (c / DENSITY_BIN_DEG).floor() as i64,
                        (p / DENSITY_BIN_DEG).floor() as i64,
                    );
                    *bins.entry(key).or_default() += 1;
                }
                let top = f64::from(bins.values().copied().max().unwrap_or(1)).ln_1p();
                chart
                    .draw_series(bins.iter().map(|(&(bx, by), &count)| {
                        let (x0, y0) = (bx as f64 * DENSITY_BIN_DEG, by as f64 * DENSITY_BIN_DEG);
                        let shade = 0.12 + 0.88 * f64::from(count).ln_1p() / top;
                        Rectangle::new(
                            [(x0, y0), (x0 + DENSITY_BIN_DEG, y0 + DENSITY_BIN_DEG)],
                            color.mix(shade).filled(),
                        )
                    }))
                    .map_err(|e| err(&e))?;
            }
        }
        root.present().map_err(|e| err(&e))?;
        Ok(())
    }
}

fn joint_stats(j: usize, cmd: &[f64], phy: &[f64]) -> JointStats {
    let n = cmd.len().max(1) as f64;
    let err: Vec<f64> = phy.iter().zip(cmd).map(|(p, c)| p - c).collect();
    let mean = |v: &mut dyn Iterator<Item = f64>| v.sum::<f64>() / n;
    let mae = mean(&mut err.iter().map(|e| e.abs()));
    let sd_abs = mean(&mut err.iter().map(|e| (e.abs() - mae).powi(2))).sqrt();
    let mean_signed = mean(&mut err.iter().copied());
    let sd_signed = mean(&mut err.iter().map(|e| (e - mean_signed).powi(2))).sqrt();
    let rmse = mean(&mut err.iter().map(|e| e * e)).sqrt();
    let max_abs = err.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    JointStats {
        joint: JOINT_NAMES[j].to_string(),
        mae_deg: mae,
        sd_abs_deg: sd_abs,
        mean_signed_deg: mean_signed,
        sd_signed_deg: sd_signed,
        rmse_deg: rmse,
        max_abs_deg: max_abs,
        loop_width_deg: loop_width_deg(cmd, phy),
        lag_residual_deg: lag_residual_deg(cmd, phy),
        fit_slope: affine_fit(cmd, phy).0,
        reach_deg: (f64::NAN, f64::NAN),
        paper_mae_deg: PAPER_TABLE_IV[j].0,
        paper_sd_deg: PAPER_TABLE_IV[j].1,
    }
}

/// Mean over 10° bins of q_cmd of (q_phy reached moving down − q_phy reached moving up),
/// weighted by the bins' sample counts; bins need 5 samples of each direction. q_phy is taken
/// relative to the least-squares line through all samples, so that the spread of q_cmd inside a
/// bin does not count: any single-valued affine map gives exactly 0.
pub fn loop_width_deg(cmd: &[f64], phy: &[f64]) -> f64 {
    const BIN_DEG: f64 = 10.0;
    let (slope, _) = affine_fit(cmd, phy);
    let mut bins: std::collections::BTreeMap<i64, [(f64, usize); 2]> = Default::default();
    let mut direction = 0i8;
    for k in 1..cmd.len() {
        let d = cmd[k] - cmd[k - 1];
        if d > 1e-9 {
            direction = 1;
        } else if d < -1e-9 {
            direction = -1;
        }
        if direction == 0 {
            continue;
        }
        let b = bins.entry((cmd[k] / BIN_DEG).floor() as i64).or_default();
        let slot = &mut b[usize::from(direction < 0)];
        slot.0 += phy[k] - slope * cmd[k];
        slot.1 += 1;
    }
    let (mut sum, mut weight) = (0.0, 0usize);
    for [(up_sum, up_n), (down_sum, down_n)] in bins.values() {
        if *up_n >= 5 && *down_n >= 5 {
            let w = up_n + down_n;
            sum += (down_sum / *down_n as f64 - up_sum / *up_n as f64) * w as f64;
            weight += w;
        }
    }
    if weight == 0 {
        0.0
    } else {
        sum / weight as f64
    }
}

/// Least-squares line y ≈ a·x + b: (a, RMS residual).
pub fn affine_fit(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len().min(y.len());
    if n == 0 {
        return (0.0, 0.0);
    }
    let (x, y) = (&x[..n], &y[..n]);
    let nf = n as f64;
    let (mx, my) = (x.iter().sum::<f64>() / nf, y.iter().sum::<f64>() / nf);
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let a = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let rms = (x
        .iter()
        .zip(y)
        .map(|(u, v)| (v - my - a * (u - mx)).powi(2))
        .sum::<f64>()
        / nf)
        .sqrt();
    (a, rms)
}

/// Smallest RMS residual of an affine fit q_phy(t) ≈ a·q_cmd(t − k) + b over k = 0…5.
pub fn lag_residual_deg(cmd: &[f64], phy: &[f64]) -> f64 {
    let mut best = f64::INFINITY;
    for lag in 0..=5usize {
        if cmd.len() <= lag + 2 {
            break;
        }
        best = best.min(affine_fit(&cmd[..cmd.len() - lag], &phy[lag..]).1);
    }
    if best.is_finite() {
        best
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Straight 3° steps between targets of varying amplitude, like one joint under eq. (16).
    fn walk() -> Vec<f64> {
        let targets = [
            40.0, -10.0, 25.0, 14.0, -35.0, 5.0, -2.0, 30.0, -20.0, 10.0, -40.0, 35.0, 20.0,
        ];
        let mut out = vec![0.0f64];
        for _ in 0..4 {
            for &t in &targets {
                let mut x = *out.last().unwrap();
                while (t - x).abs() > 3.0 {
                    x += 3.0 * (t - x).signum();
                    out.push(x);
                }
                out.push(t);
            }
        }
        out
    }

    #[test]
    fn metrics_tell_hysteresis_from_offset_gain_and_lag() {
        let cmd = walk();
        let offset: Vec<f64> = cmd.iter().map(|c| 0.8 * c + 5.0).collect();
        let lag: Vec<f64> = (0..cmd.len()).map(|k| cmd[k.saturating_sub(2)]).collect();
        let mut z = 0.0;
        let backlash: Vec<f64> = cmd
            .iter()
            .map(|&c| {
                z = crate::hysteresis::play(z, c, 8.0);
                z
            })
            .collect();
        assert!(loop_width_deg(&cmd, &offset).abs() < 1e-9);
        assert!(lag_residual_deg(&cmd, &offset) < 1e-9);
        assert!(lag_residual_deg(&cmd, &lag) < 1e-9);
        assert!(loop_width_deg(&cmd, &backlash) > 10.0);
        assert!(lag_residual_deg(&cmd, &backlash) > 2.0);
    }
}
