#!/usr/bin/env python3
"""Tables of docs/results/adapt/README.md from the session reports run.sh wrote."""
import json, os, re, sys

OUT = os.environ.get("OUT") or os.path.dirname(os.path.abspath(__file__))


def session(name):
    """(before, end) tip position error by truth, mm, and the windows (t0, t1, mm), from session.md."""
    md = open(os.path.join(OUT, name, "session.md")).read()
    truth = md.split("## Before and after the slack — simulator truth")[1]
    row = [l for l in truth.splitlines() if l.startswith("| newton")][0].split("|")
    before, end = float(row[2]), float(row[5])
    table = md.split("## Error over time — tip position error [mm], simulator truth")[1].split("\n## ")[0]
    windows = []
    for l in table.splitlines():
        m = re.match(r"\| (\d+) \| ([\d.]+)–([\d.]+)(.*?) \| ([\d.]+) \|", l)
        if m:
            windows.append((float(m.group(2)), float(m.group(3)), float(m.group(5))))
    return before, end, windows


def back_within(windows, before, onset):
    """The first 30 s window after the onset from which every later window stays within 10 % of
    the pre-slack error, as text ("never" if none)."""
    after = [x for x in windows if x[0] >= onset]
    for k, x in enumerate(after):
        if all(y[2] <= 1.1 * before for y in after[k:]):
            return f"{x[0]:.0f}–{x[1]:.0f} s ({x[0] - onset:.0f} s after onset)"
    return "never"


def settled(windows, grown_s):
    """Mean of the 30 s windows from 5 min after the slack stopped growing to the end of the
    session (the issue's "within 5 minutes"), and how many windows that is."""
    w = [x[2] for x in windows if x[0] >= grown_s + 300.0]
    return (sum(w) / len(w), len(w)) if w else (float("nan"), 0)


def swaps(name):
    p = os.path.join(OUT, name, "adapt-newton", "adapt.jsonl")
    if not os.path.exists(p):
        return None
    recs = [json.loads(l) for l in open(p)]
    return recs


def main():
    print("| scenario | controller | before slack [mm] | end, feed-forward [mm] | end, adapted [mm] | end vs before, adapted | gain lost to slack recovered | 5 min after the slack stopped growing, adapted [mm] | vs before | swaps (checks) | first window back within 10 % after onset |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    # (scenario, onset of the slack, when it stops growing) in seconds.
    for s, onset, grown in [("slip", 120.0, 120.0), ("creep", 120.0, 720.0), ("lugre-creep", 120.0, 720.0)]:
        for c in ["tcn", "accurate"]:
            ff, ad = f"{s}-{c}-ff", f"{s}-{c}-adapt"
            if not (os.path.exists(os.path.join(OUT, ff, "session.md")) and os.path.exists(os.path.join(OUT, ad, "session.md"))):
                continue
            b, e_ff, _ = session(ff)
            b2, e_ad, w = session(ad)
            recs = swaps(ad) or []
            n_sw = sum(r["decision"] == "swapped" for r in recs)
            back = back_within(w, b2, onset)
            rec = (e_ff - e_ad) / (e_ff - b) if e_ff > b else float("nan")
            st, n_st = settled(w, grown)
            st_txt = f"{st:.2f} ({n_st} windows)" if n_st else "–"
            st_rel = f"{100 * (st / b2 - 1):+.0f} %" if n_st else "–"
            print(f"| {s} | {c} | {b:.2f} | {e_ff:.2f} | {e_ad:.2f} | {100 * (e_ad / b2 - 1):+.0f} % | {100 * rec:.0f} % | {st_txt} | {st_rel} | {n_sw} ({len(recs)}) | {back} |")


if __name__ == "__main__":
    main()
