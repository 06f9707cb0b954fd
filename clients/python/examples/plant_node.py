#!/usr/bin/env python3
"""A plant node in Python: reads ``MotorCommand`` (``bowden/motor_command``), publishes
``PlantState`` (``bowden/plant_state``) — what bowden's built-in ``plant`` does, as an external
process a pipeline starts with ``exec = [...]``:

    [[node]]
    name = "plant"
    exec = ["python", "clients/python/examples/plant_node.py"]
    reports_status = true          # required in lockstep; in real time, shows it in the summary

Copy it for a motor driver: replace :class:`LinearCablePlant` by the calls to your hardware
(send ``cable_disp_mm[:n_cables]`` to the motors, read the encoders back).

**The model is not bowden's plant.** bowden's simulated robot (``components/plant``) models
tendon-sheath friction and hysteresis (capstan / Prandtl–Ishlinskii, Bouc–Wen, LuGre). This one
is deliberately simple, enough to close the loop plausibly:

1. joint drive angles from the cable displacements by the small-angle, *linear* form of eq. (5)
   with decoupling: each joint's antagonistic pair (w1/w2 → q1, …, w9/w10 → q5) pulls
   ``w_a − w_b = Σ_k A[j][k]·q_k`` (mm per rad), where ``A`` comes from the cable offsets and the
   jaw pulley radius of the robot file (``--robot``, else the pipeline's ``[runtime] robot``,
   else the shipped ``configs/robot.toml``); the system is solved for q (segment 2 and the jaws
   are decoupled from segment 1). For the shipped robot it matches eq. (5) to within 0.01° at
   30° of bend;
2. a dead band (backlash of ``--backlash-deg`` per joint): the joint does not move until the
   drive has taken up the play, so commands and physical angles differ on every reversal — a
   crude stand-in for sheath hysteresis;
3. a first-order lag (time constant ``--tau-s``) from there to the physical angles ``q_phy``.

It steps every period in real time (the elapsed time as step) and every tick in lockstep.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

try:
    import bowden_client  # noqa: F401
except ImportError:  # run from a checkout without `pip install -e clients/python`
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from bowden_client import layout, services
from bowden_client.ports import Ports, Settings
from bowden_client.stage import Stage, StepContext

N_JOINTS = 5
N_CABLES = 10

#: The shipped robot's cable routing (configs/robot.toml): (joint, offset_pitch_mm,
#: offset_yaw_mm, pulley_sign) per cable w1..w10, and the jaw pulley radius.
SHIPPED_CABLES = [
    (1, 2.0, 0.0, 0.0),
    (1, -2.0, 0.0, 0.0),
    (2, 0.0, 2.0, 0.0),
    (2, 0.0, -2.0, 0.0),
    (3, 1.6, 0.0, 0.0),
    (3, -1.6, 0.0, 0.0),
    (4, 0.4, 0.7, 1.0),
    (4, 0.4, -0.7, -1.0),
    (5, -0.4, 0.7, 1.0),
    (5, -0.4, -0.7, -1.0),
]
SHIPPED_PULLEY_RADIUS_MM = 1.2


def load_robot(path: str):
    """Cable routing and pulley radius from a robot file (configs/robot.toml layout)."""
    import tomllib  # Python 3.11+

    with open(path, "rb") as f:
        robot = tomllib.load(f)
    cables = [
        (c["joint"], c.get("offset_pitch_mm", 0.0), c.get("offset_yaw_mm", 0.0), c.get("pulley_sign", 0.0))
        for c in robot["cables"]
    ]
    return cables, robot["forceps"]["pulley_radius_mm"]


def robot_of_pipeline(config_path):
    """``[runtime] robot`` of the pipeline file (relative to it), if it names one."""
    if not config_path or config_path.startswith("@") or sys.version_info < (3, 11):
        return None
    import tomllib

    try:
        with open(config_path, "rb") as f:
            robot = tomllib.load(f).get("runtime", {}).get("robot")
    except (OSError, ValueError):
        return None
    return os.path.join(os.path.dirname(os.path.abspath(config_path)), robot) if robot else None


class LinearCablePlant:
    """Linearised decoupled cable drive → backlash → first-order lag (see the module docstring)."""

    def __init__(self, cables, pulley_radius_mm: float, tau_s: float, backlash_deg: float):
        if len(cables) != N_CABLES:
            raise ValueError(f"{len(cables)} cables, expected {N_CABLES}")
        # C[i][k]: mm cable i is pulled in per rad of joint k, to first order in eq. (5).
        self.C = []
        for joint, off_pitch, off_yaw, sign in cables:
            row = [0.0] * N_JOINTS
            row[0] = off_pitch  # segment 1 pitch hinges
            row[1] = off_yaw  # segment 1 yaw hinges
            if joint >= 3:
                row[2] = off_pitch  # the cable also crosses segment 2
            if joint >= 4:
                row[joint - 1] += sign * pulley_radius_mm  # it ends on a jaw pulley
            self.C.append(row)
        self.pairs = []
        for j in range(1, N_JOINTS + 1):
            idx = [i for i, c in enumerate(cables) if c[0] == j]
            if len(idx) != 2:
                raise ValueError(f"joint {j}: {len(idx)} cables, expected an antagonistic pair")
            self.pairs.append((idx[0], idx[1]))
        # A[j][k]: differential pull of joint j's pair per rad of joint k (lower triangular).
        self.A = [[self.C[a][k] - self.C[b][k] for k in range(N_JOINTS)] for a, b in self.pairs]
        self.tau_s = tau_s
        self.backlash_deg = backlash_deg
        self.q_drive = [0.0] * N_JOINTS
        self.q_play = [0.0] * N_JOINTS
        self.q_phy = [0.0] * N_JOINTS
        self.t_sim_ns = 0

    def drive_from_cables(self, w_mm) -> list:
        """Joint drive angles (deg) whose linearised pulls match the cables' (solves A·q = Δw)."""
        q = solve(self.A, [w_mm[a] - w_mm[b] for a, b in self.pairs])
        return [math.degrees(v) for v in q]

    def command(self, w_mm) -> None:
        self.q_drive = self.drive_from_cables(w_mm)

    def step(self, dt_s: float) -> None:
        b = self.backlash_deg
        alpha = 1.0 - math.exp(-dt_s / self.tau_s) if self.tau_s > 0 else 1.0
        for j in range(N_JOINTS):
            u = self.q_drive[j]
            # Backlash: the output moves only once the drive has taken up the play.
            if u - self.q_play[j] > b:
                self.q_play[j] = u - b
            elif u - self.q_play[j] < -b:
                self.q_play[j] = u + b
            self.q_phy[j] += alpha * (self.q_play[j] - self.q_phy[j])
        self.t_sim_ns += int(dt_s * 1e9)

    def fill_state(self, s: layout.PlantState) -> None:
        s.n_joints = N_JOINTS
        s.n_cables = N_CABLES
        s.t_sim_ns = self.t_sim_ns
        q_rad = [math.radians(v) for v in self.q_phy]
        for j in range(N_JOINTS):
            s.q_phy_deg[j] = self.q_phy[j]
            s.q_cmd_deg[j] = self.q_drive[j]
        for i in range(N_CABLES):
            # Distal cable displacement that the physical angles correspond to.
            s.cable_tip_mm[i] = sum(self.C[i][k] * q_rad[k] for k in range(N_JOINTS))


def solve(a, y):
    """Solves the small linear system a·x = y (Gaussian elimination with partial pivoting)."""
    n = len(y)
    m = [list(map(float, row)) + [float(v)] for row, v in zip(a, y)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(m[r][c]))
        if abs(m[p][c]) < 1e-12:
            raise ValueError("singular cable model")
        m[c], m[p] = m[p], m[c]
        for r in range(c + 1, n):
            f = m[r][c] / m[c][c]
            for k in range(c, n + 1):
                m[r][k] -= f * m[c][k]
    x = [0.0] * n
    for r in reversed(range(n)):
        x[r] = (m[r][n] - sum(m[r][k] * x[k] for k in range(r + 1, n))) / m[r][r]
    return x


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    Settings.add_arguments(ap)
    ap.add_argument(
        "--robot", help="robot file for the cable routing (default: the pipeline's `[runtime] robot`, else the shipped one)"
    )
    ap.add_argument("--tau-s", type=float, default=0.05, help="time constant of the joints' lag, s (default 0.05)")
    ap.add_argument("--backlash-deg", type=float, default=1.0, help="dead band of every joint, deg (default 1.0)")
    ap.add_argument("--quiet", action="store_true", help="no exit summary")
    args = ap.parse_args(argv)

    settings = Settings.from_args(args, default_node="plant")
    robot = args.robot or robot_of_pipeline(settings.config)
    cables, radius = load_robot(robot) if robot else (SHIPPED_CABLES, SHIPPED_PULLEY_RADIUS_MM)
    plant = LinearCablePlant(cables, radius, args.tau_s, args.backlash_deg)

    with Ports(settings.node, settings) as ports:
        commands = ports.input(services.MOTOR_COMMAND, layout.MotorCommand, buffer=4)
        states = ports.output(services.PLANT_STATE, layout.PlantState)
        stage = Stage(
            ports,
            settings.node,
            inputs=[services.MOTOR_COMMAND],
            outputs=[services.PLANT_STATE],
            period_ns=settings.period_us * 1000,
        )
        last = {"tick": 0, "t_prev": None}

        def step(cx: StepContext) -> None:
            m = commands.take(cx.lockstep, cx.tick)
            if m is not None:
                w = list(m.cable_disp_mm[:N_CABLES])
                if m.n_cables == N_CABLES and all(math.isfinite(v) for v in w):
                    plant.command(w)
                    last["tick"] = m.header.tick
                else:
                    stage.rejected += 1  # hold the last valid command
            now = cx.clock_ns()
            if cx.lockstep:
                dt_ns = cx.dt_ns
            else:
                # Real time: simulate the time that actually passed.
                dt_ns = max(1, now - last["t_prev"]) if last["t_prev"] is not None else cx.dt_ns
            last["t_prev"] = now
            plant.step(dt_ns * 1e-9)
            s = layout.PlantState()
            plant.fill_state(s)
            states.publish(s, cx.tick if cx.lockstep else last["tick"], cx.t_now_ns if cx.lockstep else now)

        t0 = time.monotonic()
        stage.run(step)
        if not args.quiet:
            print(
                f"[{settings.node}] python plant ({settings.mode}): {stage.cycles} cycles in "
                f"{time.monotonic() - t0:.2f} s, {states.sent} states sent, {commands.received} commands "
                f"received, rejected {stage.rejected}, skipped releases {stage.release_misses}; "
                f"q_phy = [{', '.join(f'{v:.2f}' for v in plant.q_phy)}] deg",
                file=sys.stderr,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
