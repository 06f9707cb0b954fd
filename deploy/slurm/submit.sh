#!/usr/bin/env bash
# Submits a sharded `bowden sweep`: an array of SHARDS tasks, then the merge, which Slurm starts
# only when every task has succeeded (afterok). Prints the plan first, so the runs, their
# indices and the plan fingerprint (every task's log starts with the same) are on record.
#
#   SWEEP_DATA=/shared/data/sim SWEEP_OUT=/shared/sweeps/fig10 \
#   SWEEP_ARGS="--archs tcn,lstm --seq-lens 10,50,80 --seeds 3 --epochs 30" \
#   deploy/slurm/submit.sh 8
set -euo pipefail

SHARDS=${1:?usage: submit.sh SHARDS [extra sbatch options]}
shift
: "${SWEEP_DATA:?set SWEEP_DATA}" "${SWEEP_OUT:?set SWEEP_OUT}"
export SWEEP_DATA SWEEP_OUT SWEEP_ARGS="${SWEEP_ARGS:-}" BOWDEN="${BOWDEN:-bowden}"
here=$(cd "$(dirname "$0")" && pwd)

mkdir -p "$SWEEP_OUT"
# shellcheck disable=SC2086
$BOWDEN sweep $SWEEP_ARGS --portable-kernels --data "$SWEEP_DATA" --out "$SWEEP_OUT" \
    --plan --json-out "$SWEEP_OUT/plan.json" --force

array=$(sbatch --parsable --export=ALL --array="0-$((SHARDS - 1))" "$@" "$here/sweep.sbatch")
array=${array%%;*} # --parsable prints "jobid[;cluster]"
merge=$(sbatch --parsable --export=ALL --dependency="afterok:$array" \
    --job-name=bowden-sweep-merge --cpus-per-task=1 --output=bowden-sweep-merge-%j.out \
    "$@" "$here/sweep.sbatch" merge)
echo "submitted shards: job array $array (${SHARDS} tasks); merge: job ${merge%%;*} after all succeed"
