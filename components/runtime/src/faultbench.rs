//! `bowden bench faults`: robot-side faults injected into the default simulated pipeline
//! (configs/sim.toml) in real time, each run measured from the run's own fault records: when
//! the fault was detected, how long the reaction took, and the exit code the run would have.
//!
//! Cases: the plant process publishing NaN or ±900° joint angles or going silent (its own fault
//! injection, `[node.params] fault`), hanging (SIGSTOP) and dying for good (SIGKILL, no
//! restart). The injection time of the plant's own faults is on the plant's clock, which starts
//! with the run's common start within about a millisecond; the signals are sent by this bench
//! on the launcher's clock.

use crate::config::{PipelineConfig, SIM_DEFAULT_TOML};
use crate::launch::LaunchOptions;
use crate::node::Registry;
use crate::session::{FaultRecord, RealtimeSession, RunReport, SessionError, SessionOptions};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// One kind of fault (`bowden bench faults --cases`: the kebab-case spellings).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, strum::EnumString, strum::IntoStaticStr, strum::Display, strum::VariantNames,
)]
#[strum(serialize_all = "kebab-case")]
pub enum FaultCase {
    Nan,
    OutOfRange,
    Silent,
    #[strum(serialize = "hung")]
    HungDriver,
    #[strum(serialize = "lost")]
    LostDriver,
}

impl FaultCase {
    pub const ALL: [FaultCase; 5] = [
        FaultCase::Nan,
        FaultCase::OutOfRange,
        FaultCase::Silent,
        FaultCase::HungDriver,
        FaultCase::LostDriver,
    ];

    /// The spelling on the command line and in reports.
    pub fn as_str(self) -> &'static str {
        self.into()
    }

    pub fn describe(self) -> &'static str {
        match self {
            FaultCase::Nan => "plant publishes NaN joint angles",
            FaultCase::OutOfRange => "plant publishes ±900°",
            FaultCase::Silent => "plant stops publishing, alive",
            FaultCase::HungDriver => "plant process hangs (SIGSTOP)",
            FaultCase::LostDriver => "plant process killed (SIGKILL), no restart",
        }
    }
}

/// What one run showed.
#[derive(Debug, Clone, Serialize)]
pub struct FaultRun {
    /// From the injection to the first fault record of the case's detector, ms.
    pub detection_ms: Option<f64>,
    /// From detection to the safe state (the launcher's e-stop confirmed by the actuator), ms;
    /// `None` where the actuator holds in the detecting step itself.
    pub reaction_ms: Option<f64>,
    pub detected_by: Option<String>,
    pub exit_code: u8,
}

/// All runs of one case.
#[derive(Debug, Clone, Serialize)]
pub struct FaultRow {
    pub case: &'static str,
    pub what: &'static str,
    pub runs: Vec<FaultRun>,
}

/// Settings of the bench.
#[derive(Debug, Clone)]
pub struct FaultBenchOptions {
    pub cases: Vec<FaultCase>,
    pub runs: usize,
    /// Run time before the fault, s.
    pub fault_at_s: f64,
    /// Run time after it, s.
    pub after_s: f64,
    pub launch: LaunchOptions,
    pub kinds: Registry,
    /// Where the pipeline variants are written.
    pub work_dir: PathBuf,
}

#[derive(Debug, thiserror::Error)]
pub enum FaultBenchError {
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error("{path}: {message}")]
    Config { path: String, message: String },
}

fn variant(case: FaultCase, prefix: &str, fault_at_s: f64, dir: &Path) -> Result<PathBuf, FaultBenchError> {
    let path = dir.join(format!("{prefix}sim.toml"));
    let bad = |message: String| FaultBenchError::Config {
        path: path.display().to_string(),
        message,
    };
    let mut t: toml::Table = toml::from_str(SIM_DEFAULT_TOML).map_err(|e| bad(e.to_string()))?;
    if let Some(rt) = t.get_mut("runtime").and_then(|v| v.as_table_mut()) {
        rt.insert("prefix".into(), toml::Value::String(prefix.into()));
    }
    let nodes = t
        .get_mut("node")
        .and_then(|v| v.as_array_mut())
        .ok_or_else(|| bad("no [[node]]".into()))?;
    let plant = nodes
        .iter_mut()
        .filter_map(|n| n.as_table_mut())
        .find(|n| n.get("name").and_then(|v| v.as_str()) == Some("plant"))
        .ok_or_else(|| bad("no plant node".into()))?;
    // A driver lost for good: no restart (the default config restarts it).
    plant.insert("restart".into(), toml::Value::String("never".into()));
    let kind = match case {
        FaultCase::Nan => Some("nan"),
        FaultCase::OutOfRange => Some("out-of-range"),
        FaultCase::Silent => Some("silent"),
        _ => None,
    };
    if let Some(kind) = kind {
        let params = plant
            .entry("params")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| bad("plant params is not a table".into()))?;
        let mut f = toml::Table::new();
        f.insert("kind".into(), toml::Value::String(kind.into()));
        f.insert("after_s".into(), toml::Value::Float(fault_at_s));
        params.insert("fault".into(), toml::Value::Table(f));
    }
    let text = toml::to_string(&t).map_err(|e| bad(e.to_string()))?;
    std::fs::write(&path, text).map_err(|e| bad(e.to_string()))?;
    Ok(path)
}

fn first(r: &RunReport, f: impl Fn(&FaultRecord) -> bool) -> Option<&FaultRecord> {
    r.faults.iter().find(|x| f(x))
}

fn measure(case: FaultCase, r: &RunReport, t_inj_s: f64) -> FaultRun {
    let hold = first(r, |f| f.source == "actuator" && f.what.starts_with("safe hold"));
    let (det, by) = match case {
        FaultCase::LostDriver => (first(r, |f| f.source == "process plant"), "launcher (process exit)"),
        _ => (hold, "actuator (robot-state monitor)"),
    };
    let reaction_ms = match case {
        FaultCase::LostDriver => first(r, |f| f.source == "launcher" && f.what.starts_with("e-stop confirmed"))
            .zip(det)
            .map(|(c, d)| (c.t_s - d.t_s) * 1e3),
        _ => None,
    };
    FaultRun {
        detection_ms: det.map(|d| (d.t_s - t_inj_s) * 1e3),
        reaction_ms,
        detected_by: det.map(|_| by.to_string()),
        exit_code: r.outcome.exit_code(),
    }
}

fn signal_process(s: &RealtimeSession, process: &str, sig: i32) {
    if let Some((_, pid)) = s.pids().into_iter().find(|(n, _)| n == process) {
        // SAFETY: a signal to a child process of this session.
        unsafe { libc::kill(pid as libc::pid_t, sig) };
    }
}

/// Runs every case `opts.runs` times; `progress` hears each run's line.
pub fn run(opts: &FaultBenchOptions, mut progress: impl FnMut(&str)) -> Result<Vec<FaultRow>, FaultBenchError> {
    std::fs::create_dir_all(&opts.work_dir).map_err(|e| FaultBenchError::Config {
        path: opts.work_dir.display().to_string(),
        message: e.to_string(),
    })?;
    let mut rows = Vec::new();
    for &case in &opts.cases {
        let mut runs = Vec::new();
        for k in 0..opts.runs {
            let prefix = format!("bf{}_{}{k}_", std::process::id(), case.as_str().replace('-', ""));
            let path = variant(case, &prefix, opts.fault_at_s, &opts.work_dir)?;
            let cfg =
                PipelineConfig::load(&path, &Default::default(), opts.kinds).map_err(|e| FaultBenchError::Config {
                    path: path.display().to_string(),
                    message: e.to_string(),
                })?;
            let mut so = SessionOptions::new(opts.launch.clone());
            so.launch.quiet_children = true;
            let mut s = RealtimeSession::start(&cfg, so)?;
            let before = Duration::from_secs_f64(opts.fault_at_s);
            let after = Duration::from_secs_f64(opts.after_s);
            let t_inj = match case {
                FaultCase::HungDriver | FaultCase::LostDriver => {
                    s.run_for(Some(before))?;
                    let t = s.run_time_s();
                    let sig = if case == FaultCase::HungDriver {
                        libc::SIGSTOP
                    } else {
                        libc::SIGKILL
                    };
                    signal_process(&s, "plant", sig);
                    s.run_for(Some(after))?;
                    if case == FaultCase::HungDriver {
                        signal_process(&s, "plant", libc::SIGCONT);
                    }
                    t
                }
                _ => {
                    s.run_for(Some(before + after))?;
                    opts.fault_at_s
                }
            };
            let report = s.shutdown()?;
            let _ = std::fs::remove_file(&path);
            let m = measure(case, &report, t_inj);
            progress(&format!(
                "{} run {}: detection {} ms, exit code {}",
                case.as_str(),
                k + 1,
                m.detection_ms.map_or("-".into(), |d| format!("{d:.2}")),
                m.exit_code
            ));
            runs.push(m);
        }
        rows.push(FaultRow {
            case: case.as_str(),
            what: case.describe(),
            runs,
        });
    }
    Ok(rows)
}

/// The table: per case, detection p50 / max, reaction, exit codes.
pub fn to_markdown(rows: &[FaultRow]) -> String {
    use std::fmt::Write;
    let mut s = String::from(
        "| fault | detected by | detection p50 (ms) | detection max (ms) | reaction | exit codes |\n|---|---|---:|---:|---|---|\n",
    );
    for r in rows {
        let mut d: Vec<f64> = r.runs.iter().filter_map(|x| x.detection_ms).collect();
        d.sort_by(f64::total_cmp);
        let missed = r.runs.len() - d.len();
        let p50 = d.get(d.len() / 2).map_or("-".into(), |v| format!("{v:.2}"));
        let max = d.last().map_or("-".into(), |v| format!("{v:.2}"));
        let by = r
            .runs
            .iter()
            .find_map(|x| x.detected_by.clone())
            .unwrap_or_else(|| "not detected".into());
        let mut reactions: Vec<f64> = r.runs.iter().filter_map(|x| x.reaction_ms).collect();
        reactions.sort_by(f64::total_cmp);
        let reaction = match reactions.last() {
            Some(m) => format!("e-stop confirmed ≤ {m:.1} ms"),
            None => "hold in the detecting step".into(),
        };
        let codes: Vec<String> = r.runs.iter().map(|x| x.exit_code.to_string()).collect();
        let _ = writeln!(
            s,
            "| {} | {}{} | {p50} | {max} | {reaction} | {} |",
            r.what,
            by,
            if missed > 0 {
                format!(" ({missed} of {} not detected)", r.runs.len())
            } else {
                String::new()
            },
            codes.join(" ")
        );
    }
    s
}
