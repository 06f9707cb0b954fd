#!/usr/bin/env bash
# The paper's protocol on the default robot, as a user with bowden runs it: the eq. (16) dataset
# only (1,802 random configurations), the paper's TCN (L = 80) trained in both directions for
# EPOCHS epochs with the best validation epoch kept (the paper, §IV-C: 8,000 epochs), `bowden
# tune` on those two models with the accurate controller as base (Algorithm 1 with the paper's
# M = 50, α = 0.001, Thr = 4; the safe refinement on), then `bowden evaluate` on the unseen paths
# and on the large ones (the paper's magnitude), 5 repeats as the paper.
#
# Usage: docs/results/paper-protocol/run.sh   (from the repository root)
# Environment, one per line:
#   BOWDEN      the binary (default target/release/bowden)
#   OUT         work directory (default out/paper-protocol-e$EPOCHS); steps already done there are kept
#   EPOCHS      training epochs per direction (default 8000, the paper's)
#   EARLY_STOP  stop a training after this many epochs without a better validation RMSE (default: none)
#   DECIMATION  train --decimation (default 1, the paper: consecutive samples only; 4 is what
#               configs/transfer-paper-protocol.toml trains with)
#   REPEATS     evaluation repeats (default 5, the paper's)
# The two trainings run side by side, one thread each.
set -euo pipefail
BOWDEN=${BOWDEN:-target/release/bowden}
EPOCHS=${EPOCHS:-8000}
DECIMATION=${DECIMATION:-1}
SEED=${SEED:-0}
suffix=""
[ "$DECIMATION" = 1 ] || suffix="-d$DECIMATION"
[ "$SEED" = 0 ] || suffix="$suffix-s$SEED"
OUT=${OUT:-out/paper-protocol-e$EPOCHS$suffix}
REPEATS=${REPEATS:-5}
[ -x "$BOWDEN" ] || { echo "run.sh: no bowden binary at $BOWDEN (cargo build --release, or set BOWDEN)" >&2; exit 2; }
mkdir -p "$OUT/models"
step() { # name command...
    local name=$1; shift
    [ -f "$OUT/$name.done" ] && { echo "$name: done before, kept"; return; }
    "$@" > "$OUT/$name.log" 2>&1 || { echo "run.sh: $name failed:" >&2; cat "$OUT/$name.log" >&2; exit 1; }
    touch "$OUT/$name.done"
    echo "$name done"
}
step collect "$BOWDEN" collect --samples 1802 --seed 2024 --excitation paper --out "$OUT/data" --force
es=()
[ -n "${EARLY_STOP:-}" ] && es=(--early-stop "$EARLY_STOP")
for d in forward inverse; do
    step "train-$d" "$BOWDEN" train --arch tcn --direction "$d" --seq-len 80 --epochs "$EPOCHS" "${es[@]}" \
        --decimation "$DECIMATION" --seed "$SEED" --threads 1 --data "$OUT/data" --out "$OUT/models/tcn_${d}_L80.onnx" --force &
done
wait
for d in forward inverse; do [ -f "$OUT/train-$d.done" ] || { echo "run.sh: train-$d failed" >&2; exit 1; }; done
step tune "$BOWDEN" tune --data "$OUT/data" --forward "$OUT/models/tcn_forward_L80.onnx" \
    --inverse "$OUT/models/tcn_inverse_L80.onnx" --base configs/controller-accurate.toml \
    --out "$OUT/controller.toml" --force
step evaluate "$BOWDEN" evaluate --controller-config "$OUT/controller.toml" --repeats "$REPEATS" \
    --report "$OUT/eval" --force
step evaluate-large "$BOWDEN" evaluate --controller-config "$OUT/controller.toml" --repeats "$REPEATS" \
    --trajectories-dir configs/trajectories/large --report "$OUT/eval-large" --force
