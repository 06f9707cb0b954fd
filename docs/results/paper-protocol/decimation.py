#!/usr/bin/env python3
"""Markdown tables of decimation.sh's runs: per run directory (one decimation) and unit, the
reduction of the mean tip position / orientation error vs uncalibrated, by vision, pooled over
the three paths as the paper's "Average Value" (every point of every path), for each mode, on
the shipped and on the large paths; then each run's mean over its units and its worst path.

Usage: decimation.py OUT/tuning-d1 OUT/tuning-d2 ...  (bench transfer output directories)
"""
import glob, json, os, re, sys

PATHS = ("random", "circle", "zigzag")


def reductions(summary):
    cells = {(c["trajectory"], c["controller"]): c for c in json.load(open(summary))["cells"]}
    out = {}
    for ctl in ("paper", "newton"):
        r = {}
        for m, key in (("pos", "pos_mean_mm"), ("rot", "rot_mean_deg")):
            err = lambda c, t: cells[(t, c)]["task_vision"]
            num = sum(err(ctl, t)["n"] * err(ctl, t)[key] for t in PATHS)
            den = sum(err("uncalibrated", t)["n"] * err("uncalibrated", t)[key] for t in PATHS)
            r[m] = 100 * (1 - num / den)
            r[m + "_worst"] = min(100 * (1 - err(ctl, t)[key] / err("uncalibrated", t)[key]) for t in PATHS)
        out[ctl] = r
    return out


def decimation(run):
    """The recipe's decimation, from the run's transfer.json (absent: 1)."""
    return str(json.load(open(run + "/transfer.json"))["recipe"].get("decimation", 1))


def main(runs):
    print("| decimation | unit | tune chose | shipped: paper | shipped: newton | large: paper | large: newton |")
    print("|---|---|---|---|---|---|---|")
    means = []
    for run in runs:
        acc = {}
        for unit in sorted(glob.glob(run + "/units/*/unit-*")):
            if not os.path.exists(unit + "/eval/summary.json"):
                continue
            ctl = open(unit + "/controller.toml").read()
            mode = re.search(r'^mode = "(\w+)"', ctl, re.M).group(1)
            mu = re.search(r"^prior_weight = ([\d.e-]+)", ctl, re.M)
            chose = mode + (f" μ = {float(mu.group(1)):.3g}" if mu and mode == "newton" else "")
            row = [decimation(run), "/".join(unit.split("/")[-2:]), chose]
            for ev in ("eval", "eval-large"):
                red = reductions(unit + f"/{ev}/summary.json")
                for c in ("paper", "newton"):
                    r = red[c]
                    row.append(f"{r['pos']:+.1f} / {r['rot']:+.1f} %")
                    acc.setdefault((ev, c), []).append(r)
            print("| " + " | ".join(row) + " |")
        if acc:
            means.append((decimation(run), acc))
    print()
    print("Mean over the units [worst path, position or orientation]:")
    print()
    print("| decimation | units | shipped: paper | shipped: newton | large: paper | large: newton |")
    print("|---|---|---|---|---|---|")
    for d, acc in means:
        row = [d, str(len(acc[("eval", "paper")]))]
        for ev in ("eval", "eval-large"):
            for c in ("paper", "newton"):
                v = acc[(ev, c)]
                pos = sum(r["pos"] for r in v) / len(v)
                rot = sum(r["rot"] for r in v) / len(v)
                worst = min(min(r["pos_worst"], r["rot_worst"]) for r in v)
                row.append(f"{pos:+.1f} / {rot:+.1f} % [{worst:+.1f}]")
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
