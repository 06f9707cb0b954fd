#!/usr/bin/env bash
# What the data must contain (issue #12, item 6): the same TCN recipe as `bench transfer`
# (150 epochs, early stop 40, L = 80, tune, evaluate 3 repeats) trained on datasets that differ
# in excitation and size, on TUNING units only (their datasets come from
# `bowden bench transfer --units tuning --out out/study-base`, which also gives the "mixed, all"
# case). Every case is plain bowden commands; the smaller mixed cases are prefixes of the unit's
# mixed collection (the first N commands, re-imported with `bowden import`), i.e. exactly what a
# shorter collection would have recorded, since collection is deterministic. Consecutive samples
# only (`--decimation 1`), as when the study was made: train's default is now `auto`, which
# would decimate the eq. (16) case.
#
#   docs/results/data-study/run.sh out/study-base out/data-study
set -euo pipefail
BASE=${1:-out/study-base}
OUT=${2:-out/data-study}
B=${BOWDEN:-target/release/bowden}
UNITS=${UNITS:-"bouc-wen/unit-11 robot2-capstan/unit-79"}
THREADS=${THREADS:-1}
mkdir -p "$OUT"

case_run() { # unit case datadir
  local unit=$1 name=$2 data=$3 dir=$OUT/$1/$2
  mkdir -p "$dir/models"
  [ -f "$dir/eval/report.json" ] && return 0
  for d in forward inverse; do
    [ -f "$dir/models/tcn_${d}_L80.onnx" ] || "$B" train --arch tcn --direction $d --seq-len 80 --epochs 150 \
      --early-stop 40 --decimation 1 --threads "$THREADS" --data "$data" --out "$dir/models/tcn_${d}_L80.onnx" > "$dir/train-$d.log" 2>&1
  done
  "$B" tune --data "$data" --forward "$dir/models/tcn_forward_L80.onnx" --inverse "$dir/models/tcn_inverse_L80.onnx" \
    --base configs/controller.toml --out "$dir/controller.toml" --force > "$dir/tune.log" 2>&1
  "$B" evaluate --plant "$BASE/units/$unit/plant.toml" --controller-config "$dir/controller.toml" --repeats 3 \
    --trajectories random,circle,zigzag --controllers uncalibrated,paper,newton --report "$dir/eval" > "$dir/evaluate.log" 2>&1
}

for unit in $UNITS; do
  src=$BASE/units/$unit/data
  rows=$(($(wc -l < "$src/dataset.csv") - 1))
  # Prefixes of the mixed collection: 1/2 and 1/4 of its commands.
  for frac in 2 4; do
    n=$((rows / frac)); d=$OUT/$unit/data-mixed-1of$frac
    if [ ! -f "$d/manifest.json" ]; then
      mkdir -p "$OUT/$unit"; head -n $((n + 1)) "$src/dataset.csv" > "$OUT/$unit/prefix.csv"
      "$B" import --csv "$OUT/$unit/prefix.csv" --out "$d" > /dev/null; rm "$OUT/$unit/prefix.csv"
    fi
  done
  # eq. (16) only, with as many commands as the mixed collection (the paper's protocol:
  # 1,802 configurations gave 24,178 commands; 1,650 give about the mixed collection's count).
  d=$OUT/$unit/data-paper
  [ -f "$d/manifest.json" ] || "$B" collect --plant "$BASE/units/$unit/plant.toml" --samples 1650 --seed 2024 \
    --excitation paper --out "$d" > "$OUT/$unit/collect-paper.log" 2>&1
  case_run "$unit" mixed-1of2 "$OUT/$unit/data-mixed-1of2" &
  case_run "$unit" mixed-1of4 "$OUT/$unit/data-mixed-1of4" &
  wait
  case_run "$unit" paper "$d"
done
echo "data study done: $OUT"
