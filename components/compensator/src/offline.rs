//! Offline compensation of a target file (`bowden compensate`): CSV in, CSV out.

use crate::compensator::{Compensator, StepOutput};
use bowden_tables::{ReadOptions, Table, TableError};
use std::io::Write;
use std::path::Path;

/// A bad target file: which file, line and column.
#[derive(Debug, thiserror::Error)]
pub enum TargetsError {
    /// Unreadable or malformed CSV, a missing column, a field that is not a finite number.
    #[error(transparent)]
    Table(#[from] TableError),
    #[error("{path}: no targets after the header")]
    NoRows { path: String },
}

/// The joint columns a target file has by default: `q1..qJ`.
pub fn default_columns(joints: usize) -> Vec<String> {
    (1..=joints).map(|k| format!("q{k}")).collect()
}

/// Reads targets from a CSV file with a header naming the joint columns `q1..qJ` (degrees,
/// any case; other columns are ignored; `#` lines and blank lines are skipped).
pub fn read_targets_csv(path: &Path, joints: usize) -> Result<Vec<Vec<f64>>, TargetsError> {
    let bytes = std::fs::read(path).map_err(|source| TableError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_targets_csv(&bytes, path, &default_columns(joints), true)
}

/// Targets from CSV bytes: the columns `names` in joint order (compared ignoring case when
/// `ignore_case`), every value finite. `path` names the bytes in errors.
pub fn parse_targets_csv(
    bytes: &[u8],
    path: &Path,
    names: &[String],
    ignore_case: bool,
) -> Result<Vec<Vec<f64>>, TargetsError> {
    let opts = ReadOptions {
        header: true,
        comments: true,
        ignore_case,
    };
    let table = Table::parse(bytes, path, opts)?;
    let cols = table.columns(names)?;
    let rows = table.finite_rows(&cols)?;
    if rows.is_empty() {
        return Err(TargetsError::NoRows {
            path: path.display().to_string(),
        });
    }
    Ok(rows)
}

/// Runs the compensator over the targets in order (one step each).
pub fn run(comp: &mut Compensator, targets: &[Vec<f64>], mut progress: impl FnMut(usize)) -> Vec<StepOutput> {
    let mut outs = Vec::with_capacity(targets.len());
    let mut out = StepOutput::default();
    for (i, t) in targets.iter().enumerate() {
        // Targets were validated when read; a rejection would still be recorded as such.
        let _ = comp.step(t, &mut out);
        outs.push(out);
        progress(i + 1);
    }
    outs
}

/// Writes one row per step: desired, command, prediction, loss, iterations, evaluations,
/// stop reason and step time.
pub fn write_csv(w: &mut impl Write, outs: &[StepOutput]) -> std::io::Result<()> {
    let j = outs.first().map(|o| o.joints).unwrap_or(0);
    let mut h = vec!["step".to_string()];
    for p in ["q_des", "q_cmd", "q_pred"] {
        h.extend((1..=j).map(|c| format!("{p}_{c}")));
    }
    h.extend(
        [
            "loss_max_abs_deg",
            "iterations",
            "forward_evals",
            "stop_reason",
            "elapsed_ns",
        ]
        .iter()
        .map(|s| s.to_string()),
    );
    writeln!(w, "{}", h.join(","))?;
    for (i, o) in outs.iter().enumerate() {
        let mut f = vec![i.to_string()];
        for a in [&o.q_desired_deg, &o.q_cmd_deg, &o.q_predicted_deg] {
            f.extend(a[..j].iter().map(|v| format!("{v:.6}")));
        }
        f.push(if o.loss_max_abs_deg.is_nan() {
            String::new()
        } else {
            format!("{:.6}", o.loss_max_abs_deg)
        });
        f.push(o.iterations.to_string());
        f.push(o.forward_evals.to_string());
        f.push(o.stop_reason.as_str().to_string());
        f.push(o.elapsed_ns.to_string());
        writeln!(w, "{}", f.join(","))?;
    }
    Ok(())
}

/// Aggregate figures of an offline run.
#[derive(Debug, Clone, serde::Serialize)]
pub struct OfflineSummary {
    pub steps: usize,
    pub mean_loss_deg: f64,
    pub max_loss_deg: f64,
    pub mean_iterations: f64,
    pub mean_forward_evals: f64,
    pub stop_reasons: Vec<(String, usize)>,
    /// Rows whose command the robot's joint limits or jaw rule changed (never silent: the
    /// command line says how many, and loudly above [`LOUD_CLAMP_FRACTION`]).
    pub joint_limited_rows: usize,
    /// Per joint, rows whose command the limits lowered (it wanted more than the upper limit).
    pub lowered_rows_per_joint: Vec<usize>,
    /// Per joint, rows whose command the limits raised.
    pub raised_rows_per_joint: Vec<usize>,
    /// Rows whose command the output rate limit changed.
    pub rate_limited_rows: usize,
}

/// A command file clamped on more than this fraction of its rows is not this robot's, or the
/// robot file's limits are not: `bowden compensate` says so as a warning, not only a count.
pub const LOUD_CLAMP_FRACTION: f64 = 0.01;

impl OfflineSummary {
    /// Fraction of the rows the joint limits changed (0 without rows).
    pub fn joint_limited_fraction(&self) -> f64 {
        if self.steps == 0 {
            0.0
        } else {
            self.joint_limited_rows as f64 / self.steps as f64
        }
    }

    /// "q4 lowered 12, q5 raised 3" for the joints the limits changed (with their names).
    pub fn clamps_by_joint(&self, joint_names: &[&str]) -> String {
        let mut parts = Vec::new();
        for (k, name) in joint_names.iter().enumerate() {
            let lowered = self.lowered_rows_per_joint.get(k).copied().unwrap_or(0);
            let raised = self.raised_rows_per_joint.get(k).copied().unwrap_or(0);
            if lowered > 0 {
                parts.push(format!("{name} lowered {lowered}"));
            }
            if raised > 0 {
                parts.push(format!("{name} raised {raised}"));
            }
        }
        parts.join(", ")
    }
}

pub fn summarize(outs: &[StepOutput]) -> OfflineSummary {
    let n = outs.len().max(1) as f64;
    let losses: Vec<f64> = outs
        .iter()
        .map(|o| o.loss_max_abs_deg)
        .filter(|v| v.is_finite())
        .collect();
    let mut reasons: Vec<(String, usize)> = Vec::new();
    for o in outs {
        let name = o.stop_reason.as_str();
        match reasons.iter_mut().find(|(r, _)| r == name) {
            Some((_, c)) => *c += 1,
            None => reasons.push((name.to_string(), 1)),
        }
    }
    let joints = outs.first().map_or(0, |o| o.joints);
    let per_joint = |mask: fn(&StepOutput) -> u32| -> Vec<usize> {
        (0..joints)
            .map(|k| outs.iter().filter(|o| mask(o) & (1 << k) != 0).count())
            .collect()
    };
    OfflineSummary {
        joint_limited_rows: outs.iter().filter(|o| o.joint_limited).count(),
        lowered_rows_per_joint: per_joint(|o| o.joint_limit_lowered_mask),
        raised_rows_per_joint: per_joint(|o| o.joint_limit_raised_mask),
        rate_limited_rows: outs.iter().filter(|o| o.rate_limited).count(),
        steps: outs.len(),
        mean_loss_deg: if losses.is_empty() {
            f64::NAN
        } else {
            losses.iter().sum::<f64>() / losses.len() as f64
        },
        max_loss_deg: losses.iter().copied().fold(f64::NAN, f64::max),
        mean_iterations: outs.iter().map(|o| o.iterations as f64).sum::<f64>() / n,
        mean_forward_evals: outs.iter().map(|o| o.forward_evals as f64).sum::<f64>() / n,
        stop_reasons: reasons,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str, name: &str) -> Result<Vec<Vec<f64>>, TargetsError> {
        parse_targets_csv(text.as_bytes(), Path::new(name), &default_columns(2), true)
    }

    #[test]
    fn csv_errors_name_line_and_column() {
        let ok = "t_ns,Q1,q2\n# comment\n0,1.5,2\n\n1,3,-4e1\n";
        assert_eq!(parse(ok, "a.csv").unwrap(), vec![vec![1.5, 2.0], vec![3.0, -40.0]]);
        let e = parse("q1,q3\n1,2\n", "b.csv").unwrap_err().to_string();
        assert!(e.contains("b.csv") && e.contains("\"q2\""), "{e}");
        let e = parse("q1,q2\n1,2\n1,NaN\n", "c.csv").unwrap_err().to_string();
        assert!(e.contains("c.csv:3:2 (q2)") && e.contains("NaN"), "{e}");
        let e = parse("q1,q2\n1\n", "d.csv").unwrap_err().to_string();
        assert!(e.contains("d.csv:2") && e.contains("1 fields"), "{e}");
        assert!(matches!(
            parse("", "e.csv"),
            Err(TargetsError::Table(TableError::Empty { .. }))
        ));
        assert!(matches!(parse("q1,q2\n", "f.csv"), Err(TargetsError::NoRows { .. })));
        // A quoted field with a comma in another column, CRLF and a byte-order mark.
        let rig = "\u{feff}note,q1,q2\r\n\"left, then up\",1,2\r\n";
        assert_eq!(parse(rig, "g.csv").unwrap(), vec![vec![1.0, 2.0]]);
    }
}
