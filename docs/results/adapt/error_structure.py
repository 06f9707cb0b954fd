#!/usr/bin/env python3
"""How much of a session's tip-joint error a low-dimensional correction could remove.

Reads the session.json that `bowden evaluate --session N --report DIR` writes (the first
repeat, simulator truth) and, for the points before the slack (t < 120 s) and after it has
settled (t > AFTER_S, the second argument), prints per joint the RMS of e = q_desired − q_true
and what is left of it after a least-squares fit of e, per joint, on:
  const           an offset
  const+dir       + the direction of the joint's last move of more than 1° (±1)
  const+dir+q     + the joint's own desired angle (a gain error)
  all q + all dir an offset, every joint's direction and every joint's desired angle
These are in-sample fits against truth: a bound on what such a correction could do, not
what an online fit from noisy camera rows does.

Usage: error_structure.py DIR/session.json AFTER_S      (pure Python, no numpy)
"""
import json
import math
import sys


def solve(a, b):
    """Least squares by the normal equations (Gaussian elimination with partial pivoting)."""
    n = len(a[0])
    m = [[sum(r[i] * r[j] for r in a) for j in range(n)] + [sum(r[i] * y for r, y in zip(a, b))] for i in range(n)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(m[r][c]))
        m[c], m[p] = m[p], m[c]
        if abs(m[c][c]) < 1e-12:
            continue
        for r in range(n):
            if r != c:
                f = m[r][c] / m[c][c]
                m[r] = [x - f * y for x, y in zip(m[r], m[c])]
    return [m[i][n] / m[i][i] if abs(m[i][i]) > 1e-12 else 0.0 for i in range(n)]


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: error_structure.py DIR/session.json AFTER_S")
    path = sys.argv[1]
    try:
        after_s = float(sys.argv[2])
    except ValueError:
        sys.exit(f"error_structure.py: AFTER_S {sys.argv[2]!r} is not a number of seconds")
    try:
        pts = json.load(open(path))["runs"][0]["points"]
    except (OSError, ValueError, KeyError, IndexError, TypeError) as e:
        sys.exit(f"error_structure.py: {path}: not a session report of `bowden evaluate --session` ({e!r})")
    if not pts:
        sys.exit(f"error_structure.py: {path}: the first run has no points")
    j = len(pts[0]["q_desired_deg"])
    dirs, cur, prev = [], [0.0] * j, None
    for p in pts:
        q = p["q_desired_deg"]
        if prev is not None:
            cur = [math.copysign(1.0, a - b) if abs(a - b) > 1.0 else c for a, b, c in zip(q, prev, cur)]
        dirs.append(cur)
        prev = q
    for name, keep in [("before", lambda t: t < 120.0), (f"after {after_s:.0f} s", lambda t: t > after_s)]:
        rows = [(p, d) for p, d in zip(pts, dirs) if keep(p["t_s"])]
        e = [[p["q_desired_deg"][k] - p["q_true_deg"][k] for k in range(j)] for p, _ in rows]
        rms = lambda v: math.sqrt(sum(x * x for x in v) / len(v))
        print(f"{name}: {len(rows)} points; RMS per joint [deg]: {[round(rms([r[k] for r in e]), 2) for k in range(j)]}")
        feats = {
            "const": lambda p, d, k: [1.0],
            "const+dir": lambda p, d, k: [1.0, d[k]],
            "const+dir+q": lambda p, d, k: [1.0, d[k], p["q_desired_deg"][k]],
            "all q + all dir": lambda p, d, k: [1.0] + list(d) + list(p["q_desired_deg"]),
        }
        for lab, f in feats.items():
            left = []
            for k in range(j):
                a = [f(p, d, k) for p, d in rows]
                y = [r[k] for r in e]
                w = solve(a, y)
                left.append(round(rms([yy - sum(wi * ai for wi, ai in zip(w, aa)) for aa, yy in zip(a, y)]), 2))
            print(f"  left after {lab:16s} {left}")


if __name__ == "__main__":
    main()
