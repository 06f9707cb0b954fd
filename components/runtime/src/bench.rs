//! Benchmarks of the runtime: one IPC hop (bowden's ports against raw iceoryx2 in the same run)
//! and the end-to-end control cycle of a real-time pipeline, with and without CPU load.
//!
//! IPC: a ping side and a pong side (another process by default, or another thread). Ping stamps
//! `t0` and sends; pong receives at `t1` (one way = t1 − t0, the same monotonic clock in both
//! processes) and echoes `t1`; ping receives at `t2` (round trip = t2 − t0). Both sides either
//! busy-poll their subscriber or block on the service's event listener (`-event` variants, what
//! the pipeline's event-driven stages do). Frames: the publisher writes the header and the first
//! and last byte of a loaned slice, the subscriber reads them: a hop is zero copy, so its time
//! does not depend on the frame size.

use crate::alloc;
use crate::launch::LaunchOptions;
use crate::ports::{IpcSettings, PortContext};
use crate::rt::{self, Outcome};
use crate::session::{RealtimeSession, RunReport, SessionError, SessionOptions};
use crate::stats::{LatencyHistogram, Percentiles};
use crate::sys::monotonic_ns;
use crate::PipelineConfig;
use bowden_interfaces::{JointCommand, RgbdFrameHeader};
use iceoryx2::prelude::*;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Bytes of a 640×480 RGBD frame (RGB8 + u16 depth).
pub const VGA_FRAME_BYTES: usize = RgbdFrameHeader::payload_len_for(640, 480);
/// A small frame, to show the hop does not depend on size.
pub const SMALL_FRAME_BYTES: usize = 64;

/// What one IPC measurement exchanges, and how.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    strum::EnumString,
    strum::IntoStaticStr,
    strum::Display,
    strum::VariantNames,
    strum::VariantArray,
)]
pub enum IpcVariant {
    /// iceoryx2 API directly, `JointCommand` (240 B), busy polling.
    #[strum(serialize = "raw-sample")]
    RawSample,
    /// bowden `Output`/`Input`, `JointCommand`, busy polling.
    #[strum(serialize = "ports-sample")]
    PortsSample,
    /// iceoryx2 directly + event notifier/listener wake-up.
    #[strum(serialize = "raw-sample-event")]
    RawSampleEvent,
    /// bowden ports + `Wakeup`/`Waiter` (the pipeline's event-driven path).
    #[strum(serialize = "ports-sample-event")]
    PortsSampleEvent,
    #[strum(serialize = "raw-frame-64B")]
    RawFrameSmall,
    #[strum(serialize = "ports-frame-64B")]
    PortsFrameSmall,
    #[strum(serialize = "raw-frame-640x480")]
    RawFrameVga,
    #[strum(serialize = "ports-frame-640x480")]
    PortsFrameVga,
}

impl IpcVariant {
    /// Every variant, in declaration order.
    pub const ALL: &'static [IpcVariant] = <IpcVariant as strum::VariantArray>::VARIANTS;

    /// The spelling in configs, reports and on the command line.
    pub fn as_str(self) -> &'static str {
        self.into()
    }

    /// Parses the spelling of [`IpcVariant::as_str`].
    pub fn parse(s: &str) -> Option<Self> {
        s.parse().ok()
    }

    pub fn description(self) -> &'static str {
        match self {
            IpcVariant::RawSample => "raw iceoryx2, JointCommand 240 B, busy poll",
            IpcVariant::PortsSample => "bowden ports, JointCommand 240 B, busy poll",
            IpcVariant::RawSampleEvent => "raw iceoryx2 + event wake-up, 240 B",
            IpcVariant::PortsSampleEvent => "bowden ports + event wake-up, 240 B",
            IpcVariant::RawFrameSmall => "raw iceoryx2, [u8] frame 64 B",
            IpcVariant::PortsFrameSmall => "bowden frame port, 64 B",
            IpcVariant::RawFrameVga => "raw iceoryx2, [u8] frame 640x480 RGBD (1.5 MB)",
            IpcVariant::PortsFrameVga => "bowden frame port, 640x480 RGBD (1.5 MB)",
        }
    }

    fn frame_len(self) -> Option<usize> {
        match self {
            IpcVariant::RawFrameSmall | IpcVariant::PortsFrameSmall => Some(SMALL_FRAME_BYTES),
            IpcVariant::RawFrameVga | IpcVariant::PortsFrameVga => Some(VGA_FRAME_BYTES),
            _ => None,
        }
    }

    fn event(self) -> bool {
        matches!(self, IpcVariant::RawSampleEvent | IpcVariant::PortsSampleEvent)
    }

    fn raw(self) -> bool {
        matches!(
            self,
            IpcVariant::RawSample | IpcVariant::RawSampleEvent | IpcVariant::RawFrameSmall | IpcVariant::RawFrameVga
        )
    }
}

/// Result of one variant.
#[derive(Debug, Clone, serde::Serialize)]
pub struct IpcResult {
    pub variant: &'static str,
    pub description: &'static str,
    pub one_way: Percentiles,
    pub round_trip: Percentiles,
    /// Heap allocations per send on the ping side: system allocator calls and pool blocks.
    pub system_allocs_per_send: f64,
    pub pool_allocs_per_send: f64,
}

/// Where the pong side runs.
#[derive(Debug, Clone)]
pub enum Peer {
    Thread,
    /// `exe bench ipc-peer --variant V --prefix P --count N` (the `bowden` binary).
    Process(std::path::PathBuf),
}

#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error("ipc bench `{variant}`: {message}")]
    Ipc { variant: &'static str, message: String },
    #[error(transparent)]
    Session(#[from] SessionError),
}

fn ipc_err(v: IpcVariant, m: impl std::fmt::Display) -> BenchError {
    BenchError::Ipc {
        variant: v.as_str(),
        message: m.to_string(),
    }
}

const PING: &str = "bench/ping";
const PONG: &str = "bench/pong";

type RawPub<T> = iceoryx2::port::publisher::Publisher<ipc::Service, T, ()>;
type RawSub<T> = iceoryx2::port::subscriber::Subscriber<ipc::Service, T, ()>;
type RawFramePub = iceoryx2::port::publisher::Publisher<ipc::Service, [u8], RgbdFrameHeader>;
type RawFrameSub = iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], RgbdFrameHeader>;

/// One side's ports for a variant: send a stamp, receive a stamp. One value per benchmark run:
/// the size difference of the variants does not matter.
#[allow(clippy::large_enum_variant)]
enum Side {
    Raw {
        tx: RawPub<JointCommand>,
        rx: RawSub<JointCommand>,
        ev: Option<(
            iceoryx2::port::notifier::Notifier<ipc::Service>,
            iceoryx2::port::listener::Listener<ipc::Service>,
        )>,
    },
    Ports {
        tx: crate::ports::Output<JointCommand>,
        rx: crate::ports::Input<JointCommand>,
        ev: Option<(crate::ports::Wakeup, crate::ports::Waiter)>,
    },
    RawFrame {
        tx: RawFramePub,
        rx: RawFrameSub,
        len: usize,
    },
    PortsFrame {
        tx: crate::ports::FrameOutput,
        rx: crate::ports::FrameInput,
        len: usize,
    },
}

fn raw_service_sample(
    node: &iceoryx2::node::Node<ipc::Service>,
    name: &str,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, JointCommand, ()>, String> {
    let q = crate::ports::qos_for(name);
    node.service_builder(&ServiceName::new(name).map_err(|e| format!("{e:?}"))?)
        .publish_subscribe::<JointCommand>()
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .subscriber_max_buffer_size(q.max_buffer)
        .subscriber_max_borrowed_samples(q.max_borrowed)
        .history_size(q.history)
        .enable_safe_overflow(q.safe_overflow)
        .max_nodes(q.max_nodes)
        .open_or_create()
        .map_err(|e| format!("{e:?}"))
}

fn raw_service_frame(
    node: &iceoryx2::node::Node<ipc::Service>,
    name: &str,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [u8], RgbdFrameHeader>, String>
{
    let q = crate::ports::qos_for("rgbd_frame");
    node.service_builder(&ServiceName::new(name).map_err(|e| format!("{e:?}"))?)
        .publish_subscribe::<[u8]>()
        .user_header::<RgbdFrameHeader>()
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .subscriber_max_buffer_size(q.max_buffer)
        .subscriber_max_borrowed_samples(q.max_borrowed)
        .history_size(q.history)
        .enable_safe_overflow(q.safe_overflow)
        .max_nodes(q.max_nodes)
        .open_or_create()
        .map_err(|e| format!("{e:?}"))
}

fn raw_event(
    node: &iceoryx2::node::Node<ipc::Service>,
    name: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<ipc::Service>, String> {
    node.service_builder(&ServiceName::new(name).map_err(|e| format!("{e:?}"))?)
        .event()
        .max_notifiers(32)
        .max_listeners(32)
        .max_nodes(32)
        .open_or_create()
        .map_err(|e| format!("{e:?}"))
}

/// The ports of one side. Ping sends on PING and receives PONG; pong the other way round.
/// The raw side keeps its own node alive through the returned context's node.
fn make_side(v: IpcVariant, ctx: &PortContext, ping: bool) -> Result<Side, String> {
    let (tx_name, rx_name) = if ping { (PING, PONG) } else { (PONG, PING) };
    let node = ctx.node();
    let ns = |n: &str| ctx.settings().service_name(n);
    Ok(match (v.raw(), v.frame_len()) {
        (true, None) => {
            let txs = raw_service_sample(node, &ns(tx_name))?;
            let rxs = raw_service_sample(node, &ns(rx_name))?;
            let ev = if v.event() {
                let n = raw_event(node, &ns(tx_name))?
                    .notifier_builder()
                    .create()
                    .map_err(|e| format!("{e:?}"))?;
                let l = raw_event(node, &ns(rx_name))?
                    .listener_builder()
                    .create()
                    .map_err(|e| format!("{e:?}"))?;
                Some((n, l))
            } else {
                None
            };
            Side::Raw {
                tx: txs
                    .publisher_builder()
                    .max_loaned_samples(2)
                    .create()
                    .map_err(|e| format!("{e:?}"))?,
                rx: rxs
                    .subscriber_builder()
                    .buffer_size(4)
                    .create()
                    .map_err(|e| format!("{e:?}"))?,
                ev,
            }
        }
        (false, None) => {
            let ev = if v.event() {
                Some((
                    ctx.notifier(tx_name).map_err(|e| e.to_string())?,
                    ctx.listener(rx_name).map_err(|e| e.to_string())?,
                ))
            } else {
                None
            };
            Side::Ports {
                tx: ctx.output(tx_name).map_err(|e| e.to_string())?,
                rx: ctx.input(rx_name, 4).map_err(|e| e.to_string())?,
                ev,
            }
        }
        (true, Some(len)) => {
            let txs = raw_service_frame(node, &ns(tx_name))?;
            let rxs = raw_service_frame(node, &ns(rx_name))?;
            Side::RawFrame {
                tx: txs
                    .publisher_builder()
                    .initial_max_slice_len(len)
                    .allocation_strategy(AllocationStrategy::Static)
                    .max_loaned_samples(1)
                    .create()
                    .map_err(|e| format!("{e:?}"))?,
                rx: rxs
                    .subscriber_builder()
                    .buffer_size(4)
                    .create()
                    .map_err(|e| format!("{e:?}"))?,
                len,
            }
        }
        (false, Some(len)) => Side::PortsFrame {
            tx: ctx.frame_output(tx_name, len).map_err(|e| e.to_string())?,
            rx: ctx.frame_input(rx_name, 4).map_err(|e| e.to_string())?,
            len,
        },
    })
}

impl Side {
    /// Sends stamp (`seq`, `t_ns`).
    fn send(&mut self, seq: u64, t_ns: u64) -> Result<(), String> {
        match self {
            Side::Raw { tx, ev, .. } => {
                let mut c = JointCommand::default();
                c.header.seq = seq;
                c.header.t_origin_ns = t_ns;
                tx.loan_uninit()
                    .map_err(|e| format!("{e:?}"))?
                    .write_payload(c)
                    .send()
                    .map_err(|e| format!("{e:?}"))?;
                if let Some((n, _)) = ev {
                    n.notify().map_err(|e| format!("{e:?}"))?;
                }
            }
            Side::Ports { tx, ev, .. } => {
                tx.publish(seq, t_ns, JointCommand::default())
                    .map_err(|e| e.to_string())?;
                if let Some((n, _)) = ev {
                    n.notify().map_err(|e| e.to_string())?;
                }
            }
            Side::RawFrame { tx, len, .. } => {
                let s = tx.loan_slice_uninit(*len).map_err(|e| format!("{e:?}"))?;
                // SAFETY: u8 shared memory, always initialised at the OS level (see ports.rs).
                let mut s = unsafe { s.assume_init() };
                s.user_header_mut().header.seq = seq;
                s.user_header_mut().header.t_origin_ns = t_ns;
                let p = s.payload_mut();
                let n = p.len();
                p[0] = seq as u8;
                p[n - 1] = seq as u8;
                s.send().map_err(|e| format!("{e:?}"))?;
            }
            Side::PortsFrame { tx, len, .. } => {
                tx.publish_with::<()>(seq, t_ns, *len, |_, p| {
                    let n = p.len();
                    p[0] = seq as u8;
                    p[n - 1] = seq as u8;
                    Ok(())
                })
                .map_err(|e| e.to_string())?
                .map_err(|_| "fill".to_string())?;
            }
        }
        Ok(())
    }

    /// Waits for the next stamp: busy polling, or blocking on the listener.
    fn recv(&mut self, timeout: Duration) -> Result<Option<(u64, u64)>, String> {
        let until = Instant::now() + timeout;
        loop {
            let got = match self {
                Side::Raw { rx, ev, .. } => match rx.receive().map_err(|e| format!("{e:?}"))? {
                    Some(s) => Some((s.header.seq, s.header.t_origin_ns)),
                    None => {
                        if let Some((_, l)) = ev {
                            l.timed_wait(|_| {}, Duration::from_millis(100))
                                .map_err(|e| format!("{e:?}"))?;
                        }
                        None
                    }
                },
                Side::Ports { rx, ev, .. } => match rx.recv() {
                    Some(s) => Some((s.header.tick, s.header.t_origin_ns)),
                    None => {
                        if let Some((_, l)) = ev {
                            l.wait(Duration::from_millis(100));
                        }
                        None
                    }
                },
                Side::RawFrame { rx, .. } => match rx.receive().map_err(|e| format!("{e:?}"))? {
                    Some(s) => {
                        let h = s.user_header().header;
                        let p = s.payload();
                        std::hint::black_box((p[0], p[p.len() - 1]));
                        Some((h.seq, h.t_origin_ns))
                    }
                    None => None,
                },
                Side::PortsFrame { rx, .. } => match rx.recv() {
                    Some(s) => {
                        let h = s.user_header().header;
                        let p = s.payload();
                        std::hint::black_box((p[0], p[p.len() - 1]));
                        Some((h.tick, h.t_origin_ns))
                    }
                    None => None,
                },
            };
            if got.is_some() {
                return Ok(got);
            }
            if Instant::now() >= until {
                return Ok(None);
            }
            std::hint::spin_loop();
        }
    }
}

/// The ping that tells the pong side to stop.
const STOP: u64 = u64::MAX;

/// The pong side: echoes every ping with its receive time until the stop ping, and returns the
/// one-way latencies (ns) of the pings after the first `warmup`. `expect` sizes the buffer up
/// front so recording does not allocate on the measured path.
pub fn run_ipc_peer(v: IpcVariant, settings: &IpcSettings, warmup: usize, expect: usize) -> Result<Vec<u64>, String> {
    let ctx = PortContext::new("bench_pong", settings).map_err(|e| e.to_string())?;
    let mut side = make_side(v, &ctx, false)?;
    let mut one_way = Vec::with_capacity(expect);
    let mut n = 0usize;
    loop {
        let Some((seq, t0)) = side.recv(Duration::from_secs(60))? else {
            return Err("no ping for 60 s".into());
        };
        let t1 = monotonic_ns();
        if seq == STOP {
            break;
        }
        n += 1;
        if n > warmup {
            one_way.push(t1.saturating_sub(t0));
        }
        side.send(seq, t1)?;
    }
    Ok(one_way)
}

type PeerResult = Arc<std::sync::Mutex<Option<Result<Vec<u64>, String>>>>;

/// A ping side connected to a running pong side: one [`PingPong::round_trip`] per call.
pub struct PingPong {
    v: IpcVariant,
    side: Side,
    seq: u64,
    thread: Option<std::thread::JoinHandle<()>>,
    child: Option<std::process::Child>,
    slot: PeerResult,
    ctx: PortContext,
}

impl PingPong {
    /// Creates the ping ports under `prefix`, starts the pong side and waits until it is connected.
    /// The pong side ignores the first `warmup` pings in its one-way figures, expects about
    /// `expect` more, and runs under SCHED_FIFO at `fifo` if given (and permitted).
    pub fn start(
        v: IpcVariant,
        prefix: &str,
        peer: &Peer,
        warmup: usize,
        expect: usize,
        fifo: Option<u8>,
    ) -> Result<Self, BenchError> {
        let settings = IpcSettings {
            prefix: prefix.to_string(),
            namespace: String::new(),
        };
        let ctx = PortContext::new("bench_ping", &settings).map_err(|e| ipc_err(v, e))?;
        let side = make_side(v, &ctx, true).map_err(|e| ipc_err(v, e))?;
        let mut pp = Self {
            v,
            side,
            seq: 0,
            thread: None,
            child: None,
            slot: Arc::default(),
            ctx,
        };
        match peer {
            Peer::Thread => {
                let s = settings.clone();
                let slot = pp.slot.clone();
                pp.thread = Some(std::thread::spawn(move || {
                    if let Some(p) = fifo {
                        let _ = rt::set_fifo(p);
                    }
                    let r = run_ipc_peer(v, &s, warmup, expect);
                    *slot.lock().expect("not poisoned") = Some(r);
                }));
            }
            Peer::Process(exe) => {
                let mut cmd = std::process::Command::new(exe);
                cmd.args(["bench", "ipc-peer", "--variant", v.as_str(), "--prefix", prefix])
                    .arg("--warmup")
                    .arg(warmup.to_string())
                    .arg("--expect")
                    .arg(expect.to_string())
                    .stdout(std::process::Stdio::piped());
                if let Some(p) = fifo {
                    cmd.arg("--fifo").arg(p.to_string());
                }
                pp.child = Some(
                    cmd.spawn()
                        .map_err(|e| ipc_err(v, format!("cannot start the peer process {}: {e}", exe.display())))?,
                );
            }
        }
        // Wait for the peer's ports: its subscriber on PING and its publisher on PONG.
        let t_wait = Instant::now();
        let frame = v.frame_len().is_some();
        loop {
            let ready = subscriber_count(&pp.ctx, &settings.service_name(PING), frame) >= 1
                && publisher_count(&pp.ctx, &settings.service_name(PONG), frame) >= 1;
            if ready {
                break;
            }
            if t_wait.elapsed() > Duration::from_secs(10) {
                return Err(ipc_err(v, "the peer did not come up within 10 s"));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        Ok(pp)
    }

    /// One ping and its pong; returns the round-trip time, ns.
    pub fn round_trip(&mut self) -> Result<u64, BenchError> {
        let v = self.v;
        let i = self.seq;
        self.seq += 1;
        let t0 = monotonic_ns();
        self.side.send(i, t0).map_err(|e| ipc_err(v, e))?;
        match self.side.recv(Duration::from_secs(10)).map_err(|e| ipc_err(v, e))? {
            Some((seq, _t1)) if seq == i => Ok(monotonic_ns() - t0),
            Some((seq, _)) => Err(ipc_err(v, format!("pong {seq} for ping {i}"))),
            None => Err(ipc_err(v, format!("no pong for ping {i} within 10 s"))),
        }
    }

    /// Stops the pong side and returns its one-way latencies, ns.
    pub fn finish(mut self) -> Result<Vec<u64>, BenchError> {
        let v = self.v;
        self.side.send(STOP, monotonic_ns()).map_err(|e| ipc_err(v, e))?;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
            return self
                .slot
                .lock()
                .expect("not poisoned")
                .take()
                .unwrap_or_else(|| Err("peer thread ended without a result".into()))
                .map_err(|e| ipc_err(v, e));
        }
        let c = self.child.take().ok_or_else(|| ipc_err(v, "no peer"))?;
        let out = c.wait_with_output().map_err(|e| ipc_err(v, e))?;
        if !out.status.success() {
            return Err(ipc_err(v, format!("peer process failed ({})", out.status)));
        }
        let text = String::from_utf8_lossy(&out.stdout);
        let line = text.lines().last().unwrap_or_default();
        serde_json::from_str::<Vec<u64>>(line).map_err(|e| ipc_err(v, format!("peer output: {e}")))
    }
}

impl Drop for PingPong {
    fn drop(&mut self) {
        // An unfinished bench must not leave its peer spinning.
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        if let Some(t) = self.thread.take() {
            let _ = self.side.send(STOP, 0);
            let _ = t.join();
        }
    }
}

/// Accumulated figures of one variant over several rounds.
struct Acc {
    rtt: LatencyHistogram,
    one_way: LatencyHistogram,
    allocs: alloc::AllocCounts,
    sends: u64,
}

/// One round of `v`: a fresh peer, `warmup` unmeasured round trips, `samples` measured ones.
fn ipc_round(
    v: IpcVariant,
    prefix: &str,
    samples: usize,
    warmup: usize,
    peer: &Peer,
    fifo: Option<u8>,
    acc: &mut Acc,
) -> Result<(), BenchError> {
    let mut pp = PingPong::start(v, prefix, peer, warmup, samples, fifo)?;
    for _ in 0..warmup {
        pp.round_trip()?;
    }
    let before = alloc::thread_counts();
    for _ in 0..samples {
        acc.rtt.record(pp.round_trip()?);
    }
    let d = alloc::thread_counts().since(&before);
    acc.allocs.system_allocs += d.system_allocs;
    acc.allocs.pool_allocs += d.pool_allocs;
    acc.sends += samples as u64;
    for ns in pp.finish()? {
        acc.one_way.record(ns);
    }
    Ok(())
}

fn subscriber_count(ctx: &PortContext, service: &str, frame: bool) -> usize {
    counts(ctx, service, frame).1
}

fn publisher_count(ctx: &PortContext, service: &str, frame: bool) -> usize {
    counts(ctx, service, frame).0
}

fn counts(ctx: &PortContext, service: &str, frame: bool) -> (usize, usize) {
    use iceoryx2::service::port_factory::PortFactory as _;
    let Ok(name) = ServiceName::new(service) else {
        return (0, 0);
    };
    if frame {
        match raw_service_frame(ctx.node(), name.as_str()) {
            Ok(f) => (
                f.dynamic_config().number_of_publishers(),
                f.dynamic_config().number_of_subscribers(),
            ),
            Err(_) => (0, 0),
        }
    } else {
        match raw_service_sample(ctx.node(), name.as_str()) {
            Ok(f) => (
                f.dynamic_config().number_of_publishers(),
                f.dynamic_config().number_of_subscribers(),
            ),
            Err(_) => (0, 0),
        }
    }
}

/// Runs every variant, `rounds` times in turn (raw and bowden alternate, so both see the same
/// machine), `samples / rounds` round trips per round, each round with a fresh peer and prefix.
/// With `fifo`, ping and pong run under SCHED_FIFO at that priority when permitted.
pub fn ipc_bench(
    prefix_base: &str,
    samples: usize,
    warmup: usize,
    rounds: usize,
    peer: &Peer,
    variants: &[IpcVariant],
    fifo: Option<u8>,
) -> Result<Vec<IpcResult>, BenchError> {
    alloc::enable_pool();
    if let Some(p) = fifo {
        let _ = rt::set_fifo(p);
    }
    let rounds = rounds.max(1);
    let per_round = samples.div_ceil(rounds);
    let mut accs: Vec<Acc> = variants
        .iter()
        .map(|_| Acc {
            rtt: LatencyHistogram::new(),
            one_way: LatencyHistogram::new(),
            allocs: alloc::AllocCounts::default(),
            sends: 0,
        })
        .collect();
    for r in 0..rounds {
        for (i, &v) in variants.iter().enumerate() {
            let settings = IpcSettings {
                prefix: format!("{prefix_base}{r}x{i}_"),
                namespace: String::new(),
            };
            let res = ipc_round(v, &settings.prefix, per_round, warmup, peer, fifo, &mut accs[i]);
            let _ = crate::cleanup::remove_stale_nodes(&settings);
            let _ = crate::cleanup::remove_prefix_files(&settings);
            res?;
        }
    }
    Ok(variants
        .iter()
        .zip(accs)
        .map(|(v, a)| IpcResult {
            variant: v.as_str(),
            description: v.description(),
            one_way: a.one_way.percentiles(),
            round_trip: a.rtt.percentiles(),
            system_allocs_per_send: a.allocs.system_allocs as f64 / a.sends.max(1) as f64,
            pool_allocs_per_send: a.allocs.pool_allocs as f64 / a.sends.max(1) as f64,
        })
        .collect())
}

/// CPU load during a cycle benchmark.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Load {
    None,
    /// Busy threads (integer and memory work) pinned to these CPUs.
    Cpus(Vec<usize>),
}

/// Spinning threads that keep CPUs and the memory bus busy until dropped.
pub struct LoadGenerator {
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl LoadGenerator {
    pub fn start(cpus: &[usize]) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let threads = cpus
            .iter()
            .map(|&c| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let _ = rt::pin_to_cpus(&[c]);
                    // 8 MiB: larger than the last-level cache, so the load also evicts.
                    let mut buf = vec![0u64; 1 << 20];
                    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
                    while !stop.load(Ordering::Relaxed) {
                        for _ in 0..4096 {
                            x ^= x << 13;
                            x ^= x >> 7;
                            x ^= x << 17;
                            let i = (x as usize) & (buf.len() - 1);
                            buf[i] = buf[i].wrapping_add(x);
                        }
                    }
                    std::hint::black_box(&buf);
                })
            })
            .collect();
        Self { stop, threads }
    }
}

impl Drop for LoadGenerator {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Whether this process may use SCHED_FIFO (tried on a throw-away thread).
pub fn probe_fifo(priority: u8) -> Outcome {
    std::thread::spawn(move || rt::set_fifo(priority))
        .join()
        .unwrap_or_else(|_| Outcome::Refused("probe thread panicked".into()))
}

/// One cycle-benchmark run.
#[derive(Debug, Clone)]
pub struct CycleResult {
    pub label: String,
    pub report: RunReport,
}

/// Runs `cfg` (real time) for `seconds` under `load`, returns the run's report (every stage's
/// final status carries its latency percentiles and misses).
///
/// With `summaries`, every process prints its own report on stderr at the end: per stage the
/// compute-time percentiles of its own steps and the overruns of its `budget_us`, which tell
/// a miss the stage caused from one the process inherited (a late wake-up, a stage before it).
pub fn cycle_run(
    cfg: &PipelineConfig,
    launch: &LaunchOptions,
    seconds: f64,
    load: &Load,
    label: &str,
    summaries: bool,
) -> Result<CycleResult, BenchError> {
    let mut opts = SessionOptions::new(launch.clone());
    opts.launch.quiet_children = !summaries;
    let session = RealtimeSession::start(cfg, opts)?;
    let gen = match load {
        Load::None => None,
        Load::Cpus(c) => Some(LoadGenerator::start(c)),
    };
    let mut session = session;
    session.run_for(Some(Duration::from_secs_f64(seconds)))?;
    drop(gen);
    let report = session.shutdown()?;
    Ok(CycleResult {
        label: label.to_string(),
        report,
    })
}
