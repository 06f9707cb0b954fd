#!/usr/bin/env bash
# Decimated training histories with the paper's protocol (issue #12): `bowden bench transfer
# --config configs/transfer-paper-protocol.toml` (eq. (16) data only, TCNs 30 epochs, tune,
# evaluate on the shipped and the large paths) at several `recipe.decimation`s on the TUNING
# units, then on the HELD-OUT units at 1 (the paper) and at the decimation the config ships.
# Every run of one role reuses the first run's collection (same command, same bytes), so only
# training, tune and evaluate differ between decimations.
#
# Usage: docs/results/paper-protocol/decimation.sh   (from the repository root)
# Environment:
#   BOWDEN       the binary (default target/release/bowden)
#   OUT          work directory (default out/decimation); finished steps there are kept
#   DECIMATIONS  tuning-unit decimations (default "1 2 4 6 8")
#   HELDOUT      held-out decimations (default "1 4")
# Then: docs/results/paper-protocol/decimation.py OUT/tuning-d* > tuning.md (and OUT/heldout-d*).
set -euo pipefail
BOWDEN=${BOWDEN:-target/release/bowden}
OUT=${OUT:-out/decimation}
DECIMATIONS=${DECIMATIONS:-1 2 4 6 8}
HELDOUT=${HELDOUT:-1 4}
CONFIG=configs/transfer-paper-protocol.toml
[ -x "$BOWDEN" ] || { echo "decimation.sh: no bowden binary at $BOWDEN (cargo build --release, or set BOWDEN)" >&2; exit 2; }
[ -f "$CONFIG" ] || { echo "decimation.sh: run from the repository root ($CONFIG not found)" >&2; exit 2; }
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)

run() { # role decimation
    local role=$1 d=$2
    local dir="$OUT/$role-d$d" cfg="$OUT/$role-d$d.toml"
    sed "s/^decimation = .*/decimation = $d/" "$CONFIG" > "$cfg"
    local first="" f
    for f in "$OUT/$role"-d*; do
        [ -d "$f" ] && [ -z "$first" ] && first=$f
    done
    if [ -n "$first" ] && [ "$first" != "$dir" ]; then
        # Share the first run's collection: its data, plant file and stamp (paths rewritten).
        for unit in "$first"/units/*/unit-*; do
            [ -f "$unit/collect.done" ] || continue
            local rel=${unit#"$first"/}
            [ -f "$dir/$rel/collect.done" ] && continue
            mkdir -p "$dir/$rel"
            cp -r "$unit/data" "$unit/plant.toml" "$dir/$rel/"
            sed "s#$first/#$dir/#g" "$unit/collect.done" > "$dir/$rel/collect.done"
        done
    fi
    echo "$role, decimation $d: $dir"
    "$BOWDEN" bench transfer --config "$cfg" --units "$role" --out "$dir" > "$dir.log" 2>&1 \
        || { echo "decimation.sh: $role-d$d failed (see $dir.log)" >&2; tail -n 20 "$dir.log" >&2; exit 1; }
}
for d in $DECIMATIONS; do run tuning "$d"; done
for d in $HELDOUT; do run heldout "$d"; done
