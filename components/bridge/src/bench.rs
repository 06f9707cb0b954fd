//! `bowden bench bridge`: one hop over the bridge on loopback, beside the plain iceoryx2 hop.
//!
//! Two bridge-only pipelines run as two real-time sessions (their own processes, their own
//! iceoryx2 prefixes), joined by Zenoh over TCP on 127.0.0.1. This process publishes on the
//! first prefix (a thread on a fixed period, `t_origin_ns` = the monotonic clock at publish)
//! and receives on the second (a thread woken by the service's event, as pipeline stages
//! are); one way = arrival − `t_origin_ns`, one clock for all processes of the machine. The
//! measured path is what a consumer on the control PC sees: iceoryx2 → bridge → Zenoh/TCP →
//! bridge → iceoryx2. Frames carry a pseudo-random 640×480 RGBD payload derived from their
//! index; the receiver regenerates it and compares FNV-1a hashes, so a frame counts as
//! delivered only when it arrived intact.

use bowden_interfaces::{fnv1a64, services, JointEstimate, RgbdFrameHeader, SampleHeader};
use bowden_runtime::launch::LaunchOptions;
use bowden_runtime::node::Registry;
use bowden_runtime::ports::{IpcSettings, PortContext};
use bowden_runtime::session::{RealtimeSession, SessionOptions};
use bowden_runtime::stats::{LatencyHistogram, Percentiles};
use bowden_runtime::sys::{monotonic_ns, sleep_until_ns};
use bowden_runtime::{Message, Overrides, PipelineConfig};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// What to measure.
#[derive(Debug, Clone)]
pub struct BridgeBenchOptions {
    /// The `bowden` executable hosting the bridge nodes.
    pub exe: PathBuf,
    /// `JointEstimate` samples per link, and their rate.
    pub samples: usize,
    pub rate_hz: f64,
    /// RGBD frames, and their rate.
    pub frames: usize,
    pub fps: f64,
    /// iceoryx2 prefix stem (one prefix per side and link is made from it).
    pub prefix: String,
    /// Print each bridge process's run summary (its latency since origin, faults).
    pub process_summaries: bool,
}

/// One measured stream.
#[derive(Debug, Clone, Serialize)]
pub struct HopRow {
    pub stream: String,
    pub path: String,
    pub sent: u64,
    /// Arrived (and, for frames, intact).
    pub delivered: u64,
    /// Frames whose payload hash or header differed from what was sent.
    pub corrupt: u64,
    /// Arrival rate over the run, per second.
    pub delivered_per_s: f64,
    pub one_way: Percentiles,
    /// Frames: median one way over the first and the last quarter (falling behind shows as
    /// growth).
    pub p50_first_quarter_ns: Option<u64>,
    pub p50_last_quarter_ns: Option<u64>,
}

/// The payload of frame `k`.
pub fn frame_payload(k: u64, out: &mut [u8]) {
    let mut x = k.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    for chunk in out.chunks_mut(8) {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let b = x.to_le_bytes();
        chunk.copy_from_slice(&b[..chunk.len()]);
    }
}

/// A bridge-only pipeline written to `dir` (the children load it by path).
fn bridge_pipeline(dir: &std::path::Path, prefix: &str, params: &str) -> Result<PipelineConfig, String> {
    let text = format!(
        "[runtime]\nmode = \"realtime\"\nprefix = \"{prefix}\"\nperiod_us = 1000\n\n\
         [[node]]\nname = \"bridge\"\n[node.params]\n{params}\n"
    );
    let path = dir.join(format!("{prefix}bridge.toml"));
    std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    PipelineConfig::load(&path, &Overrides::default(), Registry(&[&crate::KIND])).map_err(|e| e.to_string())
}

fn settings(prefix: &str) -> IpcSettings {
    IpcSettings {
        prefix: prefix.to_string(),
        namespace: String::new(),
    }
}

/// Two bridge sessions (sender side listens, receiver side dials), stopped and cleaned on drop.
struct Link {
    sessions: Vec<Option<RealtimeSession>>,
    summaries: bool,
    prefixes: [String; 2],
    _dir: tempfile::TempDir,
}

impl Link {
    /// Both bridges, sender side on `a_`, receiver side on `b_`.
    fn start(o: &BridgeBenchOptions, prefix: &str, services_list: &str, low_latency: bool) -> Result<Link, String> {
        let port = crate::free_loopback_port().map_err(|e| format!("finding a free port: {e}"))?;
        Self::start_sides(o, prefix, services_list, low_latency, port, true)
    }

    /// Only the importing bridge (on `b_`), dialling `port` where the caller's own Zenoh
    /// session listens: the export then happens in the producer's process.
    fn start_import_only(
        o: &BridgeBenchOptions,
        prefix: &str,
        services_list: &str,
        low_latency: bool,
        port: u16,
    ) -> Result<Link, String> {
        Self::start_sides(o, prefix, services_list, low_latency, port, false)
    }

    fn start_sides(
        o: &BridgeBenchOptions,
        prefix: &str,
        services_list: &str,
        low_latency: bool,
        port: u16,
        export_side: bool,
    ) -> Result<Link, String> {
        let exe = &o.exe;
        let prefixes = [format!("{prefix}a_"), format!("{prefix}b_")];
        let dir = tempfile::tempdir().map_err(|e| format!("temporary directory: {e}"))?;
        let ll = format!("low_latency = {low_latency}");
        let a = bridge_pipeline(
            dir.path(),
            &prefixes[0],
            &format!("listen = [\"tcp/127.0.0.1:{port}\"]\nexport = {services_list}\n{ll}"),
        )?;
        let b = bridge_pipeline(
            dir.path(),
            &prefixes[1],
            &format!("connect = [\"tcp/127.0.0.1:{port}\"]\nimport = {services_list}\n{ll}"),
        )?;
        let mut link = Link {
            sessions: Vec::new(),
            summaries: o.process_summaries,
            prefixes,
            _dir: dir,
        };
        let sides = if export_side { vec![&a, &b] } else { vec![&b] };
        for cfg in sides {
            let mut o = SessionOptions::new(LaunchOptions::with_exe(exe.clone()));
            o.launch.quiet_children = true;
            link.sessions.push(Some(
                RealtimeSession::start(cfg, o).map_err(|e| format!("starting a bridge: {e}"))?,
            ));
        }
        Ok(link)
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        for s in self.sessions.iter_mut() {
            if let Some(s) = s.take() {
                if let Ok(r) = s.shutdown() {
                    if self.summaries {
                        eprintln!("{}", r.format_summary());
                    }
                }
            }
        }
        for p in &self.prefixes {
            let _ = bowden_runtime::cleanup::remove_stale_nodes(&settings(p));
            let _ = bowden_runtime::cleanup::remove_prefix_files(&settings(p));
        }
    }
}

struct Received {
    lat: Vec<(u64, u64)>, // (index, one way ns)
    corrupt: u64,
    first_ns: u64,
    last_ns: u64,
}

/// How the receiving thread learns that a sample arrived.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Reader {
    /// Sleeps on the service's event until the publisher's notification wakes it (an
    /// event-driven consumer: one more wake-up on the path).
    Woken,
    /// Spins on the subscriber: the time the sample became readable in the consumer's shared
    /// memory, which is what a consumer running on its own tick (bowden's stages) gets without
    /// waiting for any wake-up.
    Polling,
}

/// Receives on `prefix` until `stop`; frames are checked against [`frame_payload`].
fn receiver(
    prefix: String,
    frames: bool,
    reader: Reader,
    stop: Arc<AtomicBool>,
    ready: Arc<AtomicBool>,
) -> Result<Received, String> {
    let ctx = PortContext::new("bench-rx", &settings(&prefix)).map_err(|e| e.to_string())?;
    let service = if frames {
        services::RGBD_FRAME
    } else {
        services::JOINT_ESTIMATE
    };
    let waiter = ctx.listener(service).map_err(|e| e.to_string())?;
    let mut est = if frames {
        None
    } else {
        Some(ctx.input::<JointEstimate>(service, 64).map_err(|e| e.to_string())?)
    };
    let mut frm = if frames {
        Some(ctx.frame_input(service, 4).map_err(|e| e.to_string())?)
    } else {
        None
    };
    ready.store(true, Ordering::Release);
    let mut out = Received {
        lat: Vec::new(),
        corrupt: 0,
        first_ns: 0,
        last_ns: 0,
    };
    let mut expected = vec![0u8; RgbdFrameHeader::payload_len_for(640, 480)];
    while !stop.load(Ordering::Acquire) {
        match reader {
            Reader::Woken => {
                waiter.wait(Duration::from_millis(20));
            }
            Reader::Polling => std::hint::spin_loop(),
        }
        loop {
            let now;
            if let Some(inp) = est.as_mut() {
                let Some(e) = inp.recv() else { break };
                now = monotonic_ns();
                out.lat.push((e.header.tick, now.saturating_sub(e.header.t_origin_ns)));
            } else if let Some(inp) = frm.as_mut() {
                let Some(f) = inp.recv() else { break };
                now = monotonic_ns();
                let h = *f.user_header();
                frame_payload(h.header.tick, &mut expected);
                let intact = h.width == 640
                    && h.height == 480
                    && f.payload().len() == expected.len()
                    && fnv1a64(f.payload()) == fnv1a64(&expected);
                if intact {
                    out.lat.push((h.header.tick, now.saturating_sub(h.header.t_origin_ns)));
                } else {
                    out.corrupt += 1;
                }
            } else {
                break;
            }
            if out.first_ns == 0 {
                out.first_ns = now;
            }
            out.last_ns = now;
        }
    }
    Ok(out)
}

/// Sends `count` items at `rate_hz` on the link's first prefix (after a warm-up that waits for
/// the first arrival), while a receiver thread listens on the other prefix; returns the row.
fn stream(link: &Link, frames: bool, count: usize, rate_hz: f64, stream: &str, path: &str) -> Result<HopRow, String> {
    let ctx = PortContext::new("bench-tx", &settings(&link.prefixes[0])).map_err(|e| e.to_string())?;
    let mut est_out = None;
    let mut frame_out = None;
    let wake = ctx
        .notifier(if frames {
            services::RGBD_FRAME
        } else {
            services::JOINT_ESTIMATE
        })
        .map_err(|e| e.to_string())?;
    if frames {
        frame_out = Some(
            ctx.frame_output(services::RGBD_FRAME, RgbdFrameHeader::payload_len_for(640, 480))
                .map_err(|e| e.to_string())?,
        );
    } else {
        let o = ctx
            .output::<JointEstimate>(services::JOINT_ESTIMATE)
            .map_err(|e| e.to_string())?;
        o.update_connections().map_err(|e| e.to_string())?;
        est_out = Some(o);
    }
    let mut payload = vec![0u8; RgbdFrameHeader::payload_len_for(640, 480)];
    let send = |index: u64| -> Result<(), String> {
        if let Some(o) = est_out.as_mut() {
            let e = JointEstimate {
                n_joints: 5,
                ..Default::default()
            };
            o.publish(index, monotonic_ns(), e).map_err(|e| e.to_string())?;
        } else if let Some(o) = frame_out.as_mut() {
            frame_payload(index, &mut payload);
            let p = &payload;
            o.publish_with(index, monotonic_ns(), p.len(), |h, buf| {
                h.width = 640;
                h.height = 480;
                h.depth_offset = 640 * 480 * 3;
                buf.copy_from_slice(p);
                Ok::<(), ()>(())
            })
            .map_err(|e| e.to_string())?
            .map_err(|_| "frame".to_string())?;
        }
        wake.notify().map_err(|e| e.to_string())?;
        Ok(())
    };
    paced_stream(
        &link.prefixes[1],
        frames,
        Reader::Woken,
        count,
        rate_hz,
        stream,
        path,
        send,
    )
}

/// Receives on `rx_prefix` while `send(index)` is called `count` times at `rate_hz` (after a
/// warm-up of unmeasured indices ≥ 2^40 that lets the link carry data end to end); returns
/// the row of what arrived.
#[allow(clippy::too_many_arguments)]
fn paced_stream(
    rx_prefix: &str,
    frames: bool,
    reader: Reader,
    count: usize,
    rate_hz: f64,
    stream: &str,
    path: &str,
    mut send: impl FnMut(u64) -> Result<(), String>,
) -> Result<HopRow, String> {
    let stop = Arc::new(AtomicBool::new(false));
    let ready = Arc::new(AtomicBool::new(false));
    let rx = {
        let (p, s, r) = (rx_prefix.to_string(), stop.clone(), ready.clone());
        std::thread::spawn(move || receiver(p, frames, reader, s, r))
    };
    while !ready.load(Ordering::Acquire) && !rx.is_finished() {
        std::thread::sleep(Duration::from_millis(1));
    }
    let period_ns = (1e9 / rate_hz) as u64;
    let t_warm = monotonic_ns();
    let mut w = 0u64;
    // The receiver counts warm-up arrivals too; they are filtered by index below.
    loop {
        send((1 << 40) + w)?;
        w += 1;
        std::thread::sleep(Duration::from_nanos(period_ns.max(1_000_000)));
        if w >= 200 || monotonic_ns() - t_warm > 30_000_000_000 {
            break;
        }
    }
    let mut next = monotonic_ns() + period_ns;
    for k in 0..count as u64 {
        sleep_until_ns(next);
        send(k)?;
        next += period_ns;
    }
    std::thread::sleep(Duration::from_millis(500));
    stop.store(true, Ordering::Release);
    let got = rx.join().map_err(|_| "receiver thread panicked".to_string())??;
    let measured: Vec<(u64, u64)> = got.lat.iter().copied().filter(|(i, _)| *i < 1 << 40).collect();
    if got.lat.len() == measured.len() && measured.is_empty() {
        return Err(format!("{stream} over {path}: nothing arrived (is the link up?)"));
    }
    let mut h = LatencyHistogram::new();
    for &(_, l) in &measured {
        h.record(l);
    }
    let quarter = |part: &[(u64, u64)]| -> Option<u64> {
        let mut v: Vec<u64> = part.iter().map(|x| x.1).collect();
        v.sort_unstable();
        v.get(v.len() / 2).copied()
    };
    let q = measured.len() / 4;
    let span_s = (count.saturating_sub(1)) as f64 / rate_hz;
    Ok(HopRow {
        stream: stream.into(),
        path: path.into(),
        sent: count as u64,
        delivered: measured.len() as u64,
        corrupt: got.corrupt,
        delivered_per_s: if span_s > 0.0 {
            measured.len().saturating_sub(1) as f64 / span_s
        } else {
            0.0
        },
        one_way: h.percentiles(),
        p50_first_quarter_ns: if frames && q > 0 { quarter(&measured[..q]) } else { None },
        p50_last_quarter_ns: if frames && q > 0 {
            quarter(&measured[measured.len() - q..])
        } else {
            None
        },
    })
}

/// Runs the bridge streams: `JointEstimate` over a low-latency link, then `JointEstimate` and
/// VGA frames over a frame-capable link, then Zenoh alone at the same rate.
pub fn bridge_bench(o: &BridgeBenchOptions, progress: &dyn Fn(&str)) -> Result<Vec<HopRow>, String> {
    if !(o.rate_hz > 0.0 && o.rate_hz <= 10_000.0 && o.fps > 0.0 && o.fps <= 120.0) {
        return Err(format!("rates: {} Hz (0..10000], {} fps (0..120]", o.rate_hz, o.fps));
    }
    // (link: services, low latency) then the streams measured over it, in turn.
    let links: [(&str, &str, bool, &[bool]); 2] = [
        ("l", "[\"bowden/joint_estimate\"]", true, &[false]),
        (
            "f",
            "[\"bowden/joint_estimate\", \"bowden/rgbd_frame\"]",
            false,
            &[false, true],
        ),
    ];
    let mut rows = Vec::new();
    for (tag, services_list, low_latency, streams) in links {
        let transport = if low_latency { "low-latency" } else { "default" };
        progress(&format!(
            "{services_list} over a bridge with Zenoh's {transport} transport"
        ));
        let link = Link::start(o, &format!("{}{tag}", o.prefix), services_list, low_latency)?;
        for &frames in streams {
            let (count, rate, what) = if frames {
                (o.frames, o.fps, "RGBD 640x480 (1.5 MB)")
            } else {
                (o.samples, o.rate_hz, "JointEstimate (184 B)")
            };
            let path = format!("bridge, Zenoh {transport} transport");
            rows.push(stream(&link, frames, count, rate, what, &path)?);
        }
    }
    progress("JointEstimate with the export in the producer's process (only the importing bridge runs apart)");
    rows.push(export_in_producer_row(o, Reader::Woken)?);
    progress("the same, read by polling (when the sample is readable on the consumer's side)");
    rows.push(export_in_producer_row(o, Reader::Polling)?);
    progress("Zenoh alone, process to process, at the same rate");
    rows.push(raw_zenoh_row(o, true)?);
    progress("a plain TCP socket, process to process, at the same rate (the machine's network floor)");
    rows.push(raw_tcp_row(o)?);
    Ok(rows)
}

/// `JointEstimate` with the export in the producer's process, as a bridge stage grouped with
/// its producer (`process = ...` on both nodes) runs it: this process holds the Zenoh session,
/// its liveliness token and the publisher a bridge stage declares, and puts each sample in the
/// bridge's wire format on the bridge's key; only the importing bridge runs as a process. The
/// path has one wake-up less than the full bridge row (the exporting bridge's).
///
/// With [`Reader::Polling`] the consumer spins on its subscriber instead of sleeping on the
/// event: the row then ends when the sample is readable on the consumer's side, as for a
/// stage that reads its inputs on its own tick, and the path has one wake-up (the importing
/// bridge's Zenoh thread), like "Zenoh alone".
fn export_in_producer_row(o: &BridgeBenchOptions, reader: Reader) -> Result<HopRow, String> {
    use zenoh::Wait;
    let port = crate::free_loopback_port().map_err(|e| format!("finding a free port: {e}"))?;
    let services_list = "[\"bowden/joint_estimate\"]";
    let p: crate::BridgeParams = toml::from_str(&format!(
        "listen = [\"tcp/127.0.0.1:{port}\"]\nexport = {services_list}\nlow_latency = true"
    ))
    .map_err(|e| e.to_string())?;
    p.validate("the bench's bridge").map_err(|e| e.to_string())?;
    let session = zenoh::open(p.zenoh_config().map_err(|e| e.to_string())?)
        .wait()
        .map_err(|e| e.to_string())?;
    let zid = session.zid().to_string();
    let _token = session
        .liveliness()
        .declare_token(p.token_key(&zid))
        .wait()
        .map_err(|e| e.to_string())?;
    let publisher = crate::export_publisher(&session, p.key_of(services::JOINT_ESTIMATE)).map_err(|e| e.to_string())?;
    let ty = crate::wire::WireType::of(services::JOINT_ESTIMATE).ok_or("JointEstimate has no wire type")?;
    let tag = match reader {
        Reader::Woken => "p",
        Reader::Polling => "q",
    };
    let link = Link::start_import_only(o, &format!("{}{tag}", o.prefix), services_list, true, port)?;
    let mut seq = 0u64;
    let send = |index: u64| -> Result<(), String> {
        let mut e = JointEstimate {
            n_joints: 5,
            ..Default::default()
        };
        *e.header_mut() = SampleHeader {
            seq,
            tick: index,
            t_origin_ns: monotonic_ns(),
        };
        seq += 1;
        publisher
            .put(crate::wire::encode(ty, &[e.as_bytes()]))
            .wait()
            .map_err(|e| e.to_string())
    };
    let path = match reader {
        Reader::Woken => "bridge, import side only: export in the producer's process (Zenoh low-latency transport)",
        Reader::Polling => "bridge, import side only, read by polling: until readable on the consumer's side",
    };
    paced_stream(
        &link.prefixes[1],
        false,
        reader,
        o.samples,
        o.rate_hz,
        "JointEstimate (184 B)",
        path,
        send,
    )
}

/// A plain iceoryx2 hop's figures as a row beside the bridge's.
pub fn ipc_row(stream: &str, r: &bowden_runtime::bench::IpcResult, samples: u64) -> HopRow {
    HopRow {
        stream: stream.into(),
        path: format!("plain iceoryx2 hop to another process ({}, ping-pong)", r.variant),
        sent: samples,
        delivered: r.one_way.count,
        corrupt: 0,
        delivered_per_s: 0.0,
        one_way: r.one_way,
        p50_first_quarter_ns: None,
        p50_last_quarter_ns: None,
    }
}

/// Key of the raw Zenoh hop (no bowden code on the path).
const RAW_KEY: &str = "bowden-bench/raw";

/// The receiving end of the raw Zenoh hop (`bowden bench bridge-peer`, started by the bench):
/// dials `connect`, prints `ready` once its subscriber is declared and the peer connected, then
/// collects one way = arrival − the sender's monotonic stamp (the first 8 payload bytes) of
/// `count` measured messages (index below 2^40) and returns them.
pub fn raw_zenoh_peer(connect: &str, count: usize, low_latency: bool) -> Result<Vec<u64>, String> {
    use zenoh::Wait;
    let p: crate::BridgeParams = toml::from_str(&format!("connect = [\"{connect}\"]\nlow_latency = {low_latency}"))
        .map_err(|e| e.to_string())?;
    p.validate("the bench's bridge").map_err(|e| e.to_string())?;
    let session = zenoh::open(p.zenoh_config().map_err(|e| e.to_string())?)
        .wait()
        .map_err(|e| e.to_string())?;
    let (tx, rx) = crossbeam::channel::unbounded::<(u64, u64)>();
    let _sub = session
        .declare_subscriber(RAW_KEY)
        .callback(move |s| {
            let now = monotonic_ns();
            let b = s.payload().to_bytes();
            if b.len() >= 16 {
                let t = u64::from_le_bytes(b[0..8].try_into().unwrap_or_default());
                let i = u64::from_le_bytes(b[8..16].try_into().unwrap_or_default());
                let _ = tx.send((i, now.saturating_sub(t)));
            }
        })
        .wait()
        .map_err(|e| e.to_string())?;
    let t0 = std::time::Instant::now();
    while session.info().peers_zid().wait().next().is_none() {
        if t0.elapsed() > Duration::from_secs(20) {
            return Err(format!("no peer at {connect} after 20 s"));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    println!("ready");
    let mut out = Vec::with_capacity(count);
    while out.len() < count {
        match rx.recv_timeout(Duration::from_secs(10)) {
            Ok((i, l)) if i < 1 << 40 => out.push(l),
            Ok(_) => {}
            Err(_) => break,
        }
    }
    Ok(out)
}

/// Zenoh alone between two processes on loopback (this process publishes, a `bridge-peer`
/// child receives): what the bridge's network hop costs on this machine without bowden.
fn raw_zenoh_row(o: &BridgeBenchOptions, low_latency: bool) -> Result<HopRow, String> {
    use zenoh::Wait;
    let port = crate::free_loopback_port().map_err(|e| format!("finding a free port: {e}"))?;
    let p: crate::BridgeParams = toml::from_str(&format!(
        "listen = [\"tcp/127.0.0.1:{port}\"]\nlow_latency = {low_latency}"
    ))
    .map_err(|e| e.to_string())?;
    let session = zenoh::open(p.zenoh_config().map_err(|e| e.to_string())?)
        .wait()
        .map_err(|e| e.to_string())?;
    // The same publisher settings as a bridge's exports.
    let publisher = crate::export_publisher(&session, RAW_KEY.to_string()).map_err(|e| e.to_string())?;
    let args = [
        "bridge-peer".to_string(),
        "--connect".into(),
        format!("tcp/127.0.0.1:{port}"),
        "--low-latency".into(),
        low_latency.to_string(),
    ];
    let lat = paced_to_peer(
        o,
        "raw Zenoh peer",
        &args,
        || Ok(()),
        |_, b| {
            let _ = publisher.put(b.to_vec()).wait();
            Ok(())
        },
    )?;
    Ok(peer_row(
        o,
        &lat,
        format!(
            "Zenoh alone, process to process ({} transport)",
            if low_latency { "low-latency" } else { "default" }
        ),
    ))
}

/// Starts `bowden bench <args> --count <samples>` (a peer that prints `ready`, then the one-way
/// latencies of the measured messages as a JSON list), calls `connected` once it is ready (its
/// result is handed to every `send`),
/// sends it 200 unmeasured warm-up messages and then `samples` measured ones at `rate_hz`
/// through `send` (each 184 bytes: the monotonic send time, then the index; warm-ups have
/// indices ≥ 2^40), and returns what the peer measured.
fn paced_to_peer<C>(
    o: &BridgeBenchOptions,
    who: &str,
    args: &[String],
    connected: impl FnOnce() -> Result<C, String>,
    mut send: impl FnMut(&mut C, &[u8; 184]) -> Result<(), String>,
) -> Result<Vec<u64>, String> {
    use std::io::BufRead;
    let mut child = std::process::Command::new(&o.exe)
        .arg("bench")
        .args(args)
        .args(["--count", &o.samples.to_string()])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .map_err(|e| format!("starting the {who}: {e}"))?;
    let stdout = child.stdout.take().ok_or("peer stdout")?;
    let mut lines = std::io::BufReader::new(stdout).lines();
    let ready = match lines.next() {
        Some(Ok(l)) if l.trim() == "ready" => connected(),
        other => Err(format!("the {who} did not start: {other:?}")),
    };
    let mut connection = match ready {
        Ok(c) => c,
        Err(e) => {
            let _ = child.kill();
            let _ = child.wait();
            return Err(e);
        }
    };
    let mut put = |i: u64| {
        let mut b = [0u8; 184];
        b[0..8].copy_from_slice(&monotonic_ns().to_le_bytes());
        b[8..16].copy_from_slice(&i.to_le_bytes());
        send(&mut connection, &b)
    };
    let period_ns = (1e9 / o.rate_hz) as u64;
    for w in 0..200u64 {
        put((1 << 40) + w)?;
        std::thread::sleep(Duration::from_nanos(period_ns.max(1_000_000)));
    }
    let mut next = monotonic_ns() + period_ns;
    for k in 0..o.samples as u64 {
        sleep_until_ns(next);
        put(k)?;
        next += period_ns;
    }
    let rest: Vec<String> = lines.map_while(Result::ok).collect();
    let status = child.wait().map_err(|e| e.to_string())?;
    if !status.success() {
        return Err(format!("the {who} failed ({status})"));
    }
    serde_json::from_str(rest.last().map(|s| s.as_str()).unwrap_or("[]")).map_err(|e| format!("{who} output: {e}"))
}

/// The row of a peer's one-way latencies.
fn peer_row(o: &BridgeBenchOptions, lat: &[u64], path: String) -> HopRow {
    let mut h = LatencyHistogram::new();
    for &l in lat {
        h.record(l);
    }
    HopRow {
        stream: "184-byte message".into(),
        path,
        sent: o.samples as u64,
        delivered: lat.len() as u64,
        corrupt: 0,
        delivered_per_s: 0.0,
        one_way: h.percentiles(),
        p50_first_quarter_ns: None,
        p50_last_quarter_ns: None,
    }
}

/// The receiving end of the plain TCP hop (`bowden bench tcp-peer`, started by the bench):
/// dials `connect` (TCP_NODELAY), prints `ready`, then reads `count` measured 184-byte messages
/// with blocking reads on this one thread and returns one way = arrival − the sender's
/// monotonic stamp (the first 8 bytes) of each. One wake-up per message, no runtime between the
/// socket and the clock read: the least any network hop costs on this machine.
pub fn raw_tcp_peer(connect: &str, count: usize) -> Result<Vec<u64>, String> {
    use std::io::Read;
    let mut s = std::net::TcpStream::connect(connect).map_err(|e| format!("connecting to {connect}: {e}"))?;
    s.set_nodelay(true).map_err(|e| e.to_string())?;
    s.set_read_timeout(Some(Duration::from_secs(10)))
        .map_err(|e| e.to_string())?;
    println!("ready");
    let mut out = Vec::with_capacity(count);
    let mut b = [0u8; 184];
    while out.len() < count {
        if s.read_exact(&mut b).is_err() {
            break;
        }
        let now = monotonic_ns();
        let t = u64::from_le_bytes(b[0..8].try_into().unwrap_or_default());
        let i = u64::from_le_bytes(b[8..16].try_into().unwrap_or_default());
        if i < 1 << 40 {
            out.push(now.saturating_sub(t));
        }
    }
    Ok(out)
}

/// A plain TCP socket between two processes on loopback (this process writes, a `tcp-peer`
/// child reads), at the rate of the bridge rows: the floor under every network row, so that a
/// bridge or Zenoh figure can be read as what it adds to the machine's own hop.
fn raw_tcp_row(o: &BridgeBenchOptions) -> Result<HopRow, String> {
    use std::io::Write;
    let listener = std::net::TcpListener::bind("127.0.0.1:0").map_err(|e| format!("binding a loopback port: {e}"))?;
    let port = listener.local_addr().map_err(|e| e.to_string())?.port();
    let args = ["tcp-peer".to_string(), "--connect".into(), format!("127.0.0.1:{port}")];
    let connect = || {
        let (s, _) = listener
            .accept()
            .map_err(|e| format!("the TCP peer did not connect: {e}"))?;
        s.set_nodelay(true).map_err(|e| e.to_string())?;
        Ok(s)
    };
    let lat = paced_to_peer(o, "TCP peer", &args, connect, |s, b| {
        s.write_all(b).map_err(|e| format!("writing to the TCP peer: {e}"))
    })?;
    Ok(peer_row(
        o,
        &lat,
        "plain TCP socket, process to process (blocking read, TCP_NODELAY)".into(),
    ))
}
