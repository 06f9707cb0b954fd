//! The `bridge` stage: forwards chosen iceoryx2 services to and from another machine over
//! [Zenoh](https://zenoh.io) (what ROS 2's rmw_zenoh uses), so the camera and the marker
//! estimator can run on a vision PC while the control chain runs on the real-time control PC.
//!
//! One bridge per machine and link, a stage of its pipeline like any other (its process wakes
//! on its exported services, on samples arriving from the peer, and every 50 ms):
//!
//! - **export** (iceoryx2 → Zenoh): every sample of an exported service is sent as one Zenoh
//!   message, its exact shared-memory bytes behind a 16-byte header ([`wire`]).
//! - **import** (Zenoh → iceoryx2): the Zenoh thread that receives a message checks it (magic,
//!   the sample type of this build, sizes) and republishes its bytes unchanged on iceoryx2 at
//!   once, so `seq`, `tick` and `t_origin_ns` cross intact. Imports are published through
//!   iceoryx2's thread-safe `ipc_threadsafe` variant (the same shared memory as `ipc`, its
//!   ports guarded by a mutex): handing the message to the stage's own thread instead would
//!   cost one more thread wake-up per sample.
//!   `t_origin_ns` stays on the clock of the machine where the information originated: across
//!   machines, latencies computed from it include the clocks' offset (synchronise with PTP).
//! - **peer**: each bridge holds a Zenoh liveliness token; a peer whose token disappears (its
//!   process died: at once; its network went silent: after `lease_ms`) is a fault, reported
//!   with what stops arriving, and the stage is degraded until a peer is back. Nothing hangs:
//!   the consumers of imported services see them go stale and fall back as they do for a
//!   local producer that died.
//! - **no surprise sockets**: the Zenoh session opens exactly `listen` and `connect`; no
//!   multicast scouting, no gossip.
//!
//! Lockstep cannot span two machines' clocks: the pipeline config refuses a bridge in lockstep.

pub mod bench;
pub mod params;
pub mod wire;

use bowden_interfaces::{services, SampleHeader};
use bowden_runtime::node::{service_list, NodeKind, ParamPorts, ParamPortsError, Read, Schedule};
use bowden_runtime::ports::{
    visit_payload, FrameInput, FrameOutput, Input, Output, PayloadVisitor, PortContext, PortError, Wakeup,
};
use bowden_runtime::stage::{Stage, StageBuildError, StageCounters, StageEnv, StageError, StepCx, StepReport};
use bowden_runtime::sys::{monotonic_ns, EventFd};
use bowden_runtime::Message;
use crossbeam::queue::ArrayQueue;
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use zenoh::Wait;

pub use params::BridgeParams;
use wire::{WireError, WireType};

/// Zenoh's runtime layout in bowden's processes unless the user sets `ZENOH_RUNTIME`: all of
/// Zenoh's runtimes (app, acceptor, tx, rx, net) handed over to one tokio runtime with one
/// worker.
///
/// Why: by default Zenoh runs five tokio runtimes, each with its own reactor. A TCP link is
/// registered with the reactor of the runtime that opened it but read by a task of the rx
/// runtime, so every message costs two thread wake-ups: that reactor's thread, then (by futex)
/// an rx worker (`strace -f`, docs/architecture.md §10). On one runtime the worker that waits in
/// epoll reads the socket itself. A 2-vCPU control or vision PC gains nothing from five
/// runtimes' threads either. Measured with `bowden bench bridge` (Zenoh alone, process to
/// process, 200 Hz, interleaved runs): p50 / p99 ≈ 125–145 / 300 µs by default against
/// ≈ 75 / 165 µs with this layout. Zenoh documents the `handover` setting for this purpose
/// (zenoh-runtime's `ZRuntime`).
pub const ZENOH_RUNTIME_LAYOUT: &str =
    "(app: (worker_threads: 1), acc: (handover: app), tx: (handover: app), rx: (handover: app), net: (handover: app))";

/// Sets `ZENOH_RUNTIME` to [`ZENOH_RUNTIME_LAYOUT`] unless the user set it (theirs wins, even
/// an empty one). Zenoh reads the variable once, when it first starts a runtime, so this must
/// run before any Zenoh call; and since changing the environment is not thread-safe, before the
/// process starts threads (the first line of `main`). Children started afterwards inherit it.
pub fn use_bowden_zenoh_runtime() {
    if std::env::var_os("ZENOH_RUNTIME").is_none() {
        std::env::set_var("ZENOH_RUNTIME", ZENOH_RUNTIME_LAYOUT);
    }
}

/// The Zenoh runtime layout this process runs with (for reports): the variable's value, or
/// Zenoh's own default when unset.
pub fn zenoh_runtime_in_effect() -> String {
    match std::env::var("ZENOH_RUNTIME") {
        Ok(v) if v == ZENOH_RUNTIME_LAYOUT => format!("bowden's single runtime `{v}`"),
        Ok(v) => format!("ZENOH_RUNTIME=`{v}` (set by the user)"),
        Err(_) => "Zenoh's default (five runtimes)".into(),
    }
}

/// The Zenoh publisher of one exported service on `key`: express (sent at once, not batched),
/// and dropping rather than blocking when the network cannot keep up: a bridge must never stall
/// the pipeline it serves (newest data matters most).
pub(crate) fn export_publisher(
    session: &zenoh::Session,
    key: String,
) -> zenoh::Result<zenoh::pubsub::Publisher<'static>> {
    session
        .declare_publisher(key)
        .express(true)
        .congestion_control(zenoh::qos::CongestionControl::Drop)
        .wait()
}

/// A TCP port on 127.0.0.1 free at the time of the call (for loopback links in tests and
/// benches; another process may take it before it is used).
pub fn free_loopback_port() -> std::io::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port())
}

/// iceoryx2's inter-process variant with thread-safe ports (same shared memory as `ipc`).
type Ts = iceoryx2::service::ipc_threadsafe::Service;

/// What Zenoh's threads hand to the stage: peer events, and a wake-up for them.
struct Shared {
    wake: EventFd,
    peers: ArrayQueue<PeerEvent>,
}

/// One imported service, driven by Zenoh's receive thread.
struct ImportSink {
    service: String,
    ty: WireType,
    max_frame: usize,
    port: Mutex<(Box<dyn ImportPort + Send>, Wakeup<Ts>)>,
    published: AtomicU64,
    rejected: AtomicU64,
    /// iceoryx2 refused a publish (counted as faults).
    publish_errors: AtomicU64,
    first_problem: Mutex<Option<String>>,
    stage: String,
}

impl ImportSink {
    /// Checks and republishes one message (runs on a Zenoh thread).
    fn deliver(&self, msg: &[u8]) {
        let body = match wire::decode(self.ty, msg) {
            Ok(b) => b,
            Err(e) => return self.problem(&self.rejected, format!("refused: {e}")),
        };
        let Ok(mut guard) = self.port.lock() else { return };
        let (port, wake) = &mut *guard;
        match port.publish(body, self.max_frame) {
            Ok(Ok(_)) => {
                self.published.fetch_add(1, Ordering::Relaxed);
                let _ = wake.notify();
            }
            Ok(Err(e)) => {
                drop(guard);
                self.problem(&self.rejected, format!("refused: {e}"))
            }
            Err(e) => {
                drop(guard);
                self.problem(&self.publish_errors, format!("not published: {e}"))
            }
        }
    }

    fn problem(&self, counter: &AtomicU64, what: String) {
        let n = counter.fetch_add(1, Ordering::Relaxed);
        let msg = format!("message on `{}` from the peer {what}", self.service);
        // The first few in the log, then only counted (a misconfigured peer sends many).
        if n < 5 {
            eprintln!("[{}] bridge: {msg}", self.stage);
        }
        if let Ok(mut f) = self.first_problem.lock() {
            f.get_or_insert(msg);
        }
    }
}

enum PeerEvent {
    Joined(String),
    Left(String),
}

/// A service read from iceoryx2 and sent to the peer.
trait ExportPort {
    /// Hands every queued sample to `send` as its wire parts, oldest first.
    fn drain(&mut self, send: &mut dyn FnMut(&[&[u8]], &SampleHeader));
}

struct SampleExport<T: Message>(Input<T>);

impl<T: Message> ExportPort for SampleExport<T> {
    fn drain(&mut self, send: &mut dyn FnMut(&[&[u8]], &SampleHeader)) {
        while let Some(v) = self.0.recv() {
            send(&[v.as_bytes()], v.header());
        }
    }
}

struct FrameExport(FrameInput);

impl ExportPort for FrameExport {
    fn drain(&mut self, send: &mut dyn FnMut(&[&[u8]], &SampleHeader)) {
        while let Some(f) = self.0.recv() {
            let h = *f.user_header();
            send(&[h.as_bytes(), f.payload()], &h.header);
        }
    }
}

/// A service received from the peer and published on iceoryx2.
trait ImportPort {
    /// Publishes one checked body; returns its header.
    fn publish(&mut self, body: &[u8], max_frame: usize) -> Result<Result<SampleHeader, WireError>, PortError>;
}

struct SampleImport<T: Message>(Output<T, Ts>);

impl<T: Message> ImportPort for SampleImport<T> {
    fn publish(&mut self, body: &[u8], _: usize) -> Result<Result<SampleHeader, WireError>, PortError> {
        let Some(v) = T::from_bytes(body) else {
            return Ok(Err(WireError::SampleSize {
                actual: body.len(),
                expected: core::mem::size_of::<T>(),
            }));
        };
        self.0.publish_raw(v)?;
        Ok(Ok(*v.header()))
    }
}

struct FrameImport(FrameOutput<Ts>);

impl ImportPort for FrameImport {
    fn publish(&mut self, body: &[u8], max_frame: usize) -> Result<Result<SampleHeader, WireError>, PortError> {
        let (h, payload) = match wire::split_frame(body, max_frame) {
            Ok(x) => x,
            Err(e) => return Ok(Err(e)),
        };
        self.0.publish_raw(&h, payload)?;
        Ok(Ok(h.header))
    }
}

struct Export {
    service: String,
    ty: WireType,
    port: Box<dyn ExportPort>,
    publisher: zenoh::pubsub::Publisher<'static>,
    sent: u64,
    send_errors: u64,
}

struct Import {
    sink: Arc<ImportSink>,
    _subscriber: zenoh::pubsub::Subscriber<()>,
}

/// The bridge as a pipeline stage.
pub struct BridgeStage {
    name: String,
    params: BridgeParams,
    session: Option<zenoh::Session>,
    zid: String,
    shared: Arc<Shared>,
    exports: Vec<Export>,
    imports: Vec<Import>,
    /// The thread-safe iceoryx2 node the imports publish through (kept alive with them).
    _import_ports: PortContext<Ts>,
    _token: Option<zenoh::liveliness::LivelinessToken>,
    _peer_watch: Option<zenoh::pubsub::Subscriber<()>>,
    peers: BTreeSet<String>,
    peers_seen: u64,
    started_ns: u64,
    no_peer_reported: bool,
    faults: u64,
}

fn build_err(env: &StageEnv<'_>, what: &str, e: impl std::fmt::Display) -> StageBuildError {
    env.error(format!(
        "{}: bridge `{}`: {what}: {e}",
        env.pipeline.origin, env.spec.name
    ))
}

/// The `bridge` node kind. Its ports come from its parameters: `export` services are read here
/// (side inputs: they wake it, nothing waits for it — a bridge closes loops between machines),
/// `import` services are published here. It wakes at least every 50 ms to watch its peer, and
/// cannot run in lockstep.
pub const KIND: NodeKind = NodeKind {
    kind: "bridge",
    summary: "forwards chosen services to and from another machine over Zenoh",
    inputs: &[],
    outputs: &[],
    schedule: Schedule {
        wake_timeout_us: Some(50_000),
        ..Schedule::EVENT
    },
    ports_from_params: Some(bridge_ports),
    lockstep_refusal: Some(
        "a bridge joins pipelines that run on different machines, each on its own clock: lockstep cannot span \
         it; run both sides with `mode = \"realtime\"`",
    ),
    build: |env| Ok(Box::new(BridgeStage::from_env(env)?)),
};

/// The services a bridge's `params.export` (iceoryx2 → network) and `params.import`
/// (network → iceoryx2) name (validated: known, not both ways, not the launcher's own).
pub fn bridge_ports(params: &toml::Table) -> Result<ParamPorts, ParamPortsError> {
    let launchers = |s: &str| {
        (s == services::CLOCK || s == services::COMPONENT_STATUS)
            .then_some("belongs to the launcher of each side and is not bridged")
    };
    let export = service_list(params, "export", launchers)?;
    let import = service_list(params, "import", launchers)?;
    if let Some(s) = export.iter().find(|s| import.contains(s)) {
        return Err(ParamPortsError::BothWays { service: s.clone() });
    }
    if export.is_empty() && import.is_empty() {
        return Err(ParamPortsError::Missing {
            what: "a bridge needs `export = [...]` and/or `import = [...]`",
        });
    }
    Ok(ParamPorts {
        inputs: export.into_iter().map(|s| (s, Read::Side)).collect(),
        outputs: import,
    })
}

impl BridgeStage {
    // Long: the bridge's ports, Zenoh session and peer liveliness opened in the order they depend on each other.
    pub fn from_env(env: &StageEnv<'_>) -> Result<Self, StageBuildError> {
        let params: BridgeParams = env.params()?;
        params
            .validate(format_args!(
                "{}: [node.params] of `{}`",
                env.pipeline.origin, env.spec.name
            ))
            .map_err(|e| env.error(e.to_string()))?;
        // The pipeline config validated the service lists (kind `bridge`): imports are this
        // stage's outputs, exports its side inputs.
        let export_services = env.spec.side_inputs.clone();
        let import_services = env.spec.outputs.clone();
        let shared = Arc::new(Shared {
            wake: EventFd::new().map_err(|e| build_err(env, "eventfd", e))?,
            peers: ArrayQueue::new(64),
        });

        let config = params.zenoh_config().map_err(|e| build_err(env, "zenoh config", e))?;
        // Zenoh parses ZENOH_RUNTIME when it first starts a runtime, and panics if it is not
        // valid: report that as this stage's error rather than a crash of the process.
        let session = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| zenoh::open(config).wait()))
            .map_err(|_| {
                build_err(
                    env,
                    "opening the Zenoh session",
                    format!(
                        "Zenoh could not start its runtime: is ZENOH_RUNTIME valid? ({})",
                        zenoh_runtime_in_effect()
                    ),
                )
            })?
            .map_err(|e| build_err(env, "opening the Zenoh session", e))?;
        let zid = session.zid().to_string();

        let mut exports = Vec::new();
        for s in &export_services {
            let ty = WireType::of(s).ok_or_else(|| env.error(format!("cannot bridge service `{s}`")))?;
            let port = visit_payload(s, MakeExport { env, service: s })
                .unwrap_or_else(|| Err(env.error(format!("cannot bridge service `{s}`"))))?;
            let publisher = export_publisher(&session, params.key_of(s))
                .map_err(|e| build_err(env, &format!("declaring the publisher of `{s}`"), e))?;
            exports.push(Export {
                service: s.clone(),
                ty,
                port,
                publisher,
                sent: 0,
                send_errors: 0,
            });
        }

        let import_ports = PortContext::<Ts>::create(&format!("{}-import", env.spec.process), env.ports.settings())?;
        let mut imports = Vec::new();
        for s in &import_services {
            let ty = WireType::of(s).ok_or_else(|| env.error(format!("cannot bridge service `{s}`")))?;
            let make = MakeImport {
                ports: &import_ports,
                service: s,
                max_frame: params.max_frame_bytes,
            };
            let port =
                visit_payload(s, make).unwrap_or_else(|| Err(env.error(format!("cannot bridge service `{s}`"))))?;
            let sink = Arc::new(ImportSink {
                service: s.clone(),
                ty,
                max_frame: params.max_frame_bytes,
                port: Mutex::new((port, import_ports.notifier(s)?)),
                published: AtomicU64::new(0),
                rejected: AtomicU64::new(0),
                publish_errors: AtomicU64::new(0),
                first_problem: Mutex::new(None),
                stage: env.spec.name.clone(),
            });
            let sk = sink.clone();
            let subscriber = session
                .declare_subscriber(params.key_of(s))
                .callback(move |sample| sk.deliver(&sample.payload().to_bytes()))
                .wait()
                .map_err(|e| build_err(env, &format!("declaring the subscriber of `{s}`"), e))?;
            imports.push(Import {
                sink,
                _subscriber: subscriber,
            });
        }

        // Peers: every bridge on this key prefix holds a liveliness token.
        let token = session
            .liveliness()
            .declare_token(params.token_key(&zid))
            .wait()
            .map_err(|e| build_err(env, "declaring the liveliness token", e))?;
        let sh = shared.clone();
        let own = params.token_key(&zid);
        let peer_watch = session
            .liveliness()
            .declare_subscriber(params.tokens_selector())
            .history(true)
            .callback(move |sample| {
                let key = sample.key_expr().as_str().to_string();
                if key == own {
                    return;
                }
                let peer = key.rsplit('/').next().unwrap_or(&key).to_string();
                let ev = match sample.kind() {
                    zenoh::sample::SampleKind::Put => PeerEvent::Joined(peer),
                    zenoh::sample::SampleKind::Delete => PeerEvent::Left(peer),
                };
                let _ = sh.peers.force_push(ev);
                sh.wake.signal();
            })
            .wait()
            .map_err(|e| build_err(env, "watching for peers", e))?;

        Ok(Self {
            name: env.spec.name.clone(),
            params,
            session: Some(session),
            zid,
            shared,
            exports,
            imports,
            _import_ports: import_ports,
            _token: Some(token),
            _peer_watch: Some(peer_watch),
            peers: BTreeSet::new(),
            peers_seen: 0,
            started_ns: monotonic_ns(),
            no_peer_reported: false,
            faults: 0,
        })
    }

    /// This side's Zenoh session id.
    pub fn zid(&self) -> &str {
        &self.zid
    }

    /// Peers currently connected (their Zenoh session ids).
    pub fn peers(&self) -> impl Iterator<Item = &str> {
        self.peers.iter().map(|s| s.as_str())
    }

    fn peer_events(&mut self) {
        while let Some(ev) = self.shared.peers.pop() {
            match ev {
                PeerEvent::Joined(p) => {
                    if self.peers.insert(p.clone()) {
                        self.peers_seen += 1;
                        eprintln!("[{}] bridge: peer {p} connected", self.name);
                    }
                }
                PeerEvent::Left(p) => {
                    if self.peers.remove(&p) {
                        self.faults += 1;
                        let stops: Vec<&str> = self.imports.iter().map(|i| i.sink.service.as_str()).collect();
                        eprintln!(
                            "[{}] bridge: fault: peer {p} lost (its process ended, or nothing arrived for {} ms); \
                             {} until a peer is back",
                            self.name,
                            self.params.lease_ms,
                            if stops.is_empty() {
                                "exports go nowhere".to_string()
                            } else {
                                format!("no more {}", stops.join(", "))
                            }
                        );
                    }
                }
            }
        }
    }
}

/// The export port of a service: samples or frames, read on iceoryx2.
struct MakeExport<'a, 'e> {
    env: &'a StageEnv<'e>,
    service: &'a str,
}

impl PayloadVisitor for MakeExport<'_, '_> {
    type Output = Result<Box<dyn ExportPort>, StageBuildError>;
    fn sample<T: Message>(self) -> Self::Output {
        Ok(Box::new(SampleExport::<T>(
            self.env.ports.input::<T>(self.service, 64)?,
        )))
    }
    fn frame(self) -> Self::Output {
        Ok(Box::new(FrameExport(self.env.ports.frame_input(self.service, 4)?)))
    }
}

/// The import port of a service, published through the thread-safe node.
struct MakeImport<'a> {
    ports: &'a PortContext<Ts>,
    service: &'a str,
    max_frame: usize,
}

impl PayloadVisitor for MakeImport<'_> {
    type Output = Result<Box<dyn ImportPort + Send>, StageBuildError>;
    fn sample<T: Message>(self) -> Self::Output {
        Ok(Box::new(SampleImport::<T>(self.ports.output::<T>(self.service)?)))
    }
    fn frame(self) -> Self::Output {
        Ok(Box::new(FrameImport(
            self.ports.frame_output(self.service, self.max_frame)?,
        )))
    }
}

impl Stage for BridgeStage {
    fn step(&mut self, _cx: &StepCx) -> Result<StepReport, StageError> {
        self.shared.wake.drain();
        self.peer_events();
        let mut rep = StepReport::IDLE;

        // iceoryx2 → network.
        let mut send_faults = 0;
        for exp in self.exports.iter_mut() {
            let (ty, publisher) = (exp.ty, &exp.publisher);
            let (mut sent, mut errors, mut origin) = (0u64, 0u64, rep.t_origin_ns);
            exp.port
                .drain(&mut |parts, h| match publisher.put(wire::encode(ty, parts)).wait() {
                    Ok(()) => {
                        sent += 1;
                        origin = Some(origin.map_or(h.t_origin_ns, |t| t.max(h.t_origin_ns)));
                    }
                    Err(_) => errors += 1,
                });
            // The executor records "handed to the network" minus the sample's origin.
            rep.t_origin_ns = origin;
            exp.sent += sent;
            exp.send_errors += errors;
            send_faults += errors;
            rep.active |= sent > 0;
        }
        self.faults += send_faults;

        if self.peers_seen == 0
            && !self.no_peer_reported
            && monotonic_ns().saturating_sub(self.started_ns) > self.params.peer_timeout_ms * 1_000_000
        {
            self.no_peer_reported = true;
            self.faults += 1;
            eprintln!(
                "[{}] bridge: fault: no peer after {} ms (listen {:?}, connect {:?}, key prefix `{}`): \
                 is the other side running with matching endpoints and key prefix?",
                self.name, self.params.peer_timeout_ms, self.params.listen, self.params.connect, self.params.key_prefix
            );
        }
        Ok(rep)
    }

    fn counters(&self) -> StageCounters {
        let sum = |f: fn(&ImportSink) -> &AtomicU64| -> u64 {
            self.imports.iter().map(|i| f(&i.sink).load(Ordering::Relaxed)).sum()
        };
        StageCounters {
            rejected: sum(|s| &s.rejected),
            faults: self.faults + sum(|s| &s.publish_errors),
            degraded: self.peers.is_empty(),
            ..Default::default()
        }
    }

    fn wake_fd(&self) -> Option<std::os::fd::RawFd> {
        Some(self.shared.wake.fd())
    }

    fn finish(&mut self) -> Result<(), StageError> {
        // Withdraw the token first so the peer sees this side leave at once.
        self._token.take();
        self._peer_watch.take();
        if let Some(s) = self.session.take() {
            let _ = s.close().wait();
        }
        Ok(())
    }

    fn summary(&self) -> Vec<String> {
        let c = self.counters();
        let mut v = vec![format!(
            "{}: bridge {} (key prefix `{}`): {} peer(s) now, {} seen; {} refused, {} fault(s)",
            self.name,
            self.zid,
            self.params.key_prefix,
            self.peers.len(),
            self.peers_seen,
            c.rejected,
            c.faults
        )];
        for e in &self.exports {
            v.push(format!(
                "{}: exported `{}`: {} sent, {} send errors",
                self.name, e.service, e.sent, e.send_errors
            ));
        }
        for i in &self.imports {
            let s = &i.sink;
            v.push(format!(
                "{}: imported `{}`: {} published, {} refused, {} publish errors",
                self.name,
                s.service,
                s.published.load(Ordering::Relaxed),
                s.rejected.load(Ordering::Relaxed),
                s.publish_errors.load(Ordering::Relaxed)
            ));
            if let Some(p) = s.first_problem.lock().ok().and_then(|f| f.clone()) {
                v.push(format!("{}: first problem: {p}", self.name));
            }
        }
        v
    }
}
