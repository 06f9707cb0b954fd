//! Typed iceoryx2 ports for bowden's samples: one place that fixes every service's QoS (so all
//! processes open a service with the same settings), a per-deployment shared-memory prefix and
//! service namespace, and small wrappers that stamp the [`SampleHeader`] and count what they see.
//!
//! Every wrapper is generic over the iceoryx2 service variant: processes use [`Ipc`] (shared
//! memory, zero copy between processes); unit tests may use `iceoryx2::service::local::Service`,
//! which creates nothing in /dev/shm.
//!
//! Allocation: `receive`, `notify` and listener draining allocate nothing. Publishing goes through
//! `Publisher::loan_uninit`, which in iceoryx2 0.10 allocates one 48-byte `Rc` per sample (upstream
//! issue #101). In a `bowden` process that allocation is served by [`crate::alloc::RtAlloc`]'s
//! pre-faulted pool (no system allocator call); the allocation test counts it per cycle.

use bowden_interfaces::{
    ClockTick, ComponentStatus, JointCommand, JointEstimate, JointTarget, MarkerSet, ModelUpdate, MotorCommand,
    PlantState, RgbdFrameHeader, SafetyCommand, SampleHeader,
};
use iceoryx2::node::{Node, NodeBuilder};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::{
    AllocationStrategy, Config, FileDescriptorBased, FileName, NodeName, SemanticString, ServiceName,
    SignalHandlingMode, ZeroCopySend,
};
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::Service;
use std::fmt::Debug;
use std::os::fd::RawFd;

use crate::node::Read;
use crate::stage::StepCx;

/// The inter-process service variant every bowden process uses.
pub type Ipc = iceoryx2::service::ipc::Service;

/// A bowden sample type: `#[repr(C)]`, plain data without padding (checked by the layout
/// assertions in `bowden-interfaces`), starting with a [`SampleHeader`].
///
/// # Safety
/// Implementors guarantee that every bit pattern is a valid value and that the type has no
/// padding bytes, so a value may be viewed as and rebuilt from `size_of::<Self>()` bytes.
pub unsafe trait Message: Copy + Default + Debug + ZeroCopySend + 'static {
    /// The iceoryx2 type name (`#[type_name]` of the interfaces type).
    const TYPE_NAME: &'static str;
    fn header(&self) -> &SampleHeader;
    fn header_mut(&mut self) -> &mut SampleHeader;

    /// The value's bytes (little-endian, the exact shared-memory layout).
    fn as_bytes(&self) -> &[u8] {
        // SAFETY: no padding (trait contract), so every byte is initialised.
        unsafe { core::slice::from_raw_parts(self as *const Self as *const u8, core::mem::size_of::<Self>()) }
    }

    /// Rebuilds a value from exactly `size_of::<Self>()` bytes; `None` on a length mismatch.
    fn from_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != core::mem::size_of::<Self>() {
            return None;
        }
        // SAFETY: length checked; any bit pattern is valid (trait contract); unaligned read.
        Some(unsafe { core::ptr::read_unaligned(bytes.as_ptr() as *const Self) })
    }
}

macro_rules! impl_message {
    ($($t:ty => $name:literal),* $(,)?) => {$(
        // SAFETY: all fields are u32/u64/f64 (arrays), sizes asserted in bowden-interfaces to have
        // no padding; every bit pattern of those is valid.
        unsafe impl Message for $t {
            const TYPE_NAME: &'static str = $name;
            #[inline]
            fn header(&self) -> &SampleHeader { &self.header }
            #[inline]
            fn header_mut(&mut self) -> &mut SampleHeader { &mut self.header }
        }
    )*};
}

impl_message! {
    JointTarget => "bowden::JointTarget",
    JointCommand => "bowden::JointCommand",
    MotorCommand => "bowden::MotorCommand",
    PlantState => "bowden::PlantState",
    RgbdFrameHeader => "bowden::RgbdFrameHeader",
    MarkerSet => "bowden::MarkerSet",
    JointEstimate => "bowden::JointEstimate",
    ComponentStatus => "bowden::ComponentStatus",
    SafetyCommand => "bowden::SafetyCommand",
    ClockTick => "bowden::ClockTick",
    ModelUpdate => "bowden::ModelUpdate",
}

/// Something done with the payload type of a service, for code that handles services by name
/// (recorder, replay, bridge): [`visit_payload`] is the one place names map to types.
pub trait PayloadVisitor {
    type Output;
    /// `service` carries fixed-size samples of type `T`.
    fn sample<T: Message>(self) -> Self::Output;
    /// `service` carries RGBD frames (`[u8]` with an `RgbdFrameHeader`).
    fn frame(self) -> Self::Output;
}

/// Calls `v` with the payload type of `service` (a full bowden service name, without
/// namespace); `None` if it is not one.
pub fn visit_payload<V: PayloadVisitor>(service: &str, v: V) -> Option<V::Output> {
    use bowden_interfaces::services as s;
    Some(match service {
        s::JOINT_TARGET => v.sample::<JointTarget>(),
        s::JOINT_COMMAND => v.sample::<JointCommand>(),
        s::MOTOR_COMMAND => v.sample::<MotorCommand>(),
        s::PLANT_STATE => v.sample::<PlantState>(),
        s::MARKER_SET => v.sample::<MarkerSet>(),
        s::JOINT_ESTIMATE => v.sample::<JointEstimate>(),
        s::COMPONENT_STATUS => v.sample::<ComponentStatus>(),
        s::SAFETY => v.sample::<SafetyCommand>(),
        s::CLOCK => v.sample::<ClockTick>(),
        s::MODEL_UPDATE => v.sample::<ModelUpdate>(),
        s::RGBD_FRAME => v.frame(),
        _ => return None,
    })
}

/// Is `service` one of the sample services (a full name without namespace, `bowden/...`)?
pub fn is_service(service: &str) -> bool {
    bowden_interfaces::services::ALL.contains(&service)
}

/// Every sample service, for error messages.
pub fn known_services() -> &'static [&'static str] {
    &bowden_interfaces::services::ALL
}

/// Something went wrong with an iceoryx2 port; names the service.
#[derive(Debug, thiserror::Error)]
pub enum PortError {
    #[error("iceoryx2 node `{node}` (prefix `{prefix}`): {message}")]
    Node {
        node: String,
        prefix: String,
        message: String,
    },
    #[error("service `{service}`: {message}")]
    Service { service: String, message: String },
    #[error("service `{service}`: cannot create {port}: {message}")]
    Port {
        service: String,
        port: &'static str,
        message: String,
    },
    #[error("service `{service}`: {op} failed: {message}")]
    Io {
        service: String,
        op: &'static str,
        message: String,
    },
    #[error("service `{service}`: frame of {len} bytes exceeds the {max} bytes the port was created for")]
    FrameTooLarge { service: String, len: usize, max: usize },
}

/// Quality of service of one bowden service. All processes derive it from the service name with
/// [`qos_for`], so opening never fails on mismatched settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    pub max_publishers: usize,
    pub max_subscribers: usize,
    /// Service-wide upper bound of a subscriber's queue.
    pub max_buffer: usize,
    pub history: usize,
    /// Newest sample wins when a subscriber's queue is full (control streams), instead of
    /// refusing to deliver.
    pub safe_overflow: bool,
    pub max_nodes: usize,
    pub max_borrowed: usize,
}

/// Suffix of a service's base name (without namespace), e.g. `joint_target`.
fn base_name(service: &str) -> &str {
    service.rsplit('/').next().unwrap_or(service)
}

/// The QoS of a service, by its base name.
pub fn qos_for(service: &str) -> Qos {
    let base = base_name(service);
    let mut q = Qos {
        // One live producer per data stream: a second one is a configuration error (two
        // trajectories, two plants) and a dead one must be cleaned before a restart.
        max_publishers: 1,
        max_subscribers: 8,
        max_buffer: 64,
        history: 0,
        safe_overflow: true,
        max_nodes: 24,
        max_borrowed: 2,
    };
    match base {
        "component_status" => {
            q.max_publishers = 24;
            q.max_subscribers = 24;
            q.max_buffer = 256;
        }
        "safety" => q.max_publishers = 4,
        // Frames are large: keep the number of chunks a publisher must provision small.
        "rgbd_frame" => {
            q.max_subscribers = 4;
            q.max_buffer = 4;
        }
        _ => {}
    }
    q
}

/// How a process reaches iceoryx2: shared-memory prefix and service namespace.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct IpcSettings {
    /// `config.global.prefix` of iceoryx2: isolates deployments (and tests) sharing a machine.
    pub prefix: String,
    /// Prepended to every service name (`<namespace>/bowden/...`); empty for none.
    pub namespace: String,
}

impl Default for IpcSettings {
    fn default() -> Self {
        Self {
            prefix: "bowden_".into(),
            namespace: String::new(),
        }
    }
}

impl IpcSettings {
    /// The iceoryx2 config for these settings.
    pub fn iox_config(&self) -> Result<Config, PortError> {
        let mut cfg = Config::default();
        // Dead nodes are cleaned by the launcher (at start and when a child dies), not by every
        // process as it exits: that raced with siblings shutting down at the same moment.
        cfg.global.node.cleanup_dead_nodes_on_destruction = false;
        cfg.global.prefix = FileName::new(self.prefix.as_bytes()).map_err(|e| PortError::Node {
            node: String::new(),
            prefix: self.prefix.clone(),
            message: format!("invalid shared-memory prefix: {e:?}"),
        })?;
        Ok(cfg)
    }

    /// The full service name of `name` under the namespace.
    pub fn service_name(&self, name: &str) -> String {
        bowden_interfaces::services::qualified(&self.namespace, name)
    }
}

fn svc_err(service: &str, e: impl Debug) -> PortError {
    PortError::Service {
        service: service.to_string(),
        message: format!("{e:?}"),
    }
}

fn port_err(service: &str, port: &'static str, e: impl Debug) -> PortError {
    PortError::Port {
        service: service.to_string(),
        port,
        message: format!("{e:?}"),
    }
}

fn io_err(service: &str, op: &'static str, e: impl Debug) -> PortError {
    PortError::Io {
        service: service.to_string(),
        op,
        message: format!("{e:?}"),
    }
}

/// iceoryx2 logs warnings to stderr on its own (e.g. about its config file); bowden reports
/// every failure through its typed errors instead. `IOX2_LOG_LEVEL` still overrides.
pub fn quiet_iceoryx2_log() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error));
}

/// The RGBD frame service: a `[u8]` payload with an [`RgbdFrameHeader`].
type FrameService<S> = iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, [u8], RgbdFrameHeader>;

/// One iceoryx2 node of a process and the factory of its ports.
pub struct PortContext<S: Service = Ipc> {
    node: Node<S>,
    settings: IpcSettings,
}

impl PortContext<Ipc> {
    /// Creates the inter-process iceoryx2 node `node_name` (what every bowden process uses).
    pub fn new(node_name: &str, settings: &IpcSettings) -> Result<Self, PortError> {
        quiet_iceoryx2_log();
        Self::create(node_name, settings)
    }
}

impl<S: Service> PortContext<S> {
    /// Creates the iceoryx2 node `node_name` of service variant `S`. Signal handling is left to
    /// [`crate::sys`].
    pub fn create(node_name: &str, settings: &IpcSettings) -> Result<Self, PortError> {
        let cfg = settings.iox_config()?;
        let node_err = |message: String| PortError::Node {
            node: node_name.to_string(),
            prefix: settings.prefix.clone(),
            message,
        };
        let name = NodeName::new(node_name).map_err(|e| node_err(format!("invalid node name: {e:?}")))?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(&cfg)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<S>()
            .map_err(|e| node_err(format!("cannot create node: {e:?}")))?;
        Ok(Self {
            node,
            settings: settings.clone(),
        })
    }

    pub fn settings(&self) -> &IpcSettings {
        &self.settings
    }

    pub fn node(&self) -> &Node<S> {
        &self.node
    }

    fn service_name(&self, name: &str) -> Result<(String, ServiceName), PortError> {
        let full = self.settings.service_name(name);
        let sn = ServiceName::new(&full).map_err(|e| svc_err(&full, format!("invalid service name: {e:?}")))?;
        Ok((full, sn))
    }

    fn pubsub<T: Message>(
        &self,
        name: &str,
    ) -> Result<
        (
            String,
            iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, T, ()>,
        ),
        PortError,
    > {
        let (full, sn) = self.service_name(name)?;
        let q = qos_for(name);
        let f = self
            .node
            .service_builder(&sn)
            .publish_subscribe::<T>()
            .max_publishers(q.max_publishers)
            .max_subscribers(q.max_subscribers)
            .subscriber_max_buffer_size(q.max_buffer)
            .subscriber_max_borrowed_samples(q.max_borrowed)
            .history_size(q.history)
            .enable_safe_overflow(q.safe_overflow)
            .max_nodes(q.max_nodes)
            .open_or_create()
            .map_err(|e| svc_err(&full, e))?;
        Ok((full, f))
    }

    fn event(&self, name: &str) -> Result<(String, iceoryx2::service::port_factory::event::PortFactory<S>), PortError> {
        let (full, sn) = self.service_name(name)?;
        let f = self
            .node
            .service_builder(&sn)
            .event()
            .max_notifiers(32)
            .max_listeners(32)
            .max_nodes(32)
            .open_or_create()
            .map_err(|e| svc_err(&full, e))?;
        Ok((full, f))
    }

    /// A publisher of `T` on service `name` (namespace applied).
    pub fn output<T: Message>(&self, name: &str) -> Result<Output<T, S>, PortError> {
        let (full, f) = self.pubsub::<T>(name)?;
        let publisher = f
            .publisher_builder()
            .max_loaned_samples(2)
            .create()
            .map_err(|e| port_err(&full, "publisher", e))?;
        Ok(Output {
            publisher,
            service: full,
            seq: 0,
            sent: 0,
        })
    }

    /// A subscriber of `T` on service `name` with a queue of `buffer` samples.
    pub fn input<T: Message>(&self, name: &str, buffer: usize) -> Result<Input<T, S>, PortError> {
        let (full, f) = self.pubsub::<T>(name)?;
        let buffer = buffer.clamp(1, qos_for(name).max_buffer);
        let subscriber = f
            .subscriber_builder()
            .buffer_size(buffer)
            .create()
            .map_err(|e| port_err(&full, "subscriber", e))?;
        Ok(Input {
            subscriber,
            factory: f,
            service: full,
            pending: None,
            stats: InputStats::default(),
            read: Read::Tick,
        })
    }

    /// Opens (or creates) the RGBD frame service `name` with its QoS: shared by both ends so
    /// publisher and subscriber always agree on the service's settings.
    fn frame_service(&self, name: &str) -> Result<(String, FrameService<S>), PortError> {
        let (full, sn) = self.service_name(name)?;
        let q = qos_for(name);
        let f = self
            .node
            .service_builder(&sn)
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
            .map_err(|e| svc_err(&full, e))?;
        Ok((full, f))
    }

    /// A publisher of RGBD frames (`[u8]` payload + [`RgbdFrameHeader`]), able to send frames of
    /// up to `max_len` bytes without reallocating shared memory.
    pub fn frame_output(&self, name: &str, max_len: usize) -> Result<FrameOutput<S>, PortError> {
        let (full, f) = self.frame_service(name)?;
        let publisher = f
            .publisher_builder()
            .initial_max_slice_len(max_len)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .create()
            .map_err(|e| port_err(&full, "frame publisher", e))?;
        Ok(FrameOutput {
            publisher,
            service: full,
            max_len,
            seq: 0,
        })
    }

    /// A subscriber of RGBD frames.
    pub fn frame_input(&self, name: &str, buffer: usize) -> Result<FrameInput<S>, PortError> {
        let (full, f) = self.frame_service(name)?;
        let q = qos_for(name);
        let subscriber = f
            .subscriber_builder()
            .buffer_size(buffer.clamp(1, q.max_buffer))
            .create()
            .map_err(|e| port_err(&full, "frame subscriber", e))?;
        Ok(FrameInput {
            subscriber,
            service: full,
            pending: None,
            stats: InputStats::default(),
        })
    }

    /// A notifier on the event service that accompanies data service `name`.
    pub fn notifier(&self, name: &str) -> Result<Wakeup<S>, PortError> {
        let (full, f) = self.event(name)?;
        let notifier = f
            .notifier_builder()
            .create()
            .map_err(|e| port_err(&full, "notifier", e))?;
        Ok(Wakeup {
            notifier,
            service: full,
        })
    }

    /// A listener on the event service that accompanies data service `name`.
    pub fn listener(&self, name: &str) -> Result<Waiter<S>, PortError> {
        let (full, f) = self.event(name)?;
        let listener = f
            .listener_builder()
            .create()
            .map_err(|e| port_err(&full, "listener", e))?;
        Ok(Waiter {
            listener,
            service: full,
        })
    }
}

/// Publisher of one sample type; stamps `seq` (per publisher, from 0), `tick` and `t_origin_ns`.
pub struct Output<T: Message, S: Service = Ipc> {
    publisher: Publisher<S, T, ()>,
    service: String,
    seq: u64,
    sent: u64,
}

impl<T: Message, S: Service> Output<T, S> {
    /// Publishes `value` with a fresh header. Returns the number of subscribers reached.
    pub fn publish(&mut self, tick: u64, t_origin_ns: u64, mut value: T) -> Result<usize, PortError> {
        *value.header_mut() = SampleHeader {
            seq: self.seq,
            tick,
            t_origin_ns,
        };
        self.publish_raw(value)
    }

    /// Publishes `value` with its header as given (replay keeps recorded headers).
    pub fn publish_raw(&mut self, value: T) -> Result<usize, PortError> {
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| io_err(&self.service, "loan", e))?;
        let n = sample
            .write_payload(value)
            .send()
            .map_err(|e| io_err(&self.service, "send", e))?;
        self.seq += 1;
        self.sent += 1;
        Ok(n)
    }

    pub fn service(&self) -> &str {
        &self.service
    }

    /// Samples sent so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }

    /// Connects subscribers created since the last send (a send does this too).
    pub fn update_connections(&self) -> Result<(), PortError> {
        use iceoryx2::port::update_connections::UpdateConnections;
        self.publisher
            .update_connections()
            .map_err(|e| io_err(&self.service, "update connections", e))
    }
}

/// Counters of an input port.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct InputStats {
    /// Samples taken from the queue.
    pub received: u64,
    /// Samples skipped because a newer one was there (real-time) or their tick had passed (lockstep).
    pub skipped: u64,
    /// Receive errors (corrupted or broken connection).
    pub errors: u64,
}

/// Subscriber of one sample type, copying samples out (they are small) so no loan is held.
pub struct Input<T: Message, S: Service = Ipc> {
    subscriber: Subscriber<S, T, ()>,
    factory: iceoryx2::service::port_factory::publish_subscribe::PortFactory<S, T, ()>,
    service: String,
    /// A sample of a later tick, kept for its tick (lockstep).
    pending: Option<T>,
    stats: InputStats,
    read: Read,
}

impl<T: Message, S: Service> Input<T, S> {
    /// The same port read with `read` (the default is [`Read::Tick`]).
    pub fn with_read(mut self, read: Read) -> Self {
        self.read = read;
        self
    }

    /// The next sample by the port's declared [`Read`] policy in the activation `cx`:
    /// - [`Read::Tick`], [`Read::Hint`]: lockstep, the sample of this tick (older ones skipped
    ///   and counted, a later one kept for its tick); real time, the newest (older ones skipped).
    ///   At most one per activation.
    /// - [`Read::Feedback`]: the next sample of an earlier tick, oldest first (lockstep: samples
    ///   of this tick or later stay queued, so the result does not depend on which process ran
    ///   first); real time, the next that arrived.
    /// - [`Read::Side`]: the next that arrived, in both modes.
    #[inline]
    pub fn next(&mut self, cx: &StepCx) -> Option<T> {
        match (self.read, cx.reproducible()) {
            (Read::Tick | Read::Hint, true) => self.take_tick(cx.tick()),
            (Read::Tick | Read::Hint, false) => self.latest(),
            (Read::Feedback, true) => self.next_upto(cx.tick().saturating_sub(1)),
            (Read::Feedback, false) | (Read::Side, _) => self.recv(),
        }
    }

    fn pop(&mut self) -> Option<T> {
        if let Some(p) = self.pending.take() {
            return Some(p);
        }
        match self.subscriber.receive() {
            Ok(Some(s)) => {
                self.stats.received += 1;
                Some(*s.payload())
            }
            Ok(None) => None,
            Err(_) => {
                self.stats.errors += 1;
                None
            }
        }
    }

    /// The next sample in arrival order.
    pub fn recv(&mut self) -> Option<T> {
        self.pop()
    }

    /// The newest sample, skipping (and counting) older ones.
    pub fn latest(&mut self) -> Option<T> {
        let mut last = None;
        while let Some(s) = self.pop() {
            if last.is_some() {
                self.stats.skipped += 1;
            }
            last = Some(s);
        }
        last
    }

    /// The sample of tick `tick`: older ticks are skipped (counted), a later one is kept for its
    /// own tick.
    pub fn take_tick(&mut self, tick: u64) -> Option<T> {
        while let Some(s) = self.pop() {
            let t = s.header().tick;
            if t == tick {
                return Some(s);
            }
            if t > tick {
                self.pending = Some(s);
                return None;
            }
            self.stats.skipped += 1;
        }
        None
    }

    /// The next sample if its tick is at most `tick` (a later one is kept).
    pub fn next_upto(&mut self, tick: u64) -> Option<T> {
        let s = self.pop()?;
        if s.header().tick > tick {
            self.pending = Some(s);
            return None;
        }
        Some(s)
    }

    /// Live publishers of the service (a dead one counts until its resources are cleaned).
    pub fn publisher_count(&self) -> usize {
        self.factory.dynamic_config().number_of_publishers()
    }

    pub fn stats(&self) -> InputStats {
        self.stats
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// Publisher of RGBD frames: the frame is rendered straight into the loaned shared memory.
pub struct FrameOutput<S: Service = Ipc> {
    publisher: Publisher<S, [u8], RgbdFrameHeader>,
    service: String,
    max_len: usize,
    seq: u64,
}

impl<S: Service> FrameOutput<S> {
    /// Loans `len` bytes (not cleared: `fill` must write all it sends), lets `fill` write the
    /// header fields and the payload in place,
    /// stamps the header and sends. `fill` returning an error drops the loan (nothing is sent).
    pub fn publish_with<E>(
        &mut self,
        tick: u64,
        t_origin_ns: u64,
        len: usize,
        fill: impl FnOnce(&mut RgbdFrameHeader, &mut [u8]) -> Result<(), E>,
    ) -> Result<Result<usize, E>, PortError> {
        let stamp = SampleHeader {
            seq: self.seq,
            tick,
            t_origin_ns,
        };
        self.send_frame(len, Some(stamp), fill)
    }

    /// Sends a frame with the given header (kept as recorded) and payload (replay).
    pub fn publish_raw(&mut self, header: &RgbdFrameHeader, payload: &[u8]) -> Result<usize, PortError> {
        let r = self.send_frame::<()>(payload.len(), None, |h, buf| {
            *h = *header;
            buf.copy_from_slice(payload);
            Ok(())
        })?;
        Ok(r.unwrap_or(0))
    }

    fn send_frame<E>(
        &mut self,
        len: usize,
        stamp: Option<SampleHeader>,
        fill: impl FnOnce(&mut RgbdFrameHeader, &mut [u8]) -> Result<(), E>,
    ) -> Result<Result<usize, E>, PortError> {
        if len > self.max_len {
            return Err(PortError::FrameTooLarge {
                service: self.service.clone(),
                len,
                max: self.max_len,
            });
        }
        let sample = self
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| io_err(&self.service, "loan frame", e))?;
        // SAFETY: `u8` has no invalid bit patterns, and the chunk lies in a shared-memory mapping
        // whose bytes are always initialised at the OS level (zero-filled by the kernel when
        // mapped, or written by earlier samples). Not zero-filling keeps a frame hop
        // independent of the frame size: the producer writes every byte it sends.
        let mut sample = unsafe { sample.assume_init() };
        let mut header = RgbdFrameHeader::default();
        if let Err(e) = fill(&mut header, sample.payload_mut()) {
            return Ok(Err(e));
        }
        if let Some(stamp) = stamp {
            header.header = stamp;
        }
        header.payload_len = len as u64;
        *sample.user_header_mut() = header;
        let n = sample.send().map_err(|e| io_err(&self.service, "send frame", e))?;
        self.seq += 1;
        Ok(Ok(n))
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// A received frame, borrowed from shared memory (zero copy) until dropped.
pub type Frame<S = Ipc> = Sample<S, [u8], RgbdFrameHeader>;

/// Subscriber of RGBD frames; frames stay in shared memory.
pub struct FrameInput<S: Service = Ipc> {
    subscriber: Subscriber<S, [u8], RgbdFrameHeader>,
    service: String,
    pending: Option<Frame<S>>,
    stats: InputStats,
}

impl<S: Service> FrameInput<S> {
    fn pop(&mut self) -> Option<Frame<S>> {
        if let Some(p) = self.pending.take() {
            return Some(p);
        }
        match self.subscriber.receive() {
            Ok(Some(s)) => {
                self.stats.received += 1;
                Some(s)
            }
            Ok(None) => None,
            Err(_) => {
                self.stats.errors += 1;
                None
            }
        }
    }

    /// The next frame in arrival order.
    pub fn recv(&mut self) -> Option<Frame<S>> {
        self.pop()
    }

    /// The newest frame; older ones are released (counted as skipped).
    pub fn latest(&mut self) -> Option<Frame<S>> {
        let mut last = None;
        while let Some(s) = self.pop() {
            if last.is_some() {
                self.stats.skipped += 1;
            }
            last = Some(s);
        }
        last
    }

    /// The frame of `tick` (lockstep), as [`Input::take_tick`].
    pub fn take_tick(&mut self, tick: u64) -> Option<Frame<S>> {
        while let Some(s) = self.pop() {
            let t = s.user_header().header.tick;
            if t == tick {
                return Some(s);
            }
            if t > tick {
                self.pending = Some(s);
                return None;
            }
            self.stats.skipped += 1;
        }
        None
    }

    /// The next frame if its tick is at most `tick` (a later one is kept).
    pub fn next_upto(&mut self, tick: u64) -> Option<Frame<S>> {
        let s = self.pop()?;
        if s.user_header().header.tick > tick {
            self.pending = Some(s);
            return None;
        }
        Some(s)
    }

    /// The frame of this activation: lockstep, the frame of this tick; real time, the newest
    /// (a frame is always a [`Read::Tick`] input).
    pub fn next(&mut self, cx: &StepCx) -> Option<Frame<S>> {
        if cx.reproducible() {
            self.take_tick(cx.tick())
        } else {
            self.latest()
        }
    }

    pub fn stats(&self) -> InputStats {
        self.stats
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// Notifier half of a service's wake-up channel.
pub struct Wakeup<S: Service = Ipc> {
    notifier: Notifier<S>,
    service: String,
}

impl<S: Service> Wakeup<S> {
    /// Wakes every listener of the service. Returns how many were reached.
    pub fn notify(&self) -> Result<usize, PortError> {
        self.notifier.notify().map_err(|e| io_err(&self.service, "notify", e))
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}

/// Listener half of a service's wake-up channel, for a [`crate::sys::Reactor`].
pub struct Waiter<S: Service = Ipc> {
    listener: Listener<S>,
    service: String,
}

impl<S: Service> Waiter<S>
where
    Listener<S>: FileDescriptorBased,
{
    /// The file descriptor that becomes readable on a notification.
    pub fn fd(&self) -> RawFd {
        // SAFETY: the fd stays owned by the listener, which outlives every use by the reactor
        // (both live in the same executor).
        unsafe { self.listener.file_descriptor().native_handle() }
    }
}

impl<S: Service> Waiter<S> {
    /// Consumes pending notifications (or the reactor wakes again at once). Returns how many.
    pub fn drain(&self) -> u64 {
        self.listener.try_wait(|_| {}).unwrap_or(0)
    }

    /// Blocks until a notification arrives or `timeout` passes.
    pub fn wait(&self, timeout: core::time::Duration) -> u64 {
        self.listener.timed_wait(|_| {}, timeout).unwrap_or(0)
    }

    pub fn service(&self) -> &str {
        &self.service
    }
}
