#!/usr/bin/env bash
# What a full recalibration reaches after the slack: the yardstick for online adaptation.
#
# For the default robot as it is before the slack, after the 0.5 mm slip of w3 and after the
# 1 mm creep of the segment-1 cables (the end states of configs/plant-slack-slip.toml and
# configs/plant-slack-creep.toml, applied from t = 0), this does what the shipped accurate pair
# went through (models/README.md): collect a whole dataset, train a TCN forward model, an LSTM
# forward model (tune's judge) and an LSTM inverse model, let `bowden tune` choose newton's
# prior weight for the TCN forward + LSTM inverse pair (base configs/controller-accurate.toml),
# then evaluate on the unseen paths (newton, 3 repeats). Beside it: the shipped accurate pair on
# the same plant. SEEDS trains the LSTM inverse again with other seeds on the same data, each
# tuned and evaluated: the spread of one recalibration. The real-time TCN pair (TCN forward and
# inverse, base configs/controller.toml) is recalibrated beside it.
#
# Usage: docs/results/adapt/oracle.sh [bowden binary]   (from the repository root)
# Environment:
#   OUT           output directory (default out/oracle)
#   SAMPLES       collect --samples (default 8000 ≈ 58,500 commands, the shipped models' amount)
#   COLLECT_SEED  collect --seed (default 2024, what a user gets; the shipped models' dataset was
#                 --samples 7800 --seed 2026)
#   SEEDS         LSTM inverse seeds (default "0")
#   PLANTS        default "default slipped crept"
#   TCN           0 skips the TCN pair
#   SESSIONS      1 runs the sessions below
# Steps already done in OUT are skipped. ≈ 20 min per plant on 2 cores, ≈ 5 min per further
# seed. SESSIONS=1 then starts run.sh's slip and creep sessions (feed-forward, and with
# configs/adapt.toml) from each recalibrated default-robot pair instead of the shipped one.
set -euo pipefail
B=${1:-target/release/bowden}
OUT=${OUT:-out/oracle}
SAMPLES=${SAMPLES:-8000}
[ -x "$B" ] || { echo "oracle.sh: no bowden binary at $B (cargo build --release, or pass its path)" >&2; exit 2; }
for p in ${PLANTS:-default slipped crept}; do
    case $p in default|slipped|crept) ;;
        *) echo "oracle.sh: PLANTS: unknown plant '$p' (default, slipped, crept)" >&2; exit 2 ;;
    esac
done
mkdir -p "$OUT"
sed 's/^at_s = 120.0/at_s = 0.0/' configs/plant-slack-slip.toml > "$OUT/plant-slipped.toml"
# 10 mm/s from t = 0: the creep is at its 1 mm cap within 0.1 s.
sed -e 's/^rate_mm_per_hour = \[6.0, 6.0, 6.0, 6.0,/rate_mm_per_hour = [36000.0, 36000.0, 36000.0, 36000.0,/' \
    -e 's/^start_s = 120.0/start_s = 0.0/' configs/plant-slack-creep.toml > "$OUT/plant-crept.toml"
grep -q '^at_s = 0.0' "$OUT/plant-slipped.toml" && grep -q '^start_s = 0.0' "$OUT/plant-crept.toml" \
    || { echo "the slack plant files changed: update oracle.sh's edits" >&2; exit 1; }
declare -A PLANT=([default]=configs/plant.toml [slipped]=$OUT/plant-slipped.toml [crept]=$OUT/plant-crept.toml)
step() { # log-file command...
    local log=$1; shift
    "$@" > "$log" 2>&1 || { cat "$log"; exit 1; }
}
for p in ${PLANTS:-default slipped crept}; do
    d=$OUT/$p
    mkdir -p "$d/models"
    [ -f "$d/data/dataset.csv" ] || step "$d/collect.log" "$B" collect --samples "$SAMPLES" --seed "${COLLECT_SEED:-2024}" --plant "${PLANT[$p]}" --out "$d/data"
    [ -f "$d/models/tcn_forward_L80.onnx" ] || step "$d/train-tcn.log" "$B" train --arch tcn --direction forward \
        --epochs 400 --early-stop 80 --data "$d/data" --out "$d/models/tcn_forward_L80.onnx"
    [ -f "$d/models/lstm_forward_L80.onnx" ] || step "$d/train-lstm-forward.log" "$B" train --arch lstm \
        --direction forward --epochs 40 --early-stop 10 --data "$d/data" --out "$d/models/lstm_forward_L80.onnx"
    [ -f "$d/shipped/report.json" ] || step "$d/shipped.log" "$B" evaluate --plant "${PLANT[$p]}" \
        --controller-config configs/controller-accurate.toml --controllers uncalibrated,newton --repeats 3 \
        --report "$d/shipped" --force
    for s in ${SEEDS:-0}; do
        inv=$d/models/lstm_inverse_L80_seed$s.onnx
        [ -f "$inv" ] || step "$d/train-lstm-seed$s.log" "$B" train --arch lstm --direction inverse --epochs 40 \
            --early-stop 10 --seed "$s" --data "$d/data" --out "$inv"
        [ -f "$d/controller-seed$s.toml" ] || step "$d/tune-seed$s.log" "$B" tune --data "$d/data" \
            --forward "$d/models/tcn_forward_L80.onnx" --inverse "$inv" --judge "$d/models/lstm_forward_L80.onnx" \
            --modes newton --base configs/controller-accurate.toml --out "$d/controller-seed$s.toml"
        [ -f "$d/recalibrated-seed$s/report.json" ] || step "$d/recalibrated-seed$s.log" "$B" evaluate \
            --plant "${PLANT[$p]}" --controller-config "$d/controller-seed$s.toml" --controllers uncalibrated,newton \
            --repeats 3 --report "$d/recalibrated-seed$s" --force
    done
    if [ "${TCN:-1}" = 1 ]; then # the real-time TCN pair the same way (base configs/controller.toml)
        [ -f "$d/models/tcn_inverse_L80.onnx" ] || step "$d/train-tcn-inverse.log" "$B" train --arch tcn \
            --direction inverse --epochs 400 --early-stop 80 --data "$d/data" --out "$d/models/tcn_inverse_L80.onnx"
        [ -f "$d/controller-tcn.toml" ] || step "$d/tune-tcn.log" "$B" tune --data "$d/data" \
            --forward "$d/models/tcn_forward_L80.onnx" --inverse "$d/models/tcn_inverse_L80.onnx" \
            --judge "$d/models/lstm_forward_L80.onnx" --modes newton --base configs/controller.toml \
            --out "$d/controller-tcn.toml"
        for r in shipped-tcn:configs/controller.toml recalibrated-tcn:$d/controller-tcn.toml; do
            [ -f "$d/${r%%:*}/report.json" ] || step "$d/${r%%:*}.log" "$B" evaluate --plant "${PLANT[$p]}" \
                --controller-config "${r#*:}" --controllers uncalibrated,newton --repeats 3 --report "$d/${r%%:*}" --force
        done
    fi
    echo "$p done"
done
if [ "${SESSIONS:-0}" = 1 ]; then
    d=$OUT/default
    for s in ${SEEDS:-0}; do
        [ -f "$d/controller-seed$s.toml" ] || {
            echo "oracle.sh: SESSIONS=1 needs $d/controller-seed$s.toml: include 'default' in PLANTS" >&2; exit 2; }
    done
    for s in ${SEEDS:-0}; do
        # As long as run.sh's sessions: 5 min past the end of the slack's growth, 3 min more.
        for sc in slip:configs/plant-slack-slip.toml:10 creep:configs/plant-slack-creep.toml:20; do
            IFS=: read -r name plant min <<< "$sc"
            for a in ff adapt; do
                r=$d/session-$name-seed$s-$a
                extra=()
                [ $a = adapt ] && extra=(--adapt configs/adapt.toml)
                [ -f "$r/session.md" ] || step "$r.log" "$B" evaluate --session "$min" --plant "$plant" \
                    --controllers newton --controller-config "$d/controller-seed$s.toml" --window-s 30 \
                    --repeats 3 --report "$r" --force "${extra[@]}"
            done
        done
    done
fi
OUT="$OUT" python3 docs/results/adapt/oracle_table.py
