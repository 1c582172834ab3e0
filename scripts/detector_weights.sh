#!/usr/bin/env bash
# Reproduce the shipped detector (src/dashtraj/data/detector/): simulate the training
# recordings, render the YOLO set, train the cpu recipe, export ONNX, evaluate on the
# held-out recordings. Every stage skips work whose output already exists, so a rerun
# resumes (training resumes from DIR/last.pt).
#   usage: scripts/detector_weights.sh [WORK_DIR]   (default runs/detector)
#   env:   DASHTRAJ=path/to/dashtraj  RECIPE=cpu|paper  SEED=0
set -euo pipefail
WORK=${1:-runs/detector}
DT=${DASHTRAJ:-.venv/bin/dashtraj}
RECIPE=${RECIPE:-cpu}
SEED=${SEED:-0}
TOWN01_REAL=${TOWN01_REAL:-../shared/maps/carla/Town01.xodr}
TOWN10_REAL=${TOWN10_REAL:-../shared/maps/carla/Town10HD.xodr}
mkdir -p "$WORK/recs" "$WORK/heldout"
SIM=(--duration 45 --no-until-target-arrives --observers 6 --agents 40 --vehicle-mix balanced
     --vehicle-classes car,truck,bus,motorcycle,bicycle -q)
# training towns: the built-in town01 and town10 and CARLA's real Town01; seeds 100-109
train=()
for town in town01 town10 "$TOWN01_REAL"; do
  tag=$(basename "$town" .xodr)
  for seed in $(seq 100 109); do
    rec="$WORK/recs/${tag}_s${seed}"
    [ -f "$rec/meta.json" ] && grep -q '"complete": true' "$rec/meta.json" \
      || "$DT" simulate --town "$town" --seed "$seed" "${SIM[@]}" -o "$rec"
    train+=("$rec")
  done
done
# held out: seeds 900-901 of the training towns and the real Town10HD (never trained on)
held=()
for town in town01 town10 "$TOWN01_REAL" "$TOWN10_REAL"; do
  tag=$(basename "$town" .xodr)
  for seed in 900 901; do
    rec="$WORK/heldout/${tag}_s${seed}"
    [ -f "$rec/meta.json" ] && grep -q '"complete": true' "$rec/meta.json" \
      || "$DT" simulate --town "$town" --seed "$seed" "${SIM[@]}" -o "$rec"
    held+=("$rec")
  done
done
[ -f "$WORK/dataset/dataset.json" ] \
  || "$DT" detection-dataset "${train[@]}" -o "$WORK/dataset" --every 2.0 --size 640x360 \
       --seed 0 -q
"$DT" detector train "$WORK/dataset" -o "$WORK/train" --recipe "$RECIPE" --seed "$SEED"
"$DT" detector export "$WORK/train/best.pt" -o "$WORK/detector.onnx" --overwrite
"$DT" detector eval "${held[@]}" --model "$WORK/detector.onnx" --json --plot \
  -o "$WORK/eval" --overwrite
