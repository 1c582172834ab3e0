#!/usr/bin/env bash
# Reproduce the shipped detector (src/dashtraj/data/detector/): simulate the training
# recordings, render the YOLO set, train the cpu recipe, export ONNX, evaluate on the
# held-out recordings. Every stage skips work whose output already exists, so a rerun
# resumes (training resumes from DIR/last.pt).
#   usage: scripts/detector_weights.sh [WORK_DIR]   (default runs/detector)
#   env:   DASHTRAJ=path/to/dashtraj  RECIPE=cpu|gpu|paper  SEED=0  EPOCHS=(recipe's)
#          WORKERS=1 (render and loading processes)  TRAIN_SEEDS="100 ... 109"
#          CARD_OUT=src/dashtraj/data/detector (where the model and its card go)
#          STOP_AFTER=N (stop after epoch N of the EPOCHS schedule; rerun without it to go on)
#          CARLA_FRAMES=../shared/carla_frames (scored with eval-external when present)
#          CLASSIFIER_EXTRA_SEEDS="110 ... 119" (more recordings of each training town, all in the box
#          classifier's train split: detection-dataset --train-only; "" for none)
#          CLASSIFIER_EPOCHS=8 (the box classifier's epochs)
#   The shipped gpu model (src/dashtraj/data/detector_gpu):
#          RECIPE=gpu WORKERS=15 TRAIN_SEEDS="$(seq 100 119)" CARD_OUT=src/dashtraj/data/detector_gpu
set -euo pipefail
WORK=${1:-runs/detector}
DT=${DASHTRAJ:-.venv/bin/dashtraj}
RECIPE=${RECIPE:-cpu}
SEED=${SEED:-0}
EPOCHS=${EPOCHS:-}
STOP_AFTER=${STOP_AFTER:-}
WORKERS=${WORKERS:-1}
TRAIN_SEEDS=${TRAIN_SEEDS:-$(seq 100 109)}
CARD_OUT=${CARD_OUT:-src/dashtraj/data/detector}
CARLA_FRAMES=${CARLA_FRAMES:-../shared/carla_frames}
TOWN01_REAL=${TOWN01_REAL:-../shared/maps/carla/Town01.xodr}
TOWN10_REAL=${TOWN10_REAL:-../shared/maps/carla/Town10HD.xodr}
mkdir -p "$WORK/recs" "$WORK/heldout"
SIM=(--duration 45 --no-until-target-arrives --observers 6 --agents 40 --vehicle-mix balanced
     --vehicle-classes car,truck,bus,motorcycle,bicycle -q)
# add_recording ARRAY TOWN SEED DIR: simulate DIR/<town>_s<seed> unless it is there complete,
# and append its path to the array named ARRAY
add_recording() {
  local -n into=$1
  local rec
  rec="$4/$(basename "$2" .xodr)_s$3"
  [ -f "$rec/meta.json" ] && grep -q '"complete": true' "$rec/meta.json" \
    || "$DT" simulate --town "$2" --seed "$3" "${SIM[@]}" -o "$rec" --overwrite
  into+=("$rec")
}
TOWNS=("$TOWN01_REAL" town01 town10)
# training towns: CARLA's real Town01 and the built-in town01 and town10; TRAIN_SEEDS. In this
# order (the recordings' names sorted, as the shipped set was built): the split by recording
# draws its val recordings by position, and so puts Town01 s102/s104, town01 s100/s101 and
# town10 s101/s106 in val, as in the shipped detector's card (the order town01, town10,
# Town01 used here until 2026-12-06 drew others)
train=()
for town in "${TOWNS[@]}"; do
  for seed in $TRAIN_SEEDS; do add_recording train "$town" "$seed" "$WORK/recs"; done
done
# held out (never trained on): seed 900 of each training town, and CARLA's real Town10HD
# (a town never used in training) at seeds 900 and 901
held=()
for spec in "town01 900" "town10 900" "$TOWN01_REAL 900" "$TOWN10_REAL 900" "$TOWN10_REAL 901"; do
  read -r town seed <<< "$spec"
  add_recording held "$town" "$seed" "$WORK/heldout"
done
[ -f "$WORK/dataset/dataset.json" ] \
  || "$DT" detection-dataset "${train[@]}" -o "$WORK/dataset" --every 2.0 --size 640x360 \
       --seed 0 --randomize --randomize-seed 0 -q --workers "$WORKERS"
"$DT" detector train "$WORK/dataset" -o "$WORK/train" --recipe "$RECIPE" --seed "$SEED" \
  ${EPOCHS:+--epochs "$EPOCHS"} ${STOP_AFTER:+--stop-after-epoch "$STOP_AFTER"} \
  --workers $(( WORKERS > 1 ? WORKERS - 1 : 0 ))
"$DT" detector export "$WORK/train/best.pt" -o "$WORK/detector.onnx" --overwrite
"$DT" detector eval "${held[@]}" --model "$WORK/detector.onnx" --every 8 --plot \
  -o "$WORK/eval" --overwrite -q
ext=()
if [ -d "$CARLA_FRAMES/images" ]; then
  "$DT" detector eval-external "$CARLA_FRAMES" --model "$WORK/detector.onnx" \
    --names vehicle,bike,motobike,traffic_light,traffic_sign -o "$WORK/carla" --overwrite -q
  ext=(--external "$WORK/carla/eval.json")
fi
# copy the model into the package with its card (MODEL.md, MODEL.json)
"${PYTHON:-.venv/bin/python}" scripts/detector_card.py --run "$WORK/train" \
  --dataset "$WORK/dataset" --onnx "$WORK/detector.onnx" --eval "$WORK/eval/eval.json" "${ext[@]}" \
  --out "$CARD_OUT"
# the second stage, the refining box classifier (CLASSIFIER=0 skips it): the training
# recordings' frames at 1280x720, every 2 s, domain-randomized; every labelled box, a jittered
# copy, the detector's own proposals (vehicle or background); trained on the same split,
# exported beside the detector, and the held-out recordings scored with it
if [ "${CLASSIFIER:-1}" = 1 ]; then
  CLS_EPOCHS=${CLASSIFIER_EPOCHS:-8}
  extra=()
  for town in "${TOWNS[@]}"; do
    for seed in ${CLASSIFIER_EXTRA_SEEDS-$(seq 110 119)}; do add_recording extra "$town" "$seed" "$WORK/recs"; done
  done
  [ -f "$WORK/set720/dataset.json" ] \
    || "$DT" detection-dataset "${train[@]}" ${extra[@]:+--train-only "${extra[@]}"} \
         -o "$WORK/set720" --every 2.0 --size 1280x720 \
         --seed 0 --randomize --randomize-seed 0 -q --workers "$WORKERS"
  [ -f "$WORK/classifier/classifier.onnx" ] \
    || "$DT" detector train-classifier "$WORK/set720" -o "$WORK/classifier" --seed "$SEED" \
         --refine-with "$WORK/detector.onnx" --epochs "$CLS_EPOCHS" --threads 2
  "$DT" detector eval "${held[@]}" --model "$WORK/detector.onnx" --every 8 \
    --classifier "$WORK/classifier/classifier.onnx" -o "$WORK/eval_classifier" --overwrite -q
  "$DT" detector eval "${held[@]}" --model "$WORK/detector.onnx" --every 8 \
    --classifier "$WORK/classifier/classifier.onnx" --refine-steps 4 \
    -o "$WORK/eval_classifier4" --overwrite -q
  cp "$WORK/classifier/classifier.onnx" "$CARD_OUT/classifier.onnx"
  "${PYTHON:-.venv/bin/python}" scripts/classifier_card.py --run "$WORK/classifier" \
    --onnx "$CARD_OUT/classifier.onnx" --dataset "$WORK/set720" \
    --eval "$WORK/eval_classifier/eval.json" --eval-without "$WORK/eval/eval.json" \
    --eval-more "$WORK/eval_classifier4/eval.json" --out "$CARD_OUT" --command "dashtraj detector train-classifier $WORK/set720 -o $WORK/classifier --seed $SEED --refine-with $WORK/detector.onnx --epochs $CLS_EPOCHS --threads 2"
fi
