"""Add the box classifier (the detector's second stage) to the detector's model card.

Usage:
    python scripts/classifier_card.py --run RUN --onnx classifier.onnx --dataset SET
        --eval eval_with.json --eval-without eval_without.json [--eval-more eval_steps4.json]
        [--out DIR] [--command TEXT] [--note TEXT]

RUN is a `dashtraj detector train-classifier` folder (log.jsonl, last.pt); the eval files
are `dashtraj detector eval --json -o` outputs (eval.json) of the same held-out recordings
with and without ``--classifier``; ``--eval-more`` adds rows for more settings of the stage
(e.g. ``--refine-steps 4``; each row named by its JSON's ``refine_steps``). Writes
(replaces) the section "Second stage: box classifier" at the end of DIR/MODEL.md and the key
"classifier" of DIR/MODEL.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

HEADING = "## Second stage: box classifier"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", required=True, type=Path)
    ap.add_argument("--onnx", required=True, type=Path)
    ap.add_argument("--dataset", required=True, type=Path)
    ap.add_argument("--eval", required=True, type=Path)
    ap.add_argument("--eval-without", required=True, type=Path)
    ap.add_argument("--eval-more", type=Path, action="append", default=[])
    ap.add_argument("--out", type=Path, default=Path("src/dashtraj/data/detector"))
    ap.add_argument("--command", default="")
    ap.add_argument("--note", default="")
    args = ap.parse_args(argv)
    from dashtraj.perception.detect import CLASSIFIER_MIN_PROB as MIN_PROB

    log = [json.loads(x) for x in (args.run / "log.jsonl").read_text().splitlines() if x]
    data = args.onnx.read_bytes()
    sha = hashlib.sha256(data).hexdigest()
    ds = json.loads((args.dataset / "dataset.json").read_text())
    ev, ev0 = json.loads(args.eval.read_text()), json.loads(args.eval_without.read_text())
    more = [json.loads(p.read_text()) for p in args.eval_more]
    more_steps = [f"`--refine-steps {e.get('refine_steps', 1)}`" for e in more]
    last = log[-1]
    rows = ["| | mAP50 | mAP50-95 | mAP50 >= 24 px | mAP50-95 >= 24 px |", "|---|---|---|---|---|"]
    steps = ev.get("refine_steps", 1)
    named = [("detector alone", ev0),
             (f"**with the box classifier** ({steps} refining step{'s' * (steps != 1)})", ev)]
    named += [(f"with the box classifier, {st}", e) for st, e in zip(more_steps, more, strict=True)]
    for name, e in named:
        rows.append(f"| {name} | {e['map50']:.3f} | {e['map50_95']:.3f} | {e['map50_24px']:.3f} "
                    f"| {e['map50_95_24px']:.3f} |")
    per = ["| class | AP50 >= 24 px, detector alone | with the box classifier |"
           + "".join(f" {st} |" for st in more_steps),
           "|---|---|---|" + "---|" * len(more)]
    for c, v in ev["per_class_24px"].items():
        v0 = ev0["per_class_24px"].get(c, {}).get("ap50")
        cells = [v0, v["ap50"]] + [e["per_class_24px"].get(c, {}).get("ap50") for e in more]
        per.append(f"| {c} | " + " | ".join("" if x is None else f"{x:.3f}" for x in cells) + " |")
    refine = "iou_after" in last["val"]
    hist = "\n".join(
        f"| {x['epoch']} | {x['loss']:.3f} | {x['val']['acc']:.3f} | {x['val']['vehicle_acc']:.3f} "
        f"| {x['val']['orientation_acc']:.3f} |"
        + (f" {x['val']['bg_recall']:.3f} | {x['val']['fg_as_bg']:.3f} | "
           f"{x['val']['iou_before']:.3f} -> {x['val']['iou_after']:.3f} |" if refine else "")
        for x in log)
    hist_head = ("| epoch | loss | accuracy (15 classes) | vehicle class | orientation |"
                 + (" background called background | vehicles called background | IoU "
                    "with the truth box, before -> after the deltas |" if refine else ""))
    hist_rule = "|---" * (5 + 3 * refine) + "|"
    val_what = "boxes and the detector's proposals" if refine else "boxes"
    counts = ds.get("counts", ds.get("splits", {}))
    extra = ds.get("train_only") or []
    split_text = ("the detector's recordings and split, and "
                  f"{len(extra)} more recordings in train only (`--train-only`: "
                  f"{', '.join(Path(p).name for p in extra)})" if extra
                  else "the detector's recordings and split")
    if refine:
        io = ("output `logits` (N, 16): the 15 classes then background (softmax; a box's "
              "class probabilities sum to 1 minus its background probability), and `deltas` "
              "(N, 4): the moves of the box's x0, y0, x1, y1 in box widths and heights; "
              "metadata `names`, `background` (1), `crop_px`, `input_px`, `margin`. "
              "`YoloDetector(classifier=...)` (`--classifier shipped` on `detect` and "
              "`detector eval`) moves each of a frame's best 100 boxes by its deltas and "
              f"gives it its classes: one box per class of probability >= {MIN_PROB:g} "
              "(`CLASSIFIER_MIN_PROB`), scored "
              "detector score x probability, then class-aware NMS.")
        net = ("average pooling, dropout 0.2, a linear layer for the classes and one for the "
               "deltas")
        what = ("the boxes of the training recordings' frames rendered at 1280x720, every 2 s, "
                "domain-randomized (`dashtraj detection-dataset ... --size 1280x720 "
                f"--randomize`; {split_text}: "
                f"{json.dumps(counts)}): every labelled box, a jittered copy of each (sides "
                "moved by 8 % of the box, normal), up to 3 of the shipped detector's proposals "
                "(score >= 0.01) per vehicle they overlap at IoU >= 0.4, and its best-scoring "
                "proposals that overlap no vehicle at IoU 0.3 (at least 6 a frame, twice the "
                "vehicles) as background. A box is its vehicle's class at IoU >= 0.5, "
                "background below 0.3, neither between; its deltas are learnt at IoU >= 0.4 "
                "(smooth L1 on deltas / 0.1, restated for each training view)")
    else:
        io = ("output `logits` (N, 15) (softmax: the 15 classes' probabilities); metadata "
              "`names`, `crop_px`, `input_px`, `margin`. `YoloDetector(classifier=...)` "
              "(`--classifier shipped` on `detect` and `detector eval`) gives each of a "
              "frame's best 100 boxes its classes: one box per class of probability >= "
              f"{MIN_PROB:g} (`CLASSIFIER_MIN_PROB`), "
              "scored detector score x probability, then class-aware NMS.")
        net = "average pooling, dropout 0.2, a linear layer"
        what = ("every labelled box of the training recordings' frames rendered at 1280x720, "
                "every 2 s, domain-randomized (`dashtraj detection-dataset ... --size 1280x720 "
                f"--randomize`; {split_text}: {json.dumps(counts)})")
    section = f"""{HEADING}

{args.note}

`classifier.onnx` — {len(data) / 1e6:.2f} MB, sha256 `{sha}`. Input `images` (N, 3, 64, 64)
RGB, /255, ImageNet mean/std: each box grown by 25 % of its width and height on every side
(black beyond the frame), squashed to 76 px square, its centre 64 px square; {io}

Network: the EfficientNet-Lite0 stem and first blocks (ImageNet start, every layer
trained), {net} (`dashtraj.train.box_classifier`). Data: {what}. Augmentation: the 64-px
centre drawn at random (58-76 px, rescaled), horizontal flips (a crop's class and
orientation survive a mirror; no traffic side is in a crop), brightness x 0.7-1.3 and
+/- 0.05. Softmax + label smoothing 0.1, AdamW lr 1e-3 cosine, 200 warm-up steps, batch 64.

    {args.command}

Training: {len(log)} epochs, {last['wall_s'] / 60:.1f} min on {open_threads(args.run)} torch
thread(s) (2 shared CPU cores). Validation (the set's val recordings' {val_what}, centre crops):

{hist_head}
{hist_rule}
{hist}

Held-out evaluation (`dashtraj detector eval` on the recordings above, `--every 8`, with and
without `--classifier`):

{chr(10).join(rows)}

{chr(10).join(per)}
"""
    md_path = args.out / "MODEL.md"
    md = md_path.read_text(encoding="utf-8")
    if HEADING in md:
        md = md[:md.index(HEADING)].rstrip() + "\n"
    md_path.write_text(md + "\n" + section, encoding="utf-8")
    jp = args.out / "MODEL.json"
    card = json.loads(jp.read_text(encoding="utf-8"))
    card["classifier"] = {"file": "classifier.onnx", "bytes": len(data), "sha256": sha,
                          "epochs": len(log), "val": last["val"],
                          "heldout": {k: ev[k] for k in ("map50", "map50_95", "map50_24px",
                                                           "map50_95_24px")},
                          "heldout_detector_alone": {k: ev0[k] for k in (
                              "map50", "map50_95", "map50_24px", "map50_95_24px")}}
    for e in more:
        card["classifier"][f"heldout_refine_steps_{e.get('refine_steps', 1)}"] = {
            k: e[k] for k in ("map50", "map50_95", "map50_24px", "map50_95_24px")}
    jp.write_text(json.dumps(card, indent=1) + "\n", encoding="utf-8")
    print(f"{args.out}: classifier.onnx ({len(data) / 1e6:.2f} MB, sha256 {sha[:12]}...) "
          "added to MODEL.md and MODEL.json")
    return 0


def open_threads(run: Path) -> str:
    """The torch thread count a run trained with (its last.pt), or '?'."""
    try:
        import torch

        return str(torch.load(run / "last.pt", map_location="cpu", weights_only=False)
                   .get("threads", "?"))
    except Exception:  # a card still gets written without torch
        return "?"


if __name__ == "__main__":
    raise SystemExit(main())
