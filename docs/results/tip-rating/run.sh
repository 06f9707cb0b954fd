#!/usr/bin/env bash
# The tip rating of the never-worse choice (`[safety] never_worse_tip`, docs/architecture.md,
# "Safe refinement") on units a `bowden bench transfer` run has already calibrated: for every unit
# of SRC, `bowden tune` again exactly as the benchmark ran it but with never_worse_tip = true in
# its base config, then `bowden evaluate` on the shipped and the large paths as the benchmark
# does. Collection and training are the benchmark's: only the never-worse choice (and what tune
# picks with it) differs, so compare.py can set the two runs side by side.
#
# Usage: docs/results/tip-rating/run.sh SRC OUT   (from the repository root)
#   SRC  a finished `bowden bench transfer --out SRC` directory
#   OUT  where the re-tuned units' evaluations go (finished units are kept)
# Environment: BOWDEN (default target/release/bowden).
# Then: docs/results/tip-rating/compare.py SRC OUT
set -euo pipefail
BOWDEN=${BOWDEN:-target/release/bowden}
[ $# -eq 2 ] || { echo "usage: $0 SRC OUT" >&2; exit 2; }
SRC=${1%/}; OUT=${2%/}
[ -x "$BOWDEN" ] || { echo "run.sh: no bowden binary at $BOWDEN (cargo build --release, or set BOWDEN)" >&2; exit 2; }
[ -d configs/trajectories/large ] || { echo "run.sh: run from the repository root" >&2; exit 2; }
ls -d "$SRC"/units/*/unit-* > /dev/null 2>&1 || { echo "run.sh: $SRC holds no bench transfer units" >&2; exit 2; }
mkdir -p "$OUT"
for u in "$SRC"/units/*/unit-*; do
    name=${u#"$SRC"/units/}
    o=$OUT/units/$name
    mkdir -p "$o"
    [ -f "$u/logs/tune.log" ] || { echo "run.sh: $u has no tune log (unit not finished?)" >&2; exit 1; }
    # The benchmark's own tune command (first line of its log), with the base config swapped.
    cmd=$(head -n 1 "$u/logs/tune.log" | sed 's/^\$ cd [^&]*&& bowden //')
    base=$(sed -E 's/.*--base ([^ ]+).*/\1/' <<< "$cmd")
    tipbase=$OUT/$(basename "$base" .toml)-tip.toml
    grep -q '^never_worse = true' "$base" || { echo "run.sh: $base has no 'never_worse = true'" >&2; exit 1; }
    sed 's/^never_worse = true/never_worse = true\nnever_worse_tip = true/' "$base" > "$tipbase"
    # Written beside the unit's own controller.toml: its model paths are relative to it.
    cmd=$(sed -E "s#--base [^ ]+#--base $tipbase#; s#--out [^ ]+#--out $u/controller-tip.toml --force#" <<< "$cmd")
    # shellcheck disable=SC2086 # the benchmark's arguments, split as it wrote them
    if [ ! -f "$o/tune.done" ]; then
        "$BOWDEN" $cmd > "$o/tune.log" 2>&1 || { echo "run.sh: tune failed for $name (see $o/tune.log)" >&2; exit 1; }
        touch "$o/tune.done"
    fi
    cp "$u/controller-tip.toml" "$o/controller.toml"
    for ev in eval eval-large; do
        [ -f "$o/$ev/summary.json" ] && continue
        extra=()
        [ "$ev" = eval-large ] && extra=(--trajectories-dir configs/trajectories/large)
        "$BOWDEN" evaluate --plant "$u/plant.toml" --controller-config "$u/controller-tip.toml" --repeats 3 \
            --trajectories random,circle,zigzag --controllers uncalibrated,paper,newton "${extra[@]}" \
            --report "$o/$ev" --json-out "$o/$ev/summary.json" > "$o/$ev.log" 2>&1 \
            || { echo "run.sh: evaluate failed for $name (see $o/$ev.log)" >&2; exit 1; }
    done
    echo "$name: $(grep -E '^mode =|^prior_weight =' "$o/controller.toml" | tr '\n' ' ')"
done
