"""Running a Python stage inside a ``bowden run``: the launcher's protocol, in both modes
(``docs/deployment.md``, "Swapping a node for hardware").

- **Lockstep**: publish a ``ComponentStatus`` with state 0 (starting) once the ports exist; for
  each ``ClockTick`` k wait until every stage producing one of the inputs has reported tick k
  done (or stopped), step, publish the outputs with ``header.tick = k``, then the status for k,
  then notify the outputs' event services and the status service; exit on ``shutdown = 1``.
  The pipeline entry of the stage must say ``reports_status = true``.
- **Real time**: periodic (a release every period on CLOCK_MONOTONIC, aligned with the
  launcher's start time once it is known, skipped releases counted) or event-driven (woken by
  the inputs' event services, or after a timeout); a status every status period (seen by the
  launcher with ``reports_status = true``); exit on the launcher's shutdown tick.

Both end on SIGINT/SIGTERM too, publishing a final "stopped" status.

>>> stage = Stage(ports, "plant", inputs=[services.MOTOR_COMMAND], outputs=[services.PLANT_STATE])
>>> stage.run(step)        # step(cx: StepContext) reads inputs, publishes outputs
"""

from __future__ import annotations

import collections
import signal
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Optional

import iceoryx2 as iox2

from . import layout, services
from .ports import Ports

U64_MAX = (1 << 64) - 1

_terminate = threading.Event()


def install_signal_handlers() -> None:
    """SIGINT and SIGTERM ask the stage to finish (checked at least every 100 ms)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: _terminate.set())


def termination_requested() -> bool:
    return _terminate.is_set()


@dataclass
class StepContext:
    """Context of one activation (``bowden_runtime::stage::StepCx``)."""

    lockstep: bool
    #: Lockstep: the tick being processed. Real time: the activation count.
    tick: int
    #: Lockstep: simulated time of the tick. Real time: monotonic time at activation.
    t_now_ns: int
    #: Lockstep: simulated step. Real time: the period (0 if event-driven).
    dt_ns: int
    #: Real time, periodic: the nominal release of this activation.
    t_release_ns: int

    def clock_ns(self) -> int:
        """Time to stamp a new sample's ``t_origin_ns`` with: simulated in lockstep, the
        monotonic clock in real time."""
        return self.t_now_ns if self.lockstep else time.monotonic_ns()


class Stage:
    """The bookkeeping every bowden stage does around its step: ready handshake, lockstep
    dataflow, release grid, status samples, wake-ups of consumers, shutdown.

    ``inputs`` / ``outputs`` are the service names the stage reads and writes (its ports are
    the caller's): the stage waits for the producers of its inputs in lockstep, wakes on them
    when event-driven, and notifies its outputs' event services after each step. Counters the
    step may raise: :attr:`rejected`, :attr:`faults`; :attr:`degraded` sets the state."""

    def __init__(
        self,
        ports: Ports,
        name: str,
        inputs: Iterable[str] = (),
        outputs: Iterable[str] = (),
        period_ns: Optional[int] = None,
        wake_timeout_ns: Optional[int] = 100_000_000,
        status_period_ns: int = 1_000_000_000,
    ):
        self.ports = ports
        self.settings = ports.settings
        self.name = name
        self.lockstep = self.settings.lockstep
        self.inputs = list(inputs)
        self.outputs = list(outputs)
        #: Real time: release period (None: event-driven).
        self.period_ns = period_ns
        self.wake_timeout_ns = wake_timeout_ns
        self.status_period_ns = status_period_ns
        self.cycles = 0
        self.rejected = 0
        self.faults = 0
        self.degraded = False
        self.release_misses = 0
        self._response = collections.deque(maxlen=10_000)
        self._stop = False

        install_signal_handlers()
        self._clock = ports.input(services.CLOCK, layout.ClockTick, 8)
        self._status_out = ports.output(services.COMPONENT_STATUS, layout.ComponentStatus)
        self._status_wake = ports.notifier(services.COMPONENT_STATUS)
        self._out_wake = [ports.notifier(o) for o in self.outputs]
        self._status_in = None
        self._upstream: dict = {}
        if self.lockstep:
            self._status_in = ports.input(services.COMPONENT_STATUS, layout.ComponentStatus, 256)
            for inp in self.inputs:
                for producer in services.producers(self.settings.config, inp):
                    if producer != name:
                        self._upstream[producer] = {"alive": True, "done": None}
        # Wake-ups: the clock always; the inputs unless periodic in real time (nobody would drain
        # them between releases).
        self._waitset = ports.waitset()
        self._listeners = [ports.listener(services.CLOCK)]
        if self.lockstep or period_ns is None:
            self._listeners += [ports.listener(i) for i in self.inputs]
        for listener in self._listeners:
            ports.adopt(self._waitset.attach_notification(listener))

    # -- status -------------------------------------------------------------------------------

    def _state(self, st: int) -> int:
        if st == layout.ComponentStatus.RUNNING and self.degraded:
            return layout.ComponentStatus.DEGRADED
        return st

    def publish_status(self, state: int, tick: int, t_origin_ns: int) -> None:
        s = layout.ComponentStatus(
            state=self._state(state),
            cycles=self.cycles,
            deadline_misses=self.release_misses,
            rejected_samples=self.rejected,
            faults=self.faults,
        )
        s.set_name(self.name)
        # Lockstep statuses are part of the simulated run: no wall-clock figures in them.
        if not self.lockstep and self._response:
            r = sorted(self._response)
            pick = lambda q: r[min(len(r) - 1, int(q * len(r)))]  # noqa: E731
            s.latency_p50_ns, s.latency_p99_ns, s.latency_p999_ns = pick(0.5), pick(0.99), pick(0.999)
            s.latency_max_ns = r[-1]
        self._status_out.publish(s, tick, t_origin_ns)

    # -- waiting ------------------------------------------------------------------------------

    def _wait(self, timeout_ns: int) -> None:
        """Blocks until a wake-up arrives or ``timeout_ns`` passes, then drains the listeners."""
        timeout_ns = max(0, min(timeout_ns, 100_000_000))
        self._waitset.wait_and_process_with_timeout(iox2.Duration.from_nanos(timeout_ns))
        for listener in self._listeners:
            listener.try_wait()

    def _refresh_upstreams(self) -> None:
        while True:
            st = self._status_in.recv()
            if st is None:
                return
            u = self._upstream.get(st.name())
            if u is None:
                continue
            if st.state == layout.ComponentStatus.STOPPED:
                u["alive"] = False
            elif st.state == layout.ComponentStatus.STARTING:
                u["alive"] = True
            else:
                u["alive"] = True
                u["done"] = st.header.tick

    def _ready(self, tick: int) -> bool:
        return all(not u["alive"] or (u["done"] is not None and u["done"] >= tick) for u in self._upstream.values())

    def stop(self) -> None:
        """Asks :meth:`run` to return after the current step."""
        self._stop = True

    def _should_stop(self) -> bool:
        return self._stop or termination_requested()

    # -- running ------------------------------------------------------------------------------

    def run(self, step: Callable[[StepContext], object]) -> None:
        """Runs ``step`` until the launcher's shutdown tick, SIGINT/SIGTERM or :meth:`stop`."""
        self.publish_status(layout.ComponentStatus.STARTING, 0, 0)
        self._status_wake.notify()
        try:
            if self.lockstep:
                self._run_lockstep(step)
            elif self.period_ns:
                self._run_periodic(step)
            else:
                self._run_event(step)
        finally:
            self.publish_status(layout.ComponentStatus.STOPPED, U64_MAX, 0)
            self._status_wake.notify()
            for w in self._out_wake:
                w.notify()

    def _after_step(self) -> None:
        for w in self._out_wake:
            w.notify()

    def _run_lockstep(self, step) -> None:
        while not self._should_stop():
            tick = self._clock.recv()
            if tick is None:
                self._wait(100_000_000)
                continue
            if tick.shutdown:
                return
            k = tick.header.tick
            while True:
                self._refresh_upstreams()
                if self._ready(k):
                    break
                if self._should_stop():
                    return
                self._wait(100_000_000)
            step(StepContext(True, k, tick.t_sim_ns, tick.dt_ns, tick.t_sim_ns))
            self.cycles += 1
            self.publish_status(layout.ComponentStatus.RUNNING, k, tick.t_sim_ns)
            self._after_step()
            self._status_wake.notify()

    def _clock_event(self) -> Optional[int]:
        """Real time: -1 on the shutdown tick, the common start time on a start tick, else None."""
        tick = self._clock.latest()
        if tick is None:
            return None
        if tick.shutdown:
            return -1
        return tick.t_sim_ns if tick.t_sim_ns > 0 else None

    def _maybe_status(self, now: int, tick: int) -> None:
        if now >= self._next_status:
            self._next_status = now + self.status_period_ns
            self.publish_status(layout.ComponentStatus.RUNNING, tick, now)
            self._status_wake.notify()

    def _run_periodic(self, step) -> None:
        period = self.period_ns
        now = time.monotonic_ns()
        release = now
        self._next_status = now + self.status_period_ns
        while True:
            ev = self._clock_event()
            if ev == -1 or self._should_stop():
                return
            if ev is not None:
                # The launcher's common start time: join its release grid.
                now = time.monotonic_ns()
                release = ev + max(0, -(-(now - ev) // period)) * period
            now = time.monotonic_ns()
            if release > now:
                time.sleep((release - now) / 1e9)
                continue
            step(StepContext(False, self.cycles, now, period, release))
            done = time.monotonic_ns()
            self._response.append(done - release)
            self.cycles += 1
            self._after_step()
            self._maybe_status(done, self.cycles)
            release += period
            if done > release:
                # Overran into the next period(s): skip them rather than burst to catch up.
                missed = (done - release) // period + 1
                self.release_misses += missed
                release += missed * period

    def _run_event(self, step) -> None:
        self._next_status = time.monotonic_ns() + self.status_period_ns
        while True:
            self._wait(self.wake_timeout_ns or 100_000_000)
            if self._clock_event() == -1 or self._should_stop():
                return
            now = time.monotonic_ns()
            step(StepContext(False, self.cycles, now, 0, now))
            done = time.monotonic_ns()
            self._response.append(done - now)
            self.cycles += 1
            self._after_step()
            self._maybe_status(done, self.cycles)
