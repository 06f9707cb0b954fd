"""iceoryx2 ports for bowden's samples, opened exactly as the Rust processes open them
(``bowden_runtime::ports``): same shared-memory prefix, service names under the same namespace,
same QoS, same payload type names.

>>> settings = Settings.from_env()              # what `bowden run` passes to an `exec` node
>>> with Ports("plant", settings) as ports:
...     commands = ports.input(services.MOTOR_COMMAND, layout.MotorCommand, buffer=4)
...     states = ports.output(services.PLANT_STATE, layout.PlantState)
...     cmd = commands.latest()                    # a copy; the shared-memory sample is released
...     states.publish(layout.PlantState(n_joints=5), tick=0, t_origin_ns=time.monotonic_ns())
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import os
from dataclasses import dataclass, replace
from typing import Generic, Optional, Type, TypeVar

import iceoryx2 as iox2

from . import layout, services

T = TypeVar("T", bound=ctypes.Structure)


@dataclass(frozen=True)
class Settings:
    """How a process reaches a bowden run. ``bowden run`` gives an ``exec`` node these in its
    environment: ``BOWDEN_PREFIX``, ``BOWDEN_NAMESPACE``, ``BOWDEN_MODE``, ``BOWDEN_PERIOD_US``,
    ``BOWDEN_NODE``, ``BOWDEN_CONFIG``."""

    #: iceoryx2 ``config.global.prefix``: isolates deployments (and test runs) on one machine.
    prefix: str = "bowden_"
    #: Prepended to every service name (``<namespace>/bowden/...``); empty for none.
    namespace: str = ""
    #: ``"realtime"`` or ``"lockstep"``.
    mode: str = "realtime"
    #: Control period (lockstep: simulated step), µs.
    period_us: int = 1000
    #: Stage name (status samples, upstream bookkeeping).
    node: str = ""
    #: Pipeline file the run was started with (``@sim``: the embedded default).
    config: Optional[str] = None

    @classmethod
    def from_env(cls, default_node: str = "", **overrides) -> "Settings":
        """Settings from the environment ``bowden run`` sets, then ``overrides`` (those not None).
        ``default_node`` names the stage when ``BOWDEN_NODE`` is not set."""
        env = os.environ
        s = cls(
            prefix=env.get("BOWDEN_PREFIX") or "bowden_",
            namespace=env.get("BOWDEN_NAMESPACE", ""),
            mode=env.get("BOWDEN_MODE") or "realtime",
            period_us=int(env.get("BOWDEN_PERIOD_US") or 1000),
            node=env.get("BOWDEN_NODE") or default_node,
            config=env.get("BOWDEN_CONFIG") or None,
        )
        s = replace(s, **{k: v for k, v in overrides.items() if v is not None})
        if s.mode not in ("realtime", "lockstep"):
            raise ValueError(f"mode `{s.mode}`: expected realtime or lockstep")
        return s

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        """``--prefix``, ``--namespace``, ``--mode``, ``--period-us``, ``--name``: override the
        environment (for running a client by hand against a `bowden run`)."""
        g = parser.add_argument_group("bowden run settings (default: from the environment bowden run sets)")
        g.add_argument("--prefix", help="iceoryx2 shared-memory prefix (BOWDEN_PREFIX, default bowden_)")
        g.add_argument("--namespace", help="service namespace (BOWDEN_NAMESPACE)")
        g.add_argument("--mode", choices=["realtime", "lockstep"], help="scheduling mode (BOWDEN_MODE)")
        g.add_argument("--period-us", type=int, help="control period in µs (BOWDEN_PERIOD_US, default 1000)")
        g.add_argument("--name", help="stage name (BOWDEN_NODE)")

    @classmethod
    def from_args(cls, args: argparse.Namespace, default_node: str = "") -> "Settings":
        """Environment, then the command-line overrides of :meth:`add_arguments`."""
        return cls.from_env(
            default_node=default_node,
            prefix=args.prefix,
            namespace=args.namespace,
            mode=args.mode,
            period_us=args.period_us,
            node=args.name,
        )

    @property
    def lockstep(self) -> bool:
        return self.mode == "lockstep"

    def service_name(self, name: str) -> str:
        """The full service name of ``name`` under the namespace."""
        return services.qualified(self.namespace, name)

    def iox_config(self) -> "iox2.config.Config":
        """The iceoryx2 config of a bowden process (``IpcSettings::iox_config``)."""
        cfg = iox2.config.default()
        cfg.global_cfg.prefix = iox2.FileName.new(self.prefix)
        # The launcher cleans up dead nodes (at start and when a child dies), not every process
        # as it exits: that raced with siblings shutting down at the same moment.
        cfg.global_cfg.node.cleanup_dead_nodes_on_destruction = False
        return cfg


def quiet_log() -> None:
    """iceoryx2 logs warnings on its own; keep errors only unless ``IOX2_LOG_LEVEL`` says otherwise."""
    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)


class Output(Generic[T]):
    """Publisher of one sample type; stamps ``seq`` (per publisher, from 0), ``tick`` and
    ``t_origin_ns``."""

    def __init__(self, publisher, sample_type: Type[T], service: str):
        self._publisher = publisher
        self.sample_type = sample_type
        self.service = service
        self.seq = 0
        self.sent = 0

    def publish(self, value: T, tick: int, t_origin_ns: int) -> int:
        """Publishes ``value`` with a fresh header. Returns the number of subscribers reached."""
        value.header.seq = self.seq
        value.header.tick = tick
        value.header.t_origin_ns = t_origin_ns
        return self.publish_raw(value)

    def publish_raw(self, value: T) -> int:
        """Publishes ``value`` with its header as given."""
        n = self._publisher.loan_uninit().write_payload(value).send()
        self.seq += 1
        self.sent += 1
        return n

    def update_connections(self) -> None:
        """Connects subscribers created since the last send (a send does this too)."""
        self._publisher.update_connections()

    def delete(self) -> None:
        self._publisher.delete()


class Input(Generic[T]):
    """Subscriber of one sample type. Samples are copied out of shared memory (they are small),
    so no loan is held between calls."""

    def __init__(self, subscriber, sample_type: Type[T], service: str):
        self._subscriber = subscriber
        self.sample_type = sample_type
        self.service = service
        self._size = ctypes.sizeof(sample_type)
        self._pending: Optional[T] = None
        self.received = 0
        #: Samples skipped because a newer one was there, or their tick had passed.
        self.skipped = 0
        self.errors = 0

    def _pop(self) -> Optional[T]:
        if self._pending is not None:
            p, self._pending = self._pending, None
            return p
        try:
            sample = self._subscriber.receive()
        except Exception:  # ReceiveError: a corrupted or broken connection
            self.errors += 1
            return None
        if sample is None:
            return None
        value = self.sample_type.from_buffer_copy(ctypes.string_at(sample.payload_ptr, self._size))
        sample.delete()
        self.received += 1
        return value

    def recv(self) -> Optional[T]:
        """The next sample in arrival order, or None."""
        return self._pop()

    def latest(self) -> Optional[T]:
        """The newest sample, skipping (and counting) older ones; None if there is none."""
        last = None
        while True:
            s = self._pop()
            if s is None:
                return last
            if last is not None:
                self.skipped += 1
            last = s

    def take_tick(self, tick: int) -> Optional[T]:
        """The sample of tick ``tick`` (lockstep): older ones are skipped, a later one is kept."""
        while True:
            s = self._pop()
            if s is None:
                return None
            t = s.header.tick
            if t == tick:
                return s
            if t > tick:
                self._pending = s
                return None
            self.skipped += 1

    def take(self, lockstep: bool, tick: int) -> Optional[T]:
        """Lockstep: the sample of ``tick``; real time: the newest."""
        return self.take_tick(tick) if lockstep else self.latest()

    def delete(self) -> None:
        self._subscriber.delete()


class Notifier:
    """Wakes the listeners of a data service's event service (event-driven consumers)."""

    def __init__(self, notifier, service: str):
        self._notifier = notifier
        self.service = service

    def notify(self) -> int:
        return self._notifier.notify()

    def delete(self) -> None:
        self._notifier.delete()


class Ports:
    """One iceoryx2 node of a process and the factory of its ports. Close it (or use it as a
    context manager) so every port and the node are released before the process exits."""

    def __init__(self, node_name: str, settings: Settings):
        quiet_log()
        self.settings = settings
        self._owned: list = []
        self._services: dict = {}
        self._events: dict = {}
        self.node = (
            iox2.NodeBuilder.new()
            .name(iox2.NodeName.new(node_name))
            .config(settings.iox_config())
            # Signals are the process's business (see bowden_client.stage), as in bowden.
            .signal_handling_mode(iox2.SignalHandlingMode.Disabled)
            .create(iox2.ServiceType.Ipc)
        )

    def __enter__(self) -> "Ports":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _own(self, port):
        self._owned.append(port)
        return port

    def pubsub(self, name: str, sample_type: Type[T]):
        """The publish-subscribe service ``name`` (namespace applied) with bowden's QoS."""
        full = self.settings.service_name(name)
        key = (full, sample_type)
        if key not in self._services:
            q = services.qos_for(name)
            self._services[key] = (
                self.node.service_builder(iox2.ServiceName.new(full))
                .publish_subscribe(sample_type)
                .max_publishers(q.max_publishers)
                .max_subscribers(q.max_subscribers)
                .subscriber_max_buffer_size(q.max_buffer)
                .subscriber_max_borrowed_samples(q.max_borrowed)
                .history_size(q.history)
                .enable_safe_overflow(q.safe_overflow)
                .max_nodes(q.max_nodes)
                .open_or_create()
            )
        return self._services[key]

    def event(self, name: str):
        """The event service that accompanies data service ``name``."""
        full = self.settings.service_name(name)
        if full not in self._events:
            e = services.EVENT_QOS
            self._events[full] = (
                self.node.service_builder(iox2.ServiceName.new(full))
                .event()
                .max_notifiers(e.max_notifiers)
                .max_listeners(e.max_listeners)
                .max_nodes(e.max_nodes)
                .open_or_create()
            )
        return self._events[full]

    def output(self, name: str, sample_type: Type[T]) -> Output[T]:
        """A publisher of ``sample_type`` on service ``name``."""
        pub = (
            self.pubsub(name, sample_type)
            .publisher_builder()
            .max_loaned_samples(services.PUBLISHER_MAX_LOANED)
            .create()
        )
        return self._own(Output(pub, sample_type, self.settings.service_name(name)))

    def input(self, name: str, sample_type: Type[T], buffer: int = 8) -> Input[T]:
        """A subscriber of ``sample_type`` on service ``name`` with a queue of ``buffer`` samples."""
        buffer = max(1, min(buffer, services.qos_for(name).max_buffer))
        sub = self.pubsub(name, sample_type).subscriber_builder().buffer_size(buffer).create()
        return self._own(Input(sub, sample_type, self.settings.service_name(name)))

    def notifier(self, name: str) -> Notifier:
        """A notifier on the event service of ``name``."""
        return self._own(Notifier(self.event(name).notifier_builder().create(), self.settings.service_name(name)))

    def listener(self, name: str):
        """An iceoryx2 listener on the event service of ``name`` (attach it to a WaitSet)."""
        return self._own(self.event(name).listener_builder().create())

    def waitset(self):
        """An iceoryx2 WaitSet that leaves signals to the process."""
        return self._own(
            iox2.WaitSetBuilder.new().signal_handling_mode(iox2.SignalHandlingMode.Disabled).create(iox2.ServiceType.Ipc)
        )

    def adopt(self, obj):
        """Releases ``obj`` (anything with ``delete()``, e.g. a WaitSet guard) in :meth:`close`,
        before everything created earlier."""
        return self._own(obj)

    def close(self) -> None:
        """Releases every port (newest first), the services and the node."""
        while self._owned:
            p = self._owned.pop()
            try:
                p.delete()
            except Exception:
                pass
        self._services.clear()
        self._events.clear()
        self.node = None
        gc.collect()
