#!/usr/bin/env bash
# Two hours of work through the default robot's creep (issue #13: "a system that runs for
# hours"): both shipped controllers (newton), with and without `--adapt`, 3 repeats, 5-minute
# windows. The creep stops growing at 720 s; the rest shows whether adaptation holds still.
# Usage: docs/results/adapt/run-hours.sh [bowden binary]   (from the repository root; ~12 min)
# Environment: OUT (default docs/results/adapt/hours).
set -euo pipefail
BOWDEN=${1:-target/release/bowden}
OUT=${OUT:-docs/results/adapt/hours}
[ -x "$BOWDEN" ] || { echo "run-hours.sh: no bowden binary at $BOWDEN" >&2; exit 2; }
[ -f configs/plant-slack-creep.toml ] || { echo "run-hours.sh: run from the repository root" >&2; exit 2; }
mkdir -p "$OUT"
for ctl in tcn:configs/controller.toml accurate:configs/controller-accurate.toml; do
    c=${ctl%%:*}; f=${ctl#*:}
    for a in ff adapt; do
        extra=()
        [ "$a" = adapt ] && extra=(--adapt configs/adapt.toml)
        "$BOWDEN" evaluate --session 120 --plant configs/plant-slack-creep.toml --controllers newton \
            --controller-config "$f" --window-s 300 --repeats 3 --report "$OUT/creep-$c-$a" --force \
            "${extra[@]}" > "$OUT/creep-$c-$a.log" 2>&1 || { cat "$OUT/creep-$c-$a.log"; exit 1; }
        echo "creep-$c-$a done"
    done
done
# Keep what a reader looks at (as run.sh does).
find "$OUT" -name session.json -delete
find "$OUT" \( -name 'gen-*' -o -name pipelines \) -type d -prune -exec rm -rf {} +
find "$OUT" \( -name rows.csv -o -name '*.log' \) -delete
