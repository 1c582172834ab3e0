#!/usr/bin/env bash
# Calibrate the ReID track-decision threshold on TRAINING recordings (never the test seeds 0-4):
# four recordings with training seeds and the ReID set's training identities (identity_id < 650),
# perceived with the oracle detector at the experiments' image size, then `dashtraj
# reid-threshold`, which writes M.threshold.json beside the model.
# The decision recipe is reid-threshold's default: query expansion with the query's track, crops
# >= 24 px tall and >= 2 px from the image border; rule far: the highest recall with at most
# MAX_FAR (0.02) of the training negative pairs accepted.
# Usage: [RULE=far|eer|precision] [MAX_FAR=0.02] [SIZE=640x360] scripts/reid_threshold.sh WORK [MODEL.onnx] [LOOK]
# (LOOK: the render look preset the model was trained on, or "" for the renderer default)
set -euo pipefail
WORK=${1:-runs/reid_threshold}
MODEL=${2:-}
LOOK=${3:-}
D=${DASHTRAJ:-dashtraj}
SIZE=${SIZE:-640x360}
WORK="$WORK/look_${LOOK:-default}_$SIZE"   # crops depend on the look and size, not the model
mkdir -p "$WORK"
dbs=()
for spec in town01:900 town10:901 town01:902 town10:903; do
  town=${spec%%:*}; seed=${spec##*:}
  rec="$WORK/rec_${town}_s$seed"
  test -f "$rec/meta.json" || $D simulate --town "$town" --seed "$seed" --identities 0-650 \
      --agents 30 --observers 4 --duration 40 --no-until-target-arrives -q -o "$rec" --overwrite
  db="$WORK/${town}_s$seed.db"
  test -f "$db" || $D perceive "$rec" -o "$db" --detector oracle --size "$SIZE" -q \
      ${LOOK:+--look "$LOOK"}
  dbs+=("$db")
done
$D reid-threshold "${dbs[@]}" ${MODEL:+--model "$MODEL"} --rule "${RULE:-far}" \
    --max-far "${MAX_FAR:-0.02}" --overwrite
