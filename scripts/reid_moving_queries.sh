#!/usr/bin/env bash
# The moving-observer queries of a ReID set's 50 test identities (make reid-data, reid_judge.sh):
# two town10 recordings of identities 650-700 (6 observers, 30 agents, 90 s, seeds 1 and 2) into
# DATA_moving1 and DATA_moving2, then `reid moving-queries` into DATA/image_query_moving. Each
# step is skipped where its output is there already.
# Usage: [WORKERS=2] scripts/reid_moving_queries.sh DATA
set -euo pipefail
DATA=$1
D=${DASHTRAJ:-dashtraj}
for s in 1 2; do
  test -f "${DATA}_moving$s/meta.json" || $D simulate --town town10 --identities 650-700 \
      --observers 6 --agents 30 --duration 90 --seed "$s" -q -o "${DATA}_moving$s"
done
test -d "$DATA/image_query_moving" || $D reid moving-queries "$DATA" "${DATA}_moving1" \
    "${DATA}_moving2" --workers "${WORKERS:-2}"
