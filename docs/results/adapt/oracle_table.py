"""The table of oracle.sh: tip position / orientation error and joint MAE by simulator truth,
averaged over the three unseen paths and the repeats, for the shipped TCN and accurate pairs and
each recalibrated one, on each plant; then the slack sessions started from recalibrated pairs."""
import glob
import json
import os
import sys

OUT = os.environ.get("OUT", "out/oracle")


def average(path):
    rows = {}
    for r in json.load(open(path))["summary"]["average"]:
        t = r["task_truth"]
        mae = r["joint_truth"]["mae_deg"]
        rows[r["controller"]] = (t["pos_mean_mm"], t["rot_mean_deg"], sum(mae) / len(mae))
    return rows


print("| plant | models | uncalibrated: position [mm] / orientation [°] / joint MAE [°] "
      "| newton | position reduction |")
print("|---|---|---|---|---|")
for plant in ("default", "slipped", "crept"):
    runs = [("shipped TCN pair", f"{OUT}/{plant}/shipped-tcn/report.json"),
            ("TCN pair recalibrated on it, tuned", f"{OUT}/{plant}/recalibrated-tcn/report.json"),
            ("shipped accurate pair", f"{OUT}/{plant}/shipped/report.json")]
    seeds = sorted({p.split("-seed")[-1].split("/")[0]
                    for p in glob.glob(f"{OUT}/{plant}/*-seed*/report.json")})
    for seed in seeds:
        runs.append((f"accurate pair recalibrated on it, LSTM seed {seed}, tuned",
                     f"{OUT}/{plant}/recalibrated-seed{seed}/report.json"))
        runs.append((f"accurate pair recalibrated on it, LSTM seed {seed}, shipped settings",
                     f"{OUT}/{plant}/untuned-seed{seed}/report.json"))
    for name, rep in runs:
        if not os.path.exists(rep):
            continue
        a = average(rep)
        u, n = a["uncalibrated"], a["newton"]
        print(f"| {plant} | {name} | {u[0]:.2f} / {u[1]:.2f} / {u[2]:.2f} | "
              f"{n[0]:.2f} / {n[1]:.2f} / {n[2]:.2f} | {100 * (1 - n[0] / u[0]):+.1f} % |")

# The slack sessions started from each recalibrated default-robot pair (SESSIONS=1).
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import summarize  # noqa: E402

summarize.OUT = f"{OUT}/default"
rows = []
for seed in sorted({p.split("-seed")[-1].split("-")[0]
                    for p in glob.glob(f"{OUT}/default/session-*-seed*-adapt/session.md")}):
    for scenario in ("slip", "creep"):
        ff, ad = f"session-{scenario}-seed{seed}-ff", f"session-{scenario}-seed{seed}-adapt"
        if not all(os.path.exists(f"{OUT}/default/{n}/session.md") for n in (ff, ad)):
            continue
        before, end_ff, _ = summarize.session(ff)
        before_ad, end_ad, windows = summarize.session(ad)
        back = summarize.back_within(windows, before_ad, 120.0)
        # The 3-minute mean from 5 min after the slack stopped growing (slip 120 s, creep 720 s).
        st, n_st = summarize.settled(windows, 120.0 if scenario == "slip" else 720.0)
        st_txt = f"{st:.2f} ({100 * (st / before_ad - 1):+.0f} %)" if n_st else "–"
        rows.append(f"| {scenario} | {seed} | {before:.2f} | {end_ff:.2f} | {end_ad:.2f} | "
                    f"{100 * (end_ad / before_ad - 1):+.0f} % | {st_txt} | {back} |")
if rows:
    print()
    print("| scenario | recalibrated pair (LSTM seed) | before slack [mm] | end, feed-forward [mm] "
          "| end, adapted [mm] | end vs before, adapted | 5 min after the slack stopped growing, adapted [mm] "
          "| first window back within 10 % after onset |")
    print("|---|---|---:|---:|---:|---:|---:|---|")
    print("\n".join(rows))
