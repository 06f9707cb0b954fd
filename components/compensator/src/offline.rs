//! Offline compensation of a target file (`bowden compensate`): CSV in, CSV out.

use crate::compensator::{Compensator, StepOutput};
use std::io::Write;
use std::path::Path;

/// A bad target file: which file, line and column.
#[derive(Debug, thiserror::Error)]
pub enum TargetsError {
    #[error("{path}: cannot read: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: empty file (expected a header with columns q1..q{joints})")]
    Empty { path: String, joints: usize },
    #[error("{path}: header has no column `{column}` (expected q1..q{joints}, found: {header})")]
    MissingColumn {
        path: String,
        column: String,
        joints: usize,
        header: String,
    },
    #[error("{path}:{line}: column `{column}` = {value:?} is not a finite number")]
    BadValue {
        path: String,
        line: usize,
        column: String,
        value: String,
    },
    #[error("{path}:{line}: {found} fields, the header has {expected}")]
    FieldCount {
        path: String,
        line: usize,
        found: usize,
        expected: usize,
    },
    #[error("{path}: no targets after the header")]
    NoRows { path: String },
}

/// Reads targets from a CSV file with a header naming columns `q1..qJ` (degrees; other
/// columns are ignored; `#` lines and blank lines are skipped).
pub fn read_targets_csv(path: &Path, joints: usize) -> Result<Vec<Vec<f64>>, TargetsError> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| TargetsError::Io {
        path: name.clone(),
        source,
    })?;
    parse_targets_csv(&text, &name, joints)
}

pub fn parse_targets_csv(text: &str, name: &str, joints: usize) -> Result<Vec<Vec<f64>>, TargetsError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (_, header) = lines.next().ok_or_else(|| TargetsError::Empty {
        path: name.to_string(),
        joints,
    })?;
    let cols: Vec<String> = header.split(',').map(|c| c.trim().to_lowercase()).collect();
    let mut idx = Vec::with_capacity(joints);
    for c in 1..=joints {
        let want = format!("q{c}");
        let i = cols
            .iter()
            .position(|h| *h == want)
            .ok_or_else(|| TargetsError::MissingColumn {
                path: name.to_string(),
                column: want.clone(),
                joints,
                header: header.to_string(),
            })?;
        idx.push(i);
    }
    let mut rows = Vec::new();
    for (line, l) in lines {
        let fields: Vec<&str> = l.split(',').map(|f| f.trim()).collect();
        if fields.len() != cols.len() {
            return Err(TargetsError::FieldCount {
                path: name.to_string(),
                line,
                found: fields.len(),
                expected: cols.len(),
            });
        }
        let mut row = Vec::with_capacity(joints);
        for (c, &i) in idx.iter().enumerate() {
            match fields[i].parse::<f64>() {
                Ok(v) if v.is_finite() => row.push(v),
                _ => {
                    return Err(TargetsError::BadValue {
                        path: name.to_string(),
                        line,
                        column: format!("q{}", c + 1),
                        value: fields[i].to_string(),
                    })
                }
            }
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(TargetsError::NoRows { path: name.to_string() });
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
        f.push(o.stop_reason.name().to_string());
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
        let name = o.stop_reason.name();
        match reasons.iter_mut().find(|(r, _)| r == name) {
            Some((_, c)) => *c += 1,
            None => reasons.push((name.to_string(), 1)),
        }
    }
    OfflineSummary {
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

    #[test]
    fn csv_errors_name_line_and_column() {
        let ok = "t_ns,q1,q2\n# comment\n0,1.5,2\n\n1,3,-4e1\n";
        assert_eq!(
            parse_targets_csv(ok, "a.csv", 2).unwrap(),
            vec![vec![1.5, 2.0], vec![3.0, -40.0]]
        );
        let e = parse_targets_csv("q1,q3\n1,2\n", "b.csv", 2).unwrap_err().to_string();
        assert!(e.contains("b.csv") && e.contains("`q2`"), "{e}");
        let e = parse_targets_csv("q1,q2\n1,2\n1,NaN\n", "c.csv", 2)
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.csv:3") && e.contains("q2") && e.contains("NaN"), "{e}");
        let e = parse_targets_csv("q1,q2\n1\n", "d.csv", 2).unwrap_err().to_string();
        assert!(e.contains("d.csv:2") && e.contains("1 fields"), "{e}");
        assert!(matches!(
            parse_targets_csv("", "e.csv", 2),
            Err(TargetsError::Empty { .. })
        ));
        assert!(matches!(
            parse_targets_csv("q1,q2\n", "f.csv", 2),
            Err(TargetsError::NoRows { .. })
        ));
    }
}
