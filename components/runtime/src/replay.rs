//! `bowden replay`: feed a recorded log back onto its services (at the recorded pace or as fast
//! as possible), and summarise a log.

use crate::ports::{visit_payload, FrameOutput, Message, Output, PayloadVisitor, PortContext, PortError, Wakeup};
use crate::record::{LogError, LogReader, KIND_FRAME};
use crate::sys::{self, monotonic_ns};
use bowden_interfaces::{services, JointEstimate, MotorCommand, PlantState, RgbdFrameHeader, MAX_JOINTS};
use serde::Serialize;
use std::path::Path;

/// Why a replay failed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(transparent)]
    Log(#[from] LogError),
    #[error(transparent)]
    Port(#[from] PortError),
    #[error("{path}: record {index} of `{service}` has the wrong size for its type")]
    BadRecord {
        path: String,
        index: usize,
        service: String,
    },
}

/// How fast to replay.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// Republish with the recorded spacing of `t_origin_ns`, scaled by `speed` (2.0 = twice as fast).
    Recorded { speed: f64 },
    /// As fast as possible.
    Fast,
}

/// What a replay did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ReplayStats {
    pub published: u64,
    pub skipped_services: u64,
    pub seconds: f64,
    pub interrupted: bool,
}

trait Sink {
    fn send(&mut self, payload: &[u8]) -> Result<bool, PortError>;
}

struct SampleSink<T: Message> {
    out: Output<T>,
    wake: Wakeup,
}

impl<T: Message> Sink for SampleSink<T> {
    fn send(&mut self, payload: &[u8]) -> Result<bool, PortError> {
        let Some(v) = T::from_bytes(payload) else {
            return Ok(false);
        };
        self.out.publish_raw(v)?;
        self.wake.notify()?;
        Ok(true)
    }
}

struct FrameSink {
    out: FrameOutput,
    wake: Wakeup,
}

impl Sink for FrameSink {
    fn send(&mut self, payload: &[u8]) -> Result<bool, PortError> {
        let hl = core::mem::size_of::<RgbdFrameHeader>();
        if payload.len() < hl {
            return Ok(false);
        }
        let Some(h) = RgbdFrameHeader::from_bytes(&payload[..hl]) else {
            return Ok(false);
        };
        self.out.publish_raw(&h, &payload[hl..])?;
        self.wake.notify()?;
        Ok(true)
    }
}

fn sink_for(ports: &PortContext, service: &str, max_frame: usize) -> Result<Option<Box<dyn Sink>>, PortError> {
    struct MakeSink<'a> {
        ports: &'a PortContext,
        service: &'a str,
        max_frame: usize,
    }
    impl PayloadVisitor for MakeSink<'_> {
        type Output = Result<Box<dyn Sink>, PortError>;
        fn sample<T: Message>(self) -> Self::Output {
            Ok(Box::new(SampleSink::<T> {
                out: self.ports.output::<T>(self.service)?,
                wake: self.ports.notifier(self.service)?,
            }))
        }
        fn frame(self) -> Self::Output {
            Ok(Box::new(FrameSink {
                out: self.ports.frame_output(self.service, self.max_frame.max(1))?,
                wake: self.ports.notifier(self.service)?,
            }))
        }
    }
    visit_payload(
        service,
        MakeSink {
            ports,
            service,
            max_frame,
        },
    )
    .transpose()
}

/// Republishes the records of `log` (only `only` services if given) under `ports`' prefix and
/// namespace. Stops early on SIGINT/SIGTERM.
pub fn replay(
    log: &Path,
    ports: &PortContext,
    pace: Pace,
    only: Option<&[String]>,
) -> Result<ReplayStats, ReplayError> {
    let mut r = LogReader::open(log)?;
    let max_frame = r
        .entries
        .iter()
        .filter(|e| e.kind == KIND_FRAME)
        .map(|e| e.len as usize)
        .max()
        .unwrap_or(0);
    let mut sinks: Vec<Option<Box<dyn Sink>>> = Vec::new();
    let mut stats = ReplayStats::default();
    for s in &r.services {
        let wanted = only.is_none_or(|o| o.iter().any(|x| x == &s.name));
        if wanted {
            sinks.push(sink_for(ports, &s.name, max_frame)?);
        } else {
            stats.skipped_services += 1;
            sinks.push(None);
        }
    }
    // Subscribers that already exist receive from the first sample on.
    std::thread::sleep(std::time::Duration::from_millis(50));
    let t_wall0 = monotonic_ns();
    let t_log0 = r.entries.first().map(|e| e.t_origin_ns).unwrap_or(0);
    let mut buf = Vec::new();
    for i in 0..r.entries.len() {
        if sys::termination_requested() {
            stats.interrupted = true;
            break;
        }
        let e = r.entries[i];
        let Some(sink) = sinks[e.service as usize].as_mut() else {
            continue;
        };
        if let Pace::Recorded { speed } = pace {
            let dt = e.t_origin_ns.saturating_sub(t_log0) as f64 / speed.max(1e-6);
            if !sys::sleep_until_ns(t_wall0 + dt as u64) && sys::termination_requested() {
                stats.interrupted = true;
                break;
            }
        }
        r.payload(i, &mut buf)?;
        if !sink.send(&buf)? {
            return Err(ReplayError::BadRecord {
                path: log.display().to_string(),
                index: i,
                service: r.services[e.service as usize].name.clone(),
            });
        }
        stats.published += 1;
    }
    stats.seconds = (monotonic_ns() - t_wall0) as f64 / 1e9;
    Ok(stats)
}

/// Per-service figures of a log.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ServiceSummary {
    pub service: String,
    pub type_name: String,
    pub records: u64,
    pub first_tick: Option<u64>,
    pub last_tick: Option<u64>,
    /// Missing sequence numbers (samples lost before recording).
    pub seq_gaps: u64,
    /// Times the publisher started again (its sequence numbers went back: a restarted
    /// process, whose samples while it was down are lost with no gap in the numbers).
    pub publisher_restarts: u64,
    pub t_span_s: f64,
    pub bytes: u64,
}

/// Summary of a log: per service, plus a few figures of the control run it holds.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LogSummary {
    pub path: String,
    pub records: u64,
    pub rebuilt_index: bool,
    pub services: Vec<ServiceSummary>,
    /// PlantState: mean |q_phy − q_cmd| per joint, degrees (the hysteresis the run saw).
    pub plant_mean_abs_error_deg: Vec<f64>,
    /// MotorCommand: samples with the hold / e-stop / clamped flag.
    pub motor_hold: u64,
    pub motor_estop: u64,
    pub motor_clamped: u64,
    /// JointEstimate: fraction with quality VALID.
    pub estimate_valid_fraction: Option<f64>,
}

impl LogSummary {
    /// Markdown table.
    pub fn to_markdown(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let _ = writeln!(
            s,
            "log `{}`: {} records{}\n",
            self.path,
            self.records,
            if self.rebuilt_index {
                " (index missing or incomplete: rebuilt by scanning)"
            } else {
                ""
            }
        );
        let _ = writeln!(
            s,
            "| service | records | ticks | seq gaps | publisher restarts | span (s) | bytes |\n|---|---:|---|---:|---:|---:|---:|"
        );
        for v in &self.services {
            let ticks = match (v.first_tick, v.last_tick) {
                (Some(a), Some(b)) => format!("{a}..{b}"),
                _ => "-".into(),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.3} | {} |",
                v.service, v.records, ticks, v.seq_gaps, v.publisher_restarts, v.t_span_s, v.bytes
            );
        }
        if !self.plant_mean_abs_error_deg.is_empty() {
            let _ = writeln!(
                s,
                "\nplant mean |q_phy − q_cmd| per joint (deg): {}",
                self.plant_mean_abs_error_deg
                    .iter()
                    .map(|v| format!("{v:.2}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        if self.services.iter().any(|v| v.service == services::MOTOR_COMMAND) {
            let _ = writeln!(
                s,
                "motor commands: {} holding, {} e-stop, {} clamped",
                self.motor_hold, self.motor_estop, self.motor_clamped
            );
        }
        if let Some(f) = self.estimate_valid_fraction {
            let _ = writeln!(s, "joint estimates valid: {:.1} %", f * 100.0);
        }
        s
    }
}

/// Reads the whole log once (verifying every record's checksum) and summarises it.
pub fn summarize(log: &Path) -> Result<LogSummary, LogError> {
    let mut r = LogReader::open(log)?;
    let mut out = LogSummary {
        path: log.display().to_string(),
        records: r.entries.len() as u64,
        rebuilt_index: r.rebuilt_index,
        ..Default::default()
    };
    struct Acc {
        first_t: u64,
        last_t: u64,
        last_seq: Option<u64>,
    }
    let mut acc: Vec<Option<Acc>> = r.services.iter().map(|_| None).collect();
    out.services = r
        .services
        .iter()
        .map(|s| ServiceSummary {
            service: s.name.clone(),
            type_name: s.type_name.clone(),
            ..Default::default()
        })
        .collect();
    let mut err_sum = [0.0f64; MAX_JOINTS];
    let mut n_plant = 0u64;
    let mut n_joints_plant = 0usize;
    let (mut est_valid, mut est_total) = (0u64, 0u64);
    let mut buf = Vec::new();
    for i in 0..r.entries.len() {
        let e = r.payload(i, &mut buf)?;
        let sv = &mut out.services[e.service as usize];
        sv.records += 1;
        sv.bytes += e.len as u64;
        sv.first_tick = Some(sv.first_tick.map_or(e.tick, |t| t.min(e.tick)));
        sv.last_tick = Some(sv.last_tick.map_or(e.tick, |t| t.max(e.tick)));
        let a = acc[e.service as usize].get_or_insert(Acc {
            first_t: e.t_origin_ns,
            last_t: e.t_origin_ns,
            last_seq: None,
        });
        a.first_t = a.first_t.min(e.t_origin_ns);
        a.last_t = a.last_t.max(e.t_origin_ns);
        let multi_publisher = sv.service == services::COMPONENT_STATUS || sv.service == services::SAFETY;
        if !multi_publisher {
            if let Some(l) = a.last_seq {
                if e.seq > l + 1 {
                    sv.seq_gaps += e.seq - l - 1;
                } else if e.seq <= l {
                    sv.publisher_restarts += 1;
                }
            }
            a.last_seq = Some(e.seq);
        }
        sv.t_span_s = (a.last_t - a.first_t) as f64 / 1e9;
        match sv.service.as_str() {
            services::PLANT_STATE => {
                if let Some(p) = PlantState::from_bytes(&buf) {
                    let n = (p.n_joints as usize).min(MAX_JOINTS);
                    n_joints_plant = n_joints_plant.max(n);
                    for (e, (phy, cmd)) in err_sum.iter_mut().zip(p.q_phy_deg.iter().zip(&p.q_cmd_deg)).take(n) {
                        *e += (phy - cmd).abs();
                    }
                    n_plant += 1;
                }
            }
            services::MOTOR_COMMAND => {
                if let Some(m) = MotorCommand::from_bytes(&buf) {
                    out.motor_hold += (m.flags & MotorCommand::FLAG_HOLD != 0) as u64;
                    out.motor_estop += (m.flags & MotorCommand::FLAG_ESTOP != 0) as u64;
                    out.motor_clamped += (m.flags & MotorCommand::FLAG_CLAMPED != 0) as u64;
                }
            }
            services::JOINT_ESTIMATE => {
                if let Some(j) = JointEstimate::from_bytes(&buf) {
                    est_total += 1;
                    est_valid += (j.quality == JointEstimate::QUALITY_VALID) as u64;
                }
            }
            _ => {}
        }
    }
    if n_plant > 0 {
        out.plant_mean_abs_error_deg = err_sum[..n_joints_plant].iter().map(|s| s / n_plant as f64).collect();
    }
    if est_total > 0 {
        out.estimate_valid_fraction = Some(est_valid as f64 / est_total as f64);
    }
    Ok(out)
}
