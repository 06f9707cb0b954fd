#!/usr/bin/env bash
# Online adaptation through cable slack, on the unseen trajectories (random, circle, zigzag):
# every scenario × both shipped controllers (newton), without and with `--adapt`.
# configs/adapt.toml was chosen on the tuning trajectories with the slip only.
# Usage: docs/results/adapt/run.sh [bowden binary]   (from the repository root; ~10 min on 2 cores)
set -euo pipefail
BOWDEN=${1:-target/release/bowden}
OUT=docs/results/adapt
run() { # name plant minutes controller-config adapt(yes|no)
    local extra=()
    [ "$5" = yes ] && extra=(--adapt configs/adapt.toml)
    "$BOWDEN" evaluate --session "$3" --plant "$2" --controllers newton --controller-config "$4" \
        --window-s 30 --report "$OUT/$1" --force "${extra[@]}" > "$OUT/$1.log" 2>&1
    echo "$1 done"
}
for ctl in tcn:configs/controller.toml accurate:configs/controller-accurate.toml; do
    c=${ctl%%:*}; f=${ctl#*:}
    for sc in slip:configs/plant-slack-slip.toml:7 creep:configs/plant-slack-creep.toml:15 lugre-creep:configs/plant-lugre-slack-creep.toml:15; do
        IFS=: read -r s plant min <<< "$sc"
        run "$s-$c-ff" "$plant" "$min" "$f" no
        run "$s-$c-adapt" "$plant" "$min" "$f" yes
    done
done
python3 "$OUT/summarize.py" > "$OUT/summary.md"
