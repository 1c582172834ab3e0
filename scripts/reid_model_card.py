"""Write the model card of a shipped ReID model from its run folder and evaluations.

Usage:
    python scripts/reid_model_card.py RUN_DIR MODEL.onnx CARD.md \\
        --eval ring.json [--eval moving.json] [--note TEXT] [--data-json DATA/reid.json]

RUN_DIR is a `dashtraj reid train` folder (run.json, log.jsonl); each --eval file is the
output of `dashtraj reid eval --json`. The card states the data, recipe, command,
hardware, wall time, sha256 and the evaluation table. For an ensemble (`dashtraj reid
ensemble`), RUN_DIR is its newest member's run and the card lists every member.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("onnx")
    ap.add_argument("card")
    ap.add_argument("--eval", action="append", default=[])
    ap.add_argument("--data-json", default=None)
    ap.add_argument("--note", default="")
    ap.add_argument("--export-command", default="")
    a = ap.parse_args()
    run = Path(a.run)
    info = json.loads((run / "run.json").read_text())
    epochs = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()
              if '"val"' in line]
    onnx = Path(a.onnx).read_bytes()
    sha = hashlib.sha256(onnx).hexdigest()
    r = info["recipe"]
    prog = info.get("progress", {})
    wall = prog.get("train_wall_s") or (epochs[-1]["wall_s"] if epochs else 0.0)
    from dashtraj.reid.embed import ReidEmbedder

    emb = ReidEmbedder(a.onnx, threads=1)
    members = json.loads(emb.metadata["ensemble"]) if "ensemble" in emb.metadata else []
    what = (f"an ensemble of {len(members)} {r['model']} models, "
            + ", ".join(f"{m['input_height']} px" for m in members)
            if members else f"{r['model']}, {r['name']} recipe")
    lines = [f"# {Path(a.onnx).name}: vehicle ReID embedding ({what})",
             "", a.note, "",
             "## Files", "",
             f"- `{Path(a.onnx).name}`: {len(onnx):,} bytes, sha256 `{sha}`"
             + (f" ({emb.metadata['weights_dtype']} weights)" if members else ""),
             "- input `images` (N, 3, "
             f"{emb.height}, {emb.width}) float32 RGB, /255, ImageNet mean/std "
             f"(`dashtraj.reid.preprocess`); output `embedding` (N, {emb.dim}) float32 "
             "(L2-normalised by `dashtraj.reid.embed`)"]
    for i, m in enumerate(members):
        lines.append(f"- member {i + 1}: `{m['file']}` ({m['model']}, {m['input_height']}x"
                     f"{m['input_width']}, {m['feature_dim']}-d, weight {m['weight']:g}), "
                     f"sha256 `{m['sha256']}`")
    lines += ["", "## Data", ""]
    lines.append(f"- training folder: `{info['data']}`: {info['train_images']:,} images of "
                 f"{info['num_classes']} identities (ids {info['class_pids'][0]}–"
                 f"{info['class_pids'][-1]})"
                 + (" with the extra training folders " + ", ".join(
                     f"`{f}`" for f in info["extra_train"]) if info.get("extra_train") else ""))
    if a.data_json:
        d = json.loads(Path(a.data_json).read_text())
        c = d["counts"]
        cfg = d["config"]
        lines.append(f"- evaluation set: `dashtraj reid-dataset` on {cfg['town']}, seed "
                     f"{cfg['seed']}, {cfg['n_cameras']} ring cameras (fixed lens "
                     f"{cfg.get('fov_deg')}° over {cfg.get('image_size')} px), {cfg['n_ids']} "
                     f"ids: train {c['train']['images']:,} images / {c['train']['ids']} ids, "
                     f"query {c['query']['images']}, gallery {c['test']['images']:,} of "
                     f"{c['test']['ids']} test ids"
                     + (f"; moving-observer query {c['query_moving']['images']} crops of "
                        f"{c['query_moving']['ids']} ids" if "query_moving" in c else ""))
        if "train_moving" in c:
            tm = d.get("train_moving", {})
            lines.append(f"- dashcam crops of training ids (`image_train_moving`, `dashtraj reid "
                         f"moving-train`): {c['train_moving']['images']:,} crops of "
                         f"{c['train_moving']['ids']} ids from {len(tm.get('recordings', []))} "
                         f"recordings ({len(tm.get('cameras', []))} moving observers)")
    lines += ["", "## Recipe" + (" (the newest member's run)" if members else ""), "",
              "```json", json.dumps(r, indent=1), "```", "",
              f"- seed {info['seed']}; torch {info['torch']}, {info['threads']} threads",
              f"- epochs done: {prog.get('epochs_done', len(epochs))} of {r['epochs']}; best "
              f"epoch {prog.get('best', {}).get('epoch') if prog.get('best') else '-'}",
              "", "## Command", "", "```", info.get("command") or "", a.export_command, "```",
              "", "## Hardware and wall time", "",
              f"- {platform.machine()} CPU, {os.cpu_count()} cores shared with other jobs "
              "(training, dataset rendering and experiments at once), no GPU",
              f"- training wall time {wall / 3600:.2f} h (steps + per-epoch evaluation)", "",
              "## Evaluation (VeRi-776 protocol: same-id same-camera gallery images "
              "excluded)", "",
              "| set | query set | queries | gallery | rank-1 % | rank-5 % | rank-10 % | mAP % | "
              "mINP % |", "|---|---|---|---|---|---|---|---|---|"]
    for e in a.eval:
        m = json.loads(Path(e).read_text())
        lines.append(f"| `{Path(m['data']).name}` | {m['query']} | {m['queries']} | "
                     f"{m['gallery']} | "
                     f"{100 * m['rank1']:.2f} | {100 * m['rank5']:.2f} | "
                     f"{100 * m['rank10']:.2f} | {100 * m['map']:.2f} | {100 * m['minp']:.2f} |")
    if epochs:
        sets = [q for q in ("image_query", "image_query_moving")
                if any(q in ep["val"] for ep in epochs)]
        lines += ["", "## Validation per epoch", "",
                  "| epoch | loss | train acc % | "
                  + " | ".join(f"{q} rank-1 % | {q} mAP %" for q in sets) + " |",
                  "|---|---|---|" + "---|---|" * len(sets)]
        for ep in epochs:
            cells = []
            for q in sets:
                v = ep["val"].get(q)
                cells += [f"{100 * v['rank1']:.2f}", f"{100 * v['map']:.2f}"] if v else ["-", "-"]
            lines.append(f"| {ep['epoch']} | {ep['loss']:.3f} | {100 * ep['train_acc']:.1f} | "
                         + " | ".join(cells) + " |")
    Path(a.card).write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
