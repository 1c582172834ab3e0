#!/usr/bin/env bash
# Judge ReID models on every measure the README's model tables use, from a clean clone: the
# evaluation sets and the end-to-end runs are built once into WORK (and reused by later calls),
# each model is measured into WORK/models/<name>_<sha256[:12]>/, and scripts/reid_judge_table.py
# prints one markdown row per model (the shipped model first where it is among them).
#
# The sets (nothing of the training identities; built with the shipped models where a model is
# needed, the same for every candidate):
#   WORK/veri     make reid-data's test part: the ring query and gallery images of the 50 test
#                 identities (reid-dataset --test-only: the shipped model scores on them as on
#                 the full set) and its moving-observer queries (two town10 recordings, seeds
#                 1 and 2)
#   WORK/veri99   make reid-heldout's set: the test identities in town01, camera and look seeds
#                 99, moving queries from a town01 recording (seed 3)
#   WORK/thr      the threshold calibration's four training recordings (scripts/reid_threshold.sh)
#   WORK/e2e/     `dashtraj experiments` from pixels: ten (seeds 0-4), ten_twins (--twins 3),
#                 dev (seeds 5-9), dev_twins; each model re-scored on the very same perception
#                 (scripts/reid_rescore.py), so the rows differ by the ReID model alone
# Per model: its decision threshold (calibrated on WORK/thr into the model's copy, never beside
# the given file), `reid eval --json` on the ring, moving and whole-vehicle moving queries of
# both sets, and the four re-scorings.
#
# Usage: [E2E=0] [LOOK=preset] [WORKERS=2] scripts/reid_judge.sh WORK MODEL.onnx [MODEL.onnx ...]
# E2E=0 leaves out the end-to-end runs (about two hours of two cores to build, seconds to a
# few minutes a model to re-score); LOOK: the render look the models were trained on ("" the
# default, as the shipped model's). Each step writes its file whole (a temporary name, then a
# rename), so a stopped judge is resumed by running it again.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: [E2E=0] [LOOK=preset] [WORKERS=2] $0 WORK MODEL.onnx [MODEL.onnx ...]" >&2
  exit 2
fi
WORK=$1; shift
for m in "$@"; do
  [ -f "$m" ] || { echo "$0: model $m: no such file" >&2; exit 2; }
done
D=${DASHTRAJ:-dashtraj}
PY=${PYTHON:-$(dirname "$(command -v "$D")")/python}
HERE=$(cd "$(dirname "$0")" && pwd)
W=${WORKERS:-2}
mkdir -p "$WORK/e2e" "$WORK/models"

V=$WORK/veri
test -f "$V/reid.json" || $D reid-dataset -o "$V" --test-only --workers "$W" --randomize \
    --randomize-seed 0
DASHTRAJ=$D WORKERS=$W bash "$HERE/reid_moving_queries.sh" "$V"
H=$WORK/veri99
DASHTRAJ=$D WORKERS=$W bash "$HERE/reid_heldout.sh" "$H"

E2E_SETS="ten:--seeds 0-4|ten_twins:--twins 3 --seeds 0-4|dev:--seeds 5-9"
E2E_SETS+="|dev_twins:--twins 3 --seeds 5-9"
if [ "${E2E:-1}" != 0 ]; then
  IFS='|' read -ra specs <<< "$E2E_SETS"
  for spec in "${specs[@]}"; do
    name=${spec%%:*}; args=${spec#*:}
    # shellcheck disable=SC2086  # args: several words
    test -d "$WORK/e2e/$name" || $D experiments $args -o "$WORK/e2e/$name"
  done
fi

# write FILE from the standard output of a command, whole or not at all
put() { local f=$1; shift; if [ ! -s "$f" ]; then "$@" > "$f.tmp"; mv "$f.tmp" "$f"; fi; }
for m in "$@"; do
  sha=$(sha256sum "$m" | cut -c1-12)
  O=$WORK/models/$(basename "$m" .onnx)_$sha
  mkdir -p "$O"
  if [ ! -f "$O/model.onnx" ]; then
    cp "$m" "$O/model.onnx.tmp"; mv "$O/model.onnx.tmp" "$O/model.onnx"
  fi
  echo "$m" > "$O/source.txt"
  test -f "$O/model.threshold.json" || DASHTRAJ=$D bash "$HERE/reid_threshold.sh" "$WORK/thr" \
      "$O/model.onnx" "${LOOK:-}"
  put "$O/ring.json" $D reid eval --data "$V" --model "$O/model.onnx" --json
  put "$O/moving.json" $D reid eval --data "$V" --model "$O/model.onnx" --json \
      --query image_query_moving
  put "$O/whole.json" $D reid eval --data "$V" --model "$O/model.onnx" --json \
      --query image_query_moving --max-truncation 0
  put "$O/ring99.json" $D reid eval --data "$H" --model "$O/model.onnx" --json
  put "$O/moving99.json" $D reid eval --data "$H" --model "$O/model.onnx" --json \
      --query image_query_moving
  if [ "${E2E:-1}" != 0 ]; then
    for name in ten ten_twins dev dev_twins; do
      put "$O/e2e_$name.json" "$PY" "$HERE/reid_rescore.py" "$WORK/e2e/$name" \
          --reid-model "$O/model.onnx" --json
    done
  fi
done
"$PY" "$HERE/reid_judge_table.py" "$WORK"
