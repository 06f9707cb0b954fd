#!/usr/bin/env python3
"""Tables of the data study (README.md here) from the evaluation reports and training logs that
run.sh and `bowden bench transfer --units tuning` wrote. Usage:
    docs/results/data-study/summarize.py out/study-base out/data-study
Prints Markdown: per unit and case, the data (commands), the validation RMSE of both models, the
mode `bowden tune` chose, and the reduction (truth, %) of the tip position / orientation error
and joint MAE vs uncalibrated per trajectory for paper and newton, and the best of the two."""
import json, re, sys, pathlib

base, study = map(pathlib.Path, sys.argv[1:3])

def rmse(log):
    m = re.search(r"validation RMSE ([0-9.]+)", log.read_text()) if log.exists() else None
    return float(m.group(1)) if m else float("nan")

def cases():
    for unit_dir in sorted((base / "units").glob("*/unit-*")):
        unit = f"{unit_dir.parent.name}/{unit_dir.name}"
        yield unit, "mixed, all", unit_dir / "data", unit_dir / "eval", unit_dir / "logs/train-tcn-forward.log", unit_dir / "logs/train-tcn-inverse.log", unit_dir / "controller.toml"
        for name, label in [("mixed-1of2", "mixed, first 1/2"), ("mixed-1of4", "mixed, first 1/4"), ("paper", "eq. (16) only")]:
            d = study / unit / name
            data = study / unit / ("data-" + name)
            yield unit, label, data, d / "eval", d / "train-forward.log", d / "train-inverse.log", d / "controller.toml"

def reductions(report):
    s = json.loads(report.read_text())["summary"]
    cells = {(c["trajectory"], c["controller"]): c for c in s["cells"]}
    out = {}
    for t in s["trajectories"]:
        u = cells[(t, "uncalibrated")]
        for ctl in ("paper", "newton"):
            c = cells.get((t, ctl))
            if not c:
                continue
            red = lambda a, b: 100.0 * (1.0 - a / b)
            jm = lambda x: sum(x["joint_truth"]["mae_deg"]) / 5
            out[(t, ctl)] = (
                red(c["task_truth"]["pos_mean_mm"], u["task_truth"]["pos_mean_mm"]),
                red(c["task_truth"]["rot_mean_deg"], u["task_truth"]["rot_mean_deg"]),
                red(jm(c), jm(u)),
            )
    return s["trajectories"], out

print("| unit | data | commands | fwd RMSE ° | inv RMSE ° | tune chose | trajectory | paper pos / rot / joint % | newton pos / rot / joint % | best (min of pos, rot) % |")
print("|---|---|---|---|---|---|---|---|---|---|")
for unit, label, data, ev, flog, ilog, ctl in cases():
    if not (ev / "report.json").exists():
        continue
    n = json.loads((data / "manifest.json").read_text())["samples"]
    mode = re.search(r'^mode = "(\w+)"', ctl.read_text(), re.M).group(1) if ctl.exists() else "?"
    mu = re.search(r"<- chosen", ctl.read_text()) and re.search(r"^#.*?(newton μ = [0-9.]+|paper).*<- chosen", ctl.read_text(), re.M)
    chose = mu.group(1) if mu else mode
    trajs, red = reductions(ev / "report.json")
    for i, t in enumerate(trajs):
        p, nw = red[(t, "paper")], red[(t, "newton")]
        best = max(min(p[0], p[1]), min(nw[0], nw[1]))
        head = f"| {unit} | {label} | {n} | {rmse(flog):.2f} | {rmse(ilog):.2f} | {chose} |" if i == 0 else "| | | | | | |"
        print(f"{head} {t} | {p[0]:+.1f} / {p[1]:+.1f} / {p[2]:+.1f} | {nw[0]:+.1f} / {nw[1]:+.1f} / {nw[2]:+.1f} | {best:+.1f} |")
