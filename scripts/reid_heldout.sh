#!/usr/bin/env bash
# A second evaluation set of the 50 test identities (make reid-heldout, reid_judge.sh), for
# choosing among models without choosing on the first set's own queries: another town (town01;
# the ring set is staged in town10), another camera seed (99) and look seed (99), and moving
# queries from a town01 recording of the test ids (seed 3) into OUT_moving. Each step is skipped
# where its output is there already.
# Usage: [WORKERS=2] scripts/reid_heldout.sh OUT
set -euo pipefail
OUT=$1
D=${DASHTRAJ:-dashtraj}
test -f "${OUT}_moving/meta.json" || $D simulate --town town01 --identities 650-700 \
    --observers 6 --agents 30 --duration 90 --seed 3 -q -o "${OUT}_moving"
test -f "$OUT/reid.json" || $D reid-dataset -o "$OUT" --test-only --town town01 --seed 99 \
    --randomize --randomize-seed 99 --workers "${WORKERS:-2}" --from-recordings "${OUT}_moving"
