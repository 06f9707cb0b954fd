#!/usr/bin/env bash
# Vision feedback through cable slack, on the unseen trajectories: the slip and the creep
# scenarios × feedback alone / feedback + adaptation × with the slow correction b (the shipped
# configs/controller-feedback.toml) and without it (the same with bias_gain = 0), the accurate
# pair, newton, camera at 10 fps, 3 repeats each. Each session runs 5 min past the moment its slack
# stops growing (slip 120 s, creep 720 s) and 3 min more, as run.sh's do.
# Usage: docs/results/adapt/run-feedback.sh [bowden binary]   (from the repository root; ~25 min on 2 cores)
set -euo pipefail
BOWDEN=${1:-target/release/bowden}
OUT=docs/results/adapt/feedback
mkdir -p "$OUT"
NOB="$OUT/controller-feedback-no-slow.toml"
sed 's/^bias_gain = .*/bias_gain = 0.0/' configs/controller-feedback.toml > "$NOB"
run() { # name plant minutes controller-config adapt(yes|no)
    local extra=()
    [ "$5" = yes ] && extra=(--adapt configs/adapt.toml)
    "$BOWDEN" evaluate --session "$3" --plant "$2" --controllers newton --controller-config "$4" \
        --camera-fps 10 --window-s 30 --repeats 3 --report "$OUT/$1" --force "${extra[@]}" > "$OUT/$1.log" 2>&1 \
        || { cat "$OUT/$1.log"; exit 1; }
    echo "$1 done"
}
for sc in slip:configs/plant-slack-slip.toml:10 creep:configs/plant-slack-creep.toml:20; do
    IFS=: read -r s plant min <<< "$sc"
    run "$s-fb" "$plant" "$min" configs/controller-feedback.toml no
    run "$s-fb-adapt" "$plant" "$min" configs/controller-feedback.toml yes
    run "$s-fb-noslow" "$plant" "$min" "$NOB" no
    run "$s-fb-adapt-noslow" "$plant" "$min" "$NOB" yes
done
find "$OUT" -name session.json -delete
find "$OUT" \( -name 'gen-*' -o -name pipelines \) -type d -prune -exec rm -rf {} +
find "$OUT" \( -name rows.csv -o -name '*.log' \) -delete
