#!/usr/bin/env bash
# The tuning side of the adaptation work: the shipped settings on the TUNING trajectories
# (configs/trajectories/tuning), where every variant in README.md's "tried and not adopted"
# sections was compared before anything was run on the unseen paths. The accurate pair
# (configs/controller-accurate.toml), newton, 3 repeats, truth: feed-forward with adaptation
# (configs/adapt.toml), the creep without it (for error_structure.py), and the vision feedback of
# configs/controller-feedback.toml (camera 10 fps) alone and with adaptation.
# Usage: docs/results/adapt/run-tuning.sh [bowden binary]   (from the repository root; ~8 min on 2 cores)
# Writes OUT (default out/adapt-tuning): each session's report, summary.txt and error-structure.txt.
set -euo pipefail
BOWDEN=${1:-target/release/bowden}
OUT=${OUT:-out/adapt-tuning}
mkdir -p "$OUT"
run() { # name plant minutes controller-config adapt(yes|no) extra...
    local name=$1 plant=$2 min=$3 ctl=$4 ad=$5; shift 5
    local extra=("$@")
    [ "$ad" = yes ] && extra+=(--adapt configs/adapt.toml)
    "$BOWDEN" evaluate --session "$min" --plant "$plant" --controllers newton --controller-config "$ctl" \
        --trajectories-dir configs/trajectories/tuning --window-s 30 --repeats 3 --report "$OUT/$name" \
        --force "${extra[@]}" > "$OUT/$name.log" 2>&1 || { cat "$OUT/$name.log"; exit 1; }
    echo "$name done"
}
SLIP=configs/plant-slack-slip.toml
CREEP=configs/plant-slack-creep.toml
ACC=configs/controller-accurate.toml
FB=configs/controller-feedback.toml
run slip-accurate-adapt "$SLIP" 10 "$ACC" yes
run creep-accurate-adapt "$CREEP" 20 "$ACC" yes
run creep-accurate-ff "$CREEP" 20 "$ACC" no
run slip-fb "$SLIP" 10 "$FB" no --camera-fps 10
run creep-fb "$CREEP" 20 "$FB" no --camera-fps 10
run slip-fb-adapt "$SLIP" 10 "$FB" yes --camera-fps 10
run creep-fb-adapt "$CREEP" 20 "$FB" yes --camera-fps 10
{
    for x in creep-accurate-ff:780 creep-accurate-adapt:1020 slip-accurate-adapt:420; do
        echo "## ${x%%:*}"
        python3 docs/results/adapt/error_structure.py "$OUT/${x%%:*}/session.json" "${x#*:}"
    done
} > "$OUT/error-structure.txt"
OUT="$OUT" python3 - > "$OUT/summary.txt" <<'PY'
import os, sys
sys.path.insert(0, "docs/results/adapt")
import summarize as S
S.OUT = os.environ["OUT"]
for name in sorted(os.listdir(S.OUT)):
    if not os.path.exists(os.path.join(S.OUT, name, "session.md")):
        continue
    b, e, w = S.session(name)
    st, n = S.settled(w, 120.0 if name.startswith("slip") else 720.0)
    recs = S.swaps(name) or []
    print(f"{name:22s} before {b:.2f} mm, end {e:.2f} mm, 5 min after the slack stopped growing "
          f"{st:.3f} mm ({100 * (st / b - 1):+.0f} %), swaps {sum(r['decision'] == 'swapped' for r in recs)} of {len(recs)} checks")
PY
cat "$OUT/summary.txt"
