#!/usr/bin/env python3
"""Prints the ``JointCommand`` samples of a running bowden pipeline (``bowden/joint_command``,
compensator → actuator): tick, mode, commanded and desired joint angles.

Start a pipeline (``bowden run``), then in another terminal, with the same prefix:

    python clients/python/examples/monitor.py                 # prefix bowden_, until Ctrl-C
    python clients/python/examples/monitor.py --prefix myrun_ --count 10 --every 100

It only listens: it is not a stage of the pipeline and the launcher does not know about it. It
stops on Ctrl-C, after ``--count`` samples, or when the run ends (the launcher's shutdown tick).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

try:
    import bowden_client  # noqa: F401
except ImportError:  # run from a checkout without `pip install -e clients/python`
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import iceoryx2 as iox2

from bowden_client import layout, services
from bowden_client.ports import Ports, Settings
from bowden_client.stage import install_signal_handlers, termination_requested


def fmt(q, n: int) -> str:
    return "[" + ", ".join(f"{v:7.2f}" for v in list(q)[:n]) + "]"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    Settings.add_arguments(ap)
    ap.add_argument("--count", type=int, default=0, help="exit after this many samples printed (0: never)")
    ap.add_argument("--every", type=int, default=1, help="print one sample in N (default: every one)")
    ap.add_argument("--timeout-s", type=float, default=0.0, help="exit after this long without a sample (0: never)")
    args = ap.parse_args(argv)
    settings = Settings.from_args(args, default_node="monitor")
    install_signal_handlers()

    printed = seen = 0
    with Ports(f"{settings.node}-{os.getpid()}", settings) as ports:
        commands = ports.input(services.JOINT_COMMAND, layout.JointCommand, buffer=64)
        clock = ports.input(services.CLOCK, layout.ClockTick, 8)
        wake = ports.listener(services.JOINT_COMMAND)
        print(
            f"monitor: listening on `{commands.service}` (prefix `{settings.prefix}`); Ctrl-C to stop",
            file=sys.stderr,
            flush=True,
        )
        last_sample = time.monotonic()
        while not termination_requested():
            wake.timed_wait(iox2.Duration.from_millis(100))
            while True:
                c = commands.recv()
                if c is None:
                    break
                seen += 1
                last_sample = time.monotonic()
                if (seen - 1) % max(1, args.every):
                    continue
                n = min(c.n_joints, layout.MAX_JOINTS)
                print(
                    f"JointCommand seq={c.header.seq} tick={c.header.tick} "
                    f"mode={layout.JointCommand.MODES.get(c.mode, c.mode)} q_cmd_deg={fmt(c.q_cmd_deg, n)} "
                    f"q_desired_deg={fmt(c.q_desired_deg, n)} iterations={c.iterations}",
                    flush=True,
                )
                printed += 1
                if args.count and printed >= args.count:
                    break
            if args.count and printed >= args.count:
                break
            t = clock.latest()
            if t is not None and t.shutdown:
                print("monitor: the run ended", file=sys.stderr)
                break
            if args.timeout_s and time.monotonic() - last_sample > args.timeout_s:
                print(f"monitor: no sample for {args.timeout_s} s", file=sys.stderr)
                break
    print(f"monitor: {seen} JointCommand samples received, {printed} printed", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
