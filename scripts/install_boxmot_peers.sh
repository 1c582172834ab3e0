#!/usr/bin/env bash
# Install BoxMOT (ByteTrack, OC-SORT, BoT-SORT) as tracker peers for `dashtraj tracker eval`
# and bench/bench_perception.py, into the venv given as $1 (default .venv).
#
# boxmot declares torch and torchvision; torchvision has no wheel for the local CPU torch,
# so a plain `pip install boxmot` resolves to CUDA torch (gigabytes). Here: the CPU torch,
# boxmot without its declared dependencies, then the ones its box trackers import.
set -euo pipefail
VENV=${1:-.venv}
"$VENV/bin/pip" install -q torch==2.13.0
"$VENV/bin/pip" install -q --no-deps boxmot==25.0.0
"$VENV/bin/pip" install -q filterpy lapx opencv-python-headless scikit-learn pandas rich \
    click platformdirs tqdm typing-extensions
"$VENV/bin/python" -c "import boxmot; print('boxmot', boxmot.__version__, 'ready')"
