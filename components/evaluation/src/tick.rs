//! Running a pipeline at a tick shorter than its own (`bowden evaluate --tick-ms`): the tick
//! must divide the pipeline's, and every per-tick quantity keeps its meaning by scaling with
//! the ratio (the hold in ticks, the compensator's and the actuator's rate limits in deg/s), so
//! the feed-forward runs as it does at the pipeline's tick while a faster camera fits in the
//! hold. These helpers write the scaled copies of the pipeline's files.

use crate::EvalError;
use std::path::{Path, PathBuf};

/// The actuator's rate limit when a pipeline sets none, deg/s (components/actuator's default).
const ACTUATOR_DEFAULT_RATE_DEG_S: f64 = 400.0;

fn config_error(path: &Path, message: impl std::fmt::Display) -> EvalError {
    EvalError::Config {
        path: path.to_path_buf(),
        message: message.to_string().replace('\n', " "),
    }
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> EvalError + '_ {
    move |source| EvalError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn read_table(path: &Path) -> Result<toml::Table, EvalError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    toml::from_str(&text).map_err(|e| config_error(path, e))
}

fn write_table(path: &Path, t: &toml::Table) -> Result<(), EvalError> {
    let text = toml::to_string(t).map_err(|e| config_error(path, e))?;
    std::fs::write(path, text).map_err(io_error(path))
}

/// Why a shorter tick cannot be used.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TickError {
    #[error("{tick_ms} ms: must be between 0.1 ms and the pipeline's tick ({base_ms} ms)")]
    OutOfRange { tick_ms: f64, base_ms: f64 },
    #[error(
        "{tick_ms} ms: must divide the pipeline's tick of {base_ms} ms (the hold and the per-tick rate \
         limits are kept by scaling with the ratio)"
    )]
    NotADivisor { tick_ms: f64, base_ms: f64 },
}

/// The pipeline's tick `base_tick_ns` divided into `tick_ms`: returns the tick (ns) and the
/// integer ratio.
pub fn shorter_tick(tick_ms: f64, base_tick_ns: u64) -> Result<(u64, u64), TickError> {
    let base_ms = base_tick_ns as f64 / 1e6;
    let tick_ns = (tick_ms * 1e6).round();
    if !(tick_ms.is_finite() && tick_ns >= 1e5 && tick_ns <= base_tick_ns as f64) {
        return Err(TickError::OutOfRange { tick_ms, base_ms });
    }
    let tick_ns = tick_ns as u64;
    if !base_tick_ns.is_multiple_of(tick_ns) {
        return Err(TickError::NotADivisor { tick_ms, base_ms });
    }
    Ok((tick_ns, base_tick_ns / tick_ns))
}

/// A copy of controller config `src` in `dir` for a tick `scale` times shorter: its rate limit
/// (deg/s) times `scale`, so the limit per tick is unchanged, and its model paths absolute.
/// `default_rate_deg_s` is the compensator's rate limit when `src` sets none. A relative model
/// path not found beside `src` is looked up with `find_model` (bowden's resolution order: the
/// working directory, `$BOWDEN_HOME`, the built-in copy).
pub fn controller_for_tick(
    src: &Path,
    dir: &Path,
    scale: u64,
    default_rate_deg_s: f64,
    find_model: &dyn Fn(&Path) -> Result<PathBuf, String>,
) -> Result<PathBuf, EvalError> {
    let mut t = read_table(src)?;
    let base = src.parent().unwrap_or(Path::new("."));
    for key in ["model_fwd", "model_inv", "model_judge"] {
        if let Some(toml::Value::String(m)) = t.get_mut(key) {
            let given = PathBuf::from(m.as_str());
            if given.is_relative() {
                let path = if base.join(&given).exists() {
                    base.join(&given)
                } else {
                    find_model(&given).map_err(|e| config_error(src, format!("{key}: {e}")))?
                };
                *m = std::path::absolute(&path)
                    .map_err(io_error(&path))?
                    .display()
                    .to_string();
            }
        }
    }
    let output = t
        .entry("output")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        .as_table_mut()
        .ok_or_else(|| config_error(src, "[output] is not a table"))?;
    let rate = match output.get("rate_limit_deg_s") {
        Some(v) => v
            .as_float()
            .or_else(|| v.as_integer().map(|i| i as f64))
            .ok_or_else(|| config_error(src, "output.rate_limit_deg_s is not a number"))?,
        None => default_rate_deg_s,
    };
    output.insert("rate_limit_deg_s".into(), toml::Value::Float(rate * scale as f64));
    std::fs::create_dir_all(dir).map_err(io_error(dir))?;
    let out = dir.join(format!(
        "tick-{}",
        src.file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_default()
    ));
    write_table(&out, &t)?;
    Ok(out)
}

/// `params.KEY` of the node named `node` in pipeline file `template` (None if absent).
pub fn node_param(template: &Path, node: &str, key: &str) -> Result<Option<toml::Value>, EvalError> {
    let t = read_table(template)?;
    Ok(t.get("node")
        .and_then(|n| n.as_array())
        .and_then(|nodes| {
            nodes
                .iter()
                .find(|n| n.get("name").and_then(|x| x.as_str()) == Some(node))
        })
        .and_then(|n| n.get("params"))
        .and_then(|p| p.get(key))
        .cloned())
}

/// The controller config file of pipeline `template`'s compensator node (relative to the
/// pipeline file, as the node resolves it).
pub fn pipeline_controller(template: &Path) -> Result<PathBuf, EvalError> {
    let file = node_param(template, "compensator", "config")?
        .and_then(|c| c.as_str().map(PathBuf::from))
        .ok_or_else(|| config_error(template, "no compensator node with a config"))?;
    Ok(if file.is_relative() {
        template.parent().unwrap_or(Path::new(".")).join(file)
    } else {
        file
    })
}

/// Sets `[runtime] period_us` of pipeline file `file` to `tick_ns`.
pub fn set_period(file: &Path, tick_ns: u64) -> Result<(), EvalError> {
    let mut t = read_table(file)?;
    t.entry("runtime")
        .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        .as_table_mut()
        .ok_or_else(|| config_error(file, "[runtime] is not a table"))?
        .insert("period_us".into(), toml::Value::Integer((tick_ns / 1000) as i64));
    write_table(file, &t)
}

/// The pipeline `template`'s actuator rate limit (deg/s, one or per joint) times `scale`.
pub fn actuator_rate_for_tick(template: &Path, scale: u64) -> Result<toml::Value, EvalError> {
    let rate =
        node_param(template, "actuator", "max_rate_deg_s")?.unwrap_or(toml::Value::Float(ACTUATOR_DEFAULT_RATE_DEG_S));
    let k = scale as f64;
    let num = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    Ok(match rate {
        toml::Value::Array(a) => toml::Value::Array(
            a.iter()
                .map(|v| num(v).map(|r| toml::Value::Float(r * k)))
                .collect::<Option<Vec<_>>>()
                .ok_or_else(|| config_error(template, "actuator max_rate_deg_s: not numbers"))?,
        ),
        v => toml::Value::Float(
            num(&v).ok_or_else(|| config_error(template, "actuator max_rate_deg_s: not a number"))? * k,
        ),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shorter_tick_must_divide_the_pipelines() {
        assert_eq!(shorter_tick(10.0, 100_000_000), Ok((10_000_000, 10)));
        assert_eq!(
            shorter_tick(30.0, 100_000_000),
            Err(TickError::NotADivisor {
                tick_ms: 30.0,
                base_ms: 100.0
            })
        );
        assert!(matches!(
            shorter_tick(0.05, 100_000_000),
            Err(TickError::OutOfRange { .. })
        ));
        assert!(matches!(
            shorter_tick(200.0, 100_000_000),
            Err(TickError::OutOfRange { .. })
        ));
        assert!(matches!(
            shorter_tick(f64::NAN, 100_000_000),
            Err(TickError::OutOfRange { .. })
        ));
    }
}
