//! The spacing of a dataset's commands: the grid the models learn one time step to be
//! ([`command_spacing_deg`], which `bowden tune` sets the history step from), and whether the
//! data hold any step larger than that grid ([`auto_decimation`], what `bowden train
//! --decimation auto` decides on).

use crate::dataset::Dataset;
use serde::Serialize;

/// Euclidean steps |Δq_cmd| between consecutive training rows, deg (repeats and non-finite
/// steps left out), sorted.
fn command_steps_deg(ds: &Dataset, train: &[usize]) -> Vec<f64> {
    let mut steps: Vec<f64> = train
        .windows(2)
        .filter(|w| w[1] == w[0] + 1)
        .map(|w| {
            let (a, b) = (ds.cmd(w[0]), ds.cmd(w[1]));
            a.iter().zip(b).map(|(x, y)| (y - x) * (y - x)).sum::<f64>().sqrt()
        })
        .filter(|d| d.is_finite() && *d > 1e-9)
        .collect();
    steps.sort_by(|a, b| a.total_cmp(b));
    steps
}

/// The 0.01° bin a step falls in.
fn bin(v: f64) -> i64 {
    (v * 100.0).round() as i64
}

/// The grid of sorted steps: the mean of the most frequent 0.01° bin if it holds ≥ 5 % of the
/// steps, else the median.
fn grid_of(steps: &[f64]) -> Option<f64> {
    let n = steps.len();
    if n == 0 {
        return None;
    }
    // Runs of equal 0.01° bins over the sorted steps; the longest wins (ties: the smallest step).
    let (mut best, mut best_len) = (0usize, 0usize);
    let mut k = 0;
    while k < n {
        let mut e = k + 1;
        while e < n && bin(steps[e]) == bin(steps[k]) {
            e += 1;
        }
        if e - k > best_len {
            (best, best_len) = (k, e - k);
        }
        k = e;
    }
    if best_len * 20 >= n {
        // The mean of the modal bin: exact for a grid (every member equal).
        return Some(steps[best..best + best_len].iter().sum::<f64>() / best_len as f64);
    }
    Some(if n % 2 == 1 {
        steps[n / 2]
    } else {
        0.5 * (steps[n / 2 - 1] + steps[n / 2])
    })
}

/// The models' time step in joint space, from the training commands themselves: the most
/// frequent Euclidean step between consecutive commands (to 0.01°), the grid the data was laid
/// on — eq. (16)'s 3·√5° for `collect`, whatever spacing a real robot's log used. Dither and
/// jumps spread their steps over many values and do not move the mode; where no step value
/// holds ≥ 5 % of the steps (no grid), the median. Repeats (a held command) are ignored.
pub fn command_spacing_deg(ds: &Dataset, train: &[usize]) -> Option<f64> {
    grid_of(&command_steps_deg(ds, train))
}

/// The largest history decimation `train --decimation auto` uses on single-step data. Chosen
/// on the transfer benchmark's tuning units only, among 4, 6 and 8, by tracking with the
/// paper's protocol; the figures are in docs/results/paper-protocol/README.md ("Decimated
/// histories").
pub const AUTO_DECIMATION: usize = 4;

/// Data count as single-step when fewer than this fraction of their steps exceed the grid.
/// eq. (16) data have none (steps clipped at a joint limit are shorter, never longer); the
/// mixed excitation has ≈ 85 %.
pub const SINGLE_STEP_MAX_LARGER_FRACTION: f64 = 0.01;

/// What `train --decimation auto` chose for a dataset, and why.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct DecimationChoice {
    /// The largest decimation to train with: [`AUTO_DECIMATION`] on single-step data, else 1.
    pub decimation: usize,
    /// The training commands' grid ([`command_spacing_deg`]), deg.
    pub grid_deg: f64,
    /// Steps between consecutive training commands (repeats left out).
    pub steps: usize,
    /// Fraction of those steps larger than the grid (in a higher 0.01° bin).
    pub larger_fraction: f64,
}

impl std::fmt::Display for DecimationChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let pct = 100.0 * self.larger_fraction;
        if self.decimation > 1 {
            write!(
                f,
                "decimation auto → {}: {:.2} % of the {} training steps exceed the commands' grid of {:.2}°, \
                 so without decimated histories the models would never see the larger steps a compensator sends",
                self.decimation, pct, self.steps, self.grid_deg
            )
        } else {
            write!(
                f,
                "decimation auto → 1: {:.1} % of the {} training steps exceed the commands' grid of {:.2}°, \
                 the data hold larger steps already",
                pct, self.steps, self.grid_deg
            )
        }
    }
}

/// `train --decimation auto`: decimate the training histories (by up to [`AUTO_DECIMATION`])
/// only when the training commands hold no step larger than their grid — data recorded on one
/// step size, as eq. (16)'s are, from which a model cannot learn what a larger step does,
/// while a compensator crossing the drive's dead band sends larger ones. Data with larger steps
/// already (the mixed excitation, a working log) train on consecutive samples: decimating them
/// again was measured to cost up to 4.5 points on the tuning units. `None` with fewer than two
/// consecutive training rows.
pub fn auto_decimation(ds: &Dataset, train: &[usize]) -> Option<DecimationChoice> {
    let steps = command_steps_deg(ds, train);
    let grid_deg = grid_of(&steps)?;
    let larger = steps.iter().filter(|&&s| bin(s) > bin(grid_deg)).count();
    let larger_fraction = larger as f64 / steps.len() as f64;
    let decimation = if larger_fraction < SINGLE_STEP_MAX_LARGER_FRACTION {
        AUTO_DECIMATION
    } else {
        1
    };
    Some(DecimationChoice {
        decimation,
        grid_deg,
        steps: steps.len(),
        larger_fraction,
    })
}

/// `train --decimation`: a number, or `auto` ([`auto_decimation`] decides from the data).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DecimationRule {
    #[default]
    Auto,
    /// Up to this many samples per model step; 1 = consecutive samples only (the paper).
    Fixed(usize),
}

impl std::str::FromStr for DecimationRule {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if s.eq_ignore_ascii_case("auto") {
            return Ok(Self::Auto);
        }
        match s.parse::<usize>() {
            Ok(0) | Err(_) => Err(format!(
                "decimation {s:?}: expected \"auto\" or a whole number ≥ 1 (1 = consecutive samples only)"
            )),
            Ok(n) => Ok(Self::Fixed(n)),
        }
    }
}

impl std::fmt::Display for DecimationRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Auto => f.write_str("auto"),
            Self::Fixed(n) => write!(f, "{n}"),
        }
    }
}

impl Serialize for DecimationRule {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::Auto => s.serialize_str("auto"),
            Self::Fixed(n) => s.serialize_u64(*n as u64),
        }
    }
}

/// Reads `"auto"` or a whole number ≥ 1 (TOML / JSON integer or string).
impl<'de> serde::Deserialize<'de> for DecimationRule {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Raw {
            N(i64),
            S(String),
        }
        match Raw::deserialize(d)? {
            Raw::N(n) if n >= 1 => Ok(Self::Fixed(n as usize)),
            Raw::N(n) => Err(serde::de::Error::custom(format!(
                "decimation {n}: expected \"auto\" or a whole number ≥ 1 (1 = consecutive samples only)"
            ))),
            Raw::S(s) => s.parse().map_err(serde::de::Error::custom),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dataset(cmds: &[[f64; 2]]) -> Dataset {
        let n = cmds.len();
        Dataset {
            joints: 2,
            t_ns: (0..n as i64).collect(),
            q_cmd_deg: cmds.iter().flatten().copied().collect(),
            q_phy_deg: cmds.iter().flatten().copied().collect(),
            q_true_deg: None,
            valid: vec![true; n],
        }
    }

    /// A walk of ±3° per joint (eq. (16)'s step), `mult` times as long every `every`-th step.
    fn walk(n: usize, mult: f64, every: usize) -> Vec<[f64; 2]> {
        let mut q = [0.0, 0.0];
        let mut out = vec![q];
        for i in 1..n {
            let s = if every > 0 && i % every == 0 { mult } else { 1.0 };
            let sign = |k: usize| if (i * (k + 3) / 7).is_multiple_of(2) { 1.0 } else { -1.0 };
            q = [q[0] + 3.0 * s * sign(0), q[1] + 3.0 * s * sign(1)];
            out.push(q);
        }
        out
    }

    #[test]
    fn single_step_data_are_decimated_and_data_with_larger_steps_are_not() {
        let rows: Vec<usize> = (0..400).collect();
        let one = auto_decimation(&dataset(&walk(400, 1.0, 0)), &rows).unwrap();
        assert_eq!(one.decimation, AUTO_DECIMATION, "{one}");
        assert!((one.grid_deg - 18f64.sqrt()).abs() < 1e-12);
        assert_eq!(one.larger_fraction, 0.0);
        // Shorter steps (clipped at a limit) keep the data single-step.
        let mut clipped = walk(400, 1.0, 0);
        for q in clipped.iter_mut().skip(100).take(3) {
            q[0] = 0.0;
        }
        assert_eq!(
            auto_decimation(&dataset(&clipped), &rows).unwrap().decimation,
            AUTO_DECIMATION
        );
        // One step in four twice as long (mixed excitation's multipliers): consecutive samples.
        let mixed = auto_decimation(&dataset(&walk(400, 2.0, 4)), &rows).unwrap();
        assert_eq!(mixed.decimation, 1, "{mixed}");
        assert!((mixed.larger_fraction - 0.25).abs() < 0.01, "{mixed}");
        // A few larger steps (under 1 %) do not make a dataset multi-step; 2 % do.
        assert_eq!(
            auto_decimation(&dataset(&walk(400, 2.0, 200)), &rows)
                .unwrap()
                .decimation,
            AUTO_DECIMATION
        );
        assert_eq!(
            auto_decimation(&dataset(&walk(400, 2.0, 50)), &rows)
                .unwrap()
                .decimation,
            1
        );
        // Only the given rows count, and only consecutive ones.
        let first: Vec<usize> = (0..3).collect();
        assert_eq!(
            auto_decimation(&dataset(&walk(400, 2.0, 4)), &first)
                .unwrap()
                .decimation,
            AUTO_DECIMATION
        );
        assert!(auto_decimation(&dataset(&walk(400, 2.0, 4)), &[0, 2, 4]).is_none());
    }

    #[test]
    fn the_rule_reads_auto_or_a_whole_number() {
        assert_eq!("auto".parse::<DecimationRule>().unwrap(), DecimationRule::Auto);
        assert_eq!(" AUTO ".parse::<DecimationRule>().unwrap(), DecimationRule::Auto);
        assert_eq!("4".parse::<DecimationRule>().unwrap(), DecimationRule::Fixed(4));
        for bad in ["0", "-1", "four", ""] {
            let e = bad.parse::<DecimationRule>().unwrap_err();
            assert!(e.contains("auto"), "{bad}: {e}");
        }
        #[derive(serde::Deserialize)]
        struct T {
            d: DecimationRule,
        }
        let t: T = toml::from_str("d = 4").unwrap();
        assert_eq!(t.d, DecimationRule::Fixed(4));
        let t: T = toml::from_str("d = \"auto\"").unwrap();
        assert_eq!(t.d, DecimationRule::Auto);
        for bad in ["d = 0", "d = -3", "d = \"x\"", "d = 1.5"] {
            assert!(toml::from_str::<T>(bad).is_err(), "{bad}");
        }
        assert_eq!(DecimationRule::Auto.to_string(), "auto");
        assert_eq!(DecimationRule::Fixed(2).to_string(), "2");
    }

    #[test]
    fn the_grid_is_the_modal_step_and_the_median_without_one() {
        let rows: Vec<usize> = (0..400).collect();
        let g = command_spacing_deg(&dataset(&walk(400, 2.0, 4)), &rows).unwrap();
        assert!((g - 18f64.sqrt()).abs() < 1e-12, "{g}");
        // Every step different: no bin holds 5 %, so the median.
        let spread: Vec<[f64; 2]> = (0..41).map(|i| [(i * (i + 1) / 2) as f64 * 0.1, 0.0]).collect();
        let g = command_spacing_deg(&dataset(&spread), &(0..41).collect::<Vec<_>>()).unwrap();
        assert!((g - 2.05).abs() < 1e-9, "{g}");
    }
}
