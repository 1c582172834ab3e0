"""`dashtraj reid train|eval|export|average|moving-queries|moving-train|drive-set|embed|query`:
vehicle re-identification (``embed`` and ``query`` on a sightings database run in
`dashtraj.cli.reid_db`)."""

from __future__ import annotations

import argparse
import json
import shlex
import sys


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `reid` command and its sub-commands."""
    from dashtraj.cli._args import fraction, image_size, positive_float, positive_int, seed
    from dashtraj.outputs import add_output_args

    p = subparsers.add_parser(
        "reid",
        help="vehicle re-identification: train, evaluate (VeRi protocol), export to ONNX, "
             "embed a sightings database's crops and query its tracks",
        description="Vehicle re-identification after the paper (§II.E): backbones by name, "
                    "softmax training, VeRi-776 evaluation, ONNX embedding.",
    )
    sub = p.add_subparsers(dest="reid_command", metavar="SUBCOMMAND")
    sub.required = True

    t = sub.add_parser(
        "train", help="train a backbone on a VeRi-layout set (needs the .[train] extra)",
        description="Train (or --resume) a ReID backbone on DATA/image_train with softmax "
                    "cross-entropy (label smoothing; --triplet adds the batch-hard triplet "
                    "loss). Recipes: 'cpu' (efficientnet_lite0 from its ImageNet weights, "
                    "128x128, softmax + triplet, 4 epochs on one CPU thread), 'cpu_osnet' "
                    "(osnet_x0_25 from scratch, 6 epochs), 'gpu' (efficientnet_lite0, every "
                    "layer trained, batch 128, 30 epochs) and 'paper' (Table I: Adam 3e-4, "
                    "256x256, 60 epochs); it trains on a GPU when torch sees one (--device). "
                    "The run folder holds last.pt (resumable), best.pt, log.jsonl, "
                    "curves.png and run.json.")
    t.add_argument("data", metavar="DATA", help="VeRi-layout folder (reid-dataset output)")
    t.add_argument("-o", "--output", required=True, metavar="DIR", help="run folder")
    t.add_argument("--recipe", default="cpu", help="cpu, cpu_osnet, gpu or paper (default cpu)")
    t.add_argument("--device", default="auto", metavar="DEV",
                   help="auto (a GPU when torch sees one, else the CPU), cpu, cuda or cuda:N "
                        "(default auto)")
    t.add_argument("--model", default=None,
                   help="backbone name (default: the recipe's; see dashtraj.reid.models)")
    t.add_argument("--seed", type=seed, default=0, help="seed (default 0)")
    t.add_argument("--epochs", type=positive_int, default=None, help="override the recipe's epochs")
    t.add_argument("--batch-size", type=positive_int, default=None, help="override the batch size")
    t.add_argument("--lr", type=positive_float, default=None, help="override the learning rate")
    t.add_argument("--size", type=image_size, default=None, metavar="WxH",
                   help="override the recipe's input size (e.g. 160x160); with --init M.onnx "
                        "of another size, fine-tunes that model at this one")
    t.add_argument("--triplet", action="store_true", help="add the batch-hard triplet loss")
    t.add_argument("--lowres", type=fraction, default=None, metavar="P",
                   help="shrink this share of the training images to 12-48 px high and back "
                        "(dashcam crops are that small; default: the recipe's, 0)")
    t.add_argument("--truncate", type=fraction, default=None, metavar="P",
                   help="cut this share of the training images at one border (10-70 %% of "
                        "the width or height) and stretch the rest back, as a vehicle partly "
                        "outside a dashcam's frame is cropped (default: the recipe's, 0)")
    t.add_argument("--erasing", type=fraction, default=None, metavar="P",
                   help="random erasing: paint one random rectangle (2-40 %% of the area) of "
                        "this share of the training images the mean colour (default: the "
                        "recipe's, 0)")
    t.add_argument("--group-batches", type=fraction, default=None, metavar="P",
                   help="with the triplet loss: draw this share of the identities' image "
                        "groups into batches of one colour (reid.json's identity keys), so "
                        "the hardest negatives differ by shape alone (default: the recipe's, 0)")
    t.add_argument("--resume", action="store_true", help="continue the run in DIR")
    t.add_argument("--init", default=None, metavar="CKPT.pt|M.onnx",
                   help="start from another run's weights (a second stage with its own "
                   "schedule, e.g. --epochs 3 --lr 1e-3), or from an exported model (the "
                   "shipped ONNX: its folded BatchNorms are rebuilt, its classifier fitted "
                   "to the training images' embeddings)")
    t.add_argument("--extra-train", action="append", default=[], metavar="FOLDER",
                   help="another folder of DATA whose images join image_train's (repeatable; "
                        "e.g. image_train_moving from 'dashtraj reid moving-train')")
    t.add_argument("--extra-max-truncation", type=fraction, default=None, metavar="F",
                   help="only the --extra-train images whose vehicle lies at most F (0..1) "
                        "outside its camera's frame, by the crop labels beside each folder "
                        "(labels_<stem>.csv; default: all)")
    t.add_argument("--overwrite", action="store_true", help="start afresh in a non-empty DIR")
    t.add_argument("--max-hours", type=positive_float, default=None,
                   help="stop (resumable) after this many hours of this call")
    t.add_argument("--threads", type=positive_int, default=None,
                   help="torch threads (default: all)")
    t.add_argument("--json", action="store_true", help="print the summary as JSON")
    t.set_defaults(func=run_train)

    e = sub.add_parser(
        "eval", help="evaluate an ONNX model on a VeRi-layout folder (VeRi-776 protocol)",
        description="Embed the query set and the gallery (image_test) of a VeRi-layout folder "
                    "and report CMC rank-1/5/10, mAP and mINP; gallery images of the query's "
                    "identity from the query's camera are excluded (VeRi's rule). Works on "
                    "the real VeRi-776 too.")
    e.add_argument("--data", required=True, metavar="DIR", help="VeRi-layout folder")
    e.add_argument("--model", default=None, metavar="M.onnx",
                   help="ONNX model (default: the shipped one)")
    e.add_argument("--query", default="image_query", choices=("image_query",
                                                              "image_query_moving"),
                   help="query folder (default image_query)")
    e.add_argument("--max-truncation", type=fraction, default=None, metavar="F",
                   help="only the queries whose vehicle lies at most F (0..1) outside the "
                        "camera's frame, by the crop labels beside a moving-observer query "
                        "set (labels_query_moving.csv); 0: whole vehicles, as the pipeline's "
                        "ReID uses (default: every query)")
    e.add_argument("--threads", type=positive_int, default=2,
                   help="onnxruntime threads (default 2)")
    e.add_argument("--flip", action="store_true",
                   help="test-time augmentation: embed every image and its mirror image, "
                        "sum the two (twice the compute)")
    e.add_argument("--rerank", action="store_true",
                   help="k-reciprocal re-ranking (Zhong et al. 2017) of the distances; the "
                        "figures without it are reported beside")
    e.add_argument("--rerank-k1", type=positive_int, default=20, metavar="K1",
                   help="re-ranking: k-reciprocal neighbourhood (default 20)")
    e.add_argument("--rerank-k2", type=positive_int, default=6, metavar="K2",
                   help="re-ranking: neighbours of the local query expansion (default 6)")
    e.add_argument("--rerank-lambda", type=fraction, default=0.3, metavar="L",
                   help="re-ranking: weight of the original distance, 0..1 (default 0.3)")
    e.add_argument("--errors", action="store_true",
                   help="also list the rank-1 errors: each query whose nearest gallery image "
                        "is another identity, that image, the rank of the first true match, "
                        "and both identities' catalog keys when the folder has a reid.json "
                        "(JSON: rank1_errors, confusions)")
    e.add_argument("--json", action="store_true", help="print the figures as JSON")
    e.set_defaults(func=run_eval)

    m = sub.add_parser(
        "moving-queries",
        help="add image_query_moving/ to a reid-dataset set from recordings",
        description="Crops of the set's test identities seen by the moving observers of "
                    "recordings (e.g. 'dashtraj simulate --identities 650-700') become "
                    "DATA/image_query_moving/ and name_query_moving.txt (the paper never "
                    "measured this query set); reid.json gets their counts and cameras.")
    _moving_arguments(m, "test")

    mt = sub.add_parser(
        "moving-train",
        help="add image_train_moving/ (training ids seen from dashcams) to a reid-dataset set",
        description="Crops of the set's TRAINING identities seen by the moving observers of "
                    "recordings (e.g. 'dashtraj simulate --identities 0-650') become "
                    "DATA/image_train_moving/ and name_train_moving.txt, for 'dashtraj reid "
                    "train --extra-train image_train_moving' (the dashcam's eye-level views "
                    "and streets, which the ring cameras lack); reid.json gets their counts, "
                    "cameras and recordings under \"train_moving\". Test identities in the "
                    "recordings are skipped and counted.")
    _moving_arguments(mt, "train")

    ds = sub.add_parser(
        "drive-set",
        help="a VeRi-layout ReID set from drives with truth.csv (CARLA's own frames)",
        description="Every vehicle of the drives (carla-record's, or render's) is an "
                    "identity, every observer a camera: crops of their truth boxes (mostly "
                    "visible, tall enough) become image_train/ or, for --test-fraction of "
                    "the identities, image_query/ and image_test/ (about a tenth of each test "
                    "id's cameras as queries), with name_*.txt and reid.json; 'dashtraj reid "
                    "eval --data OUT' scores a model on CARLA's images, 'reid train' learns "
                    "from them.")
    ds.add_argument("drives", nargs="+", metavar="DRIVE", help="drive folders with truth.csv")
    ds.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    _drive_set_arguments(ds)
    add_output_args(ds)
    ds.set_defaults(func=run_drive_set)

    x = sub.add_parser(
        "export", help="export a checkpoint (best.pt) to ONNX (needs the .[train] extra)",
        description="Write the embedding network of a training checkpoint as ONNX "
                    "(dynamic batch, fixed input size, metadata with the recipe).")
    x.add_argument("checkpoint", metavar="CKPT", help="best.pt or last.pt of a run")
    x.add_argument("-o", "--output", required=True, metavar="M.onnx", help="ONNX file")
    add_output_args(x)
    x.add_argument("--fp16-weights", action="store_true",
                   help="store the weights as float16 (half the file; float32 arithmetic)")
    x.add_argument("--json", action="store_true", help="print the summary as JSON")
    x.set_defaults(func=run_export)

    a = sub.add_parser(
        "average", help="average the weights of checkpoints of one run (stochastic weight "
                        "averaging; needs the .[train] extra)",
        description="Write the mean of two or more checkpoints of one network (a run's "
                    "best.pt or last.pt; e.g. the ends of successive training stages, each "
                    "continued from the last) as a checkpoint that 'reid export' takes: "
                    "every weight and BatchNorm statistic averaged (stochastic weight "
                    "averaging, Izmailov et al. 2018). The averaged network has the same "
                    "size and speed.")
    a.add_argument("checkpoints", nargs="+", metavar="CKPT", help="best.pt or last.pt files")
    a.add_argument("-o", "--output", required=True, metavar="OUT.pt", help="checkpoint file")
    add_output_args(a)
    a.add_argument("--json", action="store_true", help="print the summary as JSON")
    a.set_defaults(func=run_average)

    en = sub.add_parser(
        "ensemble", help="join exported models into one ONNX model (their embeddings "
                         "concatenated; needs onnx)",
        description="Write one ONNX model that runs every given 'reid export' model on one "
                    "input (the largest member's size; a smaller member reads it resized, "
                    "linear and antialiased) and concatenates their L2-normalised embeddings, "
                    "each scaled by the square root of its share of the weights: the squared "
                    "distance of two embeddings is the weighted mean of the members'. Models "
                    "trained at different input sizes err differently; an ensemble of them "
                    "ranks better than either and costs the members' time together.")
    en.add_argument("models", nargs="+", metavar="M.onnx", help="two or more exported models")
    en.add_argument("-o", "--output", required=True, metavar="OUT.onnx", help="ONNX file")
    en.add_argument("--weights", type=_weights, default=None, metavar="W1,W2,...",
                    help="one positive weight per model (default equal)")
    en.add_argument("--int8-weights", action="store_true",
                    help="store the weights as int8, one scale per output channel (half of "
                         "float16's file; float32 arithmetic); default float16")
    add_output_args(en)
    en.add_argument("--json", action="store_true", help="print the summary as JSON")
    en.set_defaults(func=run_ensemble)

    mb = sub.add_parser(
        "member", help="write one member of an ensemble as a standalone model (needs onnx)",
        description="Write member N (1-based, in the order 'reid ensemble' took them) of an "
                    "ensemble as the standalone ONNX model it was: its input size, nodes and "
                    "metadata, its weights as the ensemble stores them (float32). 'reid eval' "
                    "scores it alone, 'reid train --init' trains it on.")
    mb.add_argument("ensemble", metavar="ENS.onnx", help="an ensemble of 'reid ensemble'")
    mb.add_argument("index", type=positive_int, metavar="N", help="member number, from 1")
    mb.add_argument("-o", "--output", required=True, metavar="M.onnx", help="ONNX file")
    add_output_args(mb)
    mb.add_argument("--json", action="store_true", help="print the summary as JSON")
    mb.set_defaults(func=run_member)

    from dashtraj.cli.reid_db import register_db_commands

    register_db_commands(sub)


def _need(module: str, install: str) -> None:
    """DashtrajError telling how to install ``module`` when it is missing."""
    import importlib.util

    from dashtraj.errors import DashtrajError

    if importlib.util.find_spec(module) is None:  # looks, does not import it
        raise DashtrajError(f"this command needs {module}: {install}")


def _need_torch() -> None:
    _need("torch", "pip install -e '.[train]'")


def _need_onnx() -> None:
    _need("onnx", "pip install onnx (or -e '.[train]')")


def _written(output: str, meta: dict) -> dict:
    """The summary of an ONNX file a command wrote: path, size, sha256 and ``meta``."""
    import hashlib
    from pathlib import Path

    data = Path(output).read_bytes()
    return {"output": output, "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest(),
            **meta}


def _size_overrides(size: str | None) -> dict:
    """``--size WxH`` as recipe fields (none without it)."""
    if size is None:
        return {}
    from dashtraj.datasets.frames import parse_size

    w, h = parse_size(size)
    return {"height": h, "width": w}


def run_train(args: argparse.Namespace) -> int:
    """Train or resume; prints the best validation figures; returns 0."""
    import os

    # Idle OpenMP threads sleep instead of spinning: on a shared, oversubscribed CPU
    # spinning threads made training 10x slower (measured: 4 vs 40-65 img/s, 2 threads).
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    _need_torch()
    from dashtraj.reid.train import recipe_for, train

    recipe = recipe_for(args.recipe, args.model, epochs=args.epochs, batch_size=args.batch_size,
                        lr=args.lr, triplet=True if args.triplet else None,
                        lowres=args.lowres, truncate=args.truncate,
                        erasing=args.erasing, group_batches=args.group_batches,
                        **_size_overrides(args.size))
    cmd = "dashtraj " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    s = train(args.data, args.output, recipe, seed=args.seed, resume=args.resume,
              overwrite=args.overwrite, max_hours=args.max_hours, threads=args.threads,
              command=cmd, init=args.init, extra_train=tuple(args.extra_train),
              device=args.device, init_any_size=args.size is not None,
              extra_max_truncation=args.extra_max_truncation,
              log=lambda m: print(m, flush=True))
    best = s["best"]
    if args.json:
        print(json.dumps({k: s[k] for k in ("epochs_done", "finished", "train_wall_s", "best",
                                            "history")}))
    else:
        print(f"{args.output}: {s['epochs_done']}/{recipe.epochs} epochs of {recipe.model} "
              f"({recipe.name} recipe) in {s['train_wall_s'] / 60:.1f} min; best epoch "
              f"{best['epoch'] if best else '-'} (rank-1, mAP) = "
              f"{tuple(round(v, 4) for v in best['key']) if best else '-'}")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    """VeRi-protocol evaluation of an ONNX model; prints the figures; returns 0."""
    import time

    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.reid.evaluate import (
        VeriLayoutError,
        evaluate_features,
        has_true_match,
        identity_keys,
        open_veri,
        within_truncation,
    )

    q, g = open_veri(args.data, args.query)
    keys = identity_keys(args.data) if args.errors else {}
    n_all = len(q)
    if args.max_truncation is not None:
        try:
            q = within_truncation(args.data, q, args.query, args.max_truncation)
        except VeriLayoutError as exc:
            raise VeriLayoutError(f"--max-truncation: {exc}") from None
        if not len(q):
            raise VeriLayoutError(f"--max-truncation {args.max_truncation:g}: no query of "
                                  f"{args.query} is within it")
    if not has_true_match(q, g).any():  # before embedding: nothing to rank
        raise VeriLayoutError(f"--data {args.data}: no query of {args.query} has an image of "
                              "its identity from another camera in the gallery (VeRi's rule "
                              "excludes the query's own camera): nothing to rank")
    emb = ReidEmbedder(args.model, threads=args.threads, flip=args.flip)
    t0 = time.time()
    gf = emb.embed(g.paths)
    qf = emb.embed(q.paths)
    dt = time.time() - t0
    rerank = ({"k1": args.rerank_k1, "k2": args.rerank_k2, "lambda_value": args.rerank_lambda}
              if args.rerank else None)
    r = evaluate_features(qf, gf, q, g, rerank=rerank, errors=args.errors)
    plain = r["without_rerank"] if rerank else r
    figures = ("rank1", "rank5", "rank10", "map", "minp")
    out = {"data": args.data, "query": args.query, "model": str(emb.path), "flip": emb.flip,
           "rerank": rerank, **{k: r[k] for k in figures}, "queries": r["queries"],
           "skipped_queries": r["skipped"], "gallery": len(g),
           "query_ids": len(set(q.pids.tolist())), "max_truncation": args.max_truncation,
           "truncated_queries_left_out": n_all - len(q),
           "embed_crops_per_s": (len(q) + len(g)) / max(dt, 1e-9)}
    if rerank:
        out["without_rerank"] = {k: plain[k] for k in figures}
    if args.errors:
        errs = [{**e, "query_key": keys.get(e["query_id"]),
                 "nearest_key": keys.get(e["nearest_id"])} for e in r["rank1_errors"]]
        out["rank1_errors"] = errs
        out["confusions"] = _confusions(errs, bool(keys))
    if args.json:
        print(json.dumps(out))
        return 0

    def line(x: dict) -> str:
        return (f"rank-1 {100 * x['rank1']:.2f} %, rank-5 {100 * x['rank5']:.2f} %, rank-10 "
                f"{100 * x['rank10']:.2f} %, mAP {100 * x['map']:.2f} %, mINP "
                f"{100 * x['minp']:.2f} %")

    cut = (f", {n_all - len(q)} more than {args.max_truncation:g} outside the frame left out"
           if args.max_truncation is not None else "")
    print(f"{args.data} ({args.query}, {r['queries']} queries{cut}, {len(g)} gallery): "
          + line(r) + (f" ({r['skipped']} queries without a match from another camera "
                       "skipped)" if r["skipped"] else ""))
    if rerank:
        print(f"  re-ranked (k1 {args.rerank_k1}, k2 {args.rerank_k2}, lambda "
              f"{args.rerank_lambda}); without re-ranking: " + line(plain))
    if args.errors:
        print(f"rank-1 errors: {len(out['rank1_errors'])} of {r['queries']} queries")
        for e in out["rank1_errors"]:
            who = (f" ({e['query_key']} -> {e['nearest_key']})" if keys else "")
            print(f"  {e['query']} -> {e['nearest']}{who}, distance {e['distance']:.4f}; first "
                  f"true match at rank {e['true_rank']} ({e['true_distance']:.4f})")
        if out["confusions"]:
            print("most confused (query -> nearest: errors): " + "; ".join(
                f"{c['query']} -> {c['nearest']}: {c['errors']}" for c in out["confusions"][:10]))
    return 0


def _confusions(errors: list[dict], by_key: bool) -> list[dict]:
    """Rank-1 errors counted per (query identity, nearest identity), most first: by catalog
    key when the set has them, else by id."""
    from collections import Counter

    field = "key" if by_key else "id"
    n = Counter((e[f"query_{field}"], e[f"nearest_{field}"]) for e in errors)
    return [{"query": a, "nearest": b, "errors": k}
            for (a, b), k in sorted(n.items(), key=lambda kv: (-kv[1], str(kv[0])))]


def run_export(args: argparse.Namespace) -> int:
    """Export a checkpoint to ONNX; prints size and sha256; returns 0."""
    _need_torch()
    from dashtraj.outputs import atomic_output
    from dashtraj.train.reid_export import export_onnx

    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        meta = export_onnx(args.checkpoint, tmp, fp16=args.fp16_weights)
    info = _written(args.output, meta)
    if args.json:
        print(json.dumps(info))
    else:
        print(f"{args.output}: {meta['model']} {meta['input_height']}x{meta['input_width']}, "
              f"{info['bytes'] / 1e6:.2f} MB, sha256 {info['sha256'][:16]}...")
    return 0


def run_average(args: argparse.Namespace) -> int:
    """Average checkpoints into one; prints what it averaged; returns 0."""
    _need_torch()
    from dashtraj.outputs import atomic_output
    from dashtraj.train.reid_average import write_average

    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        ck = write_average(args.checkpoints, tmp)
    info = {"output": args.output, "averaged_from": ck["averaged_from"],
            "model": ck["recipe"]["model"]}
    if args.json:
        print(json.dumps(info))
    else:
        print(f"{args.output}: the mean of {len(ck['averaged_from'])} {info['model']} "
              "checkpoints (" + ", ".join(a["path"] for a in ck["averaged_from"]) + ")")
    return 0


def _weights(text: str) -> list[float]:
    """``--weights W1,W2,...``: positive numbers."""
    from dashtraj.cli._args import positive_float

    return [positive_float(t) for t in text.split(",")]


def run_ensemble(args: argparse.Namespace) -> int:
    """Join exported models into one ONNX file; prints its size and sha256; returns 0."""
    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import atomic_output

    _need_onnx()
    from dashtraj.train.reid_ensemble import build_ensemble

    if args.weights is not None and len(args.weights) != len(args.models):
        raise DashtrajError(f"--weights: {len(args.weights)} weights for "
                            f"{len(args.models)} models")
    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        meta = build_ensemble(args.models, tmp, args.weights, int8=args.int8_weights)
    info = {**_written(args.output, meta), "ensemble": json.loads(meta["ensemble"])}
    if args.json:
        print(json.dumps(info))
    else:
        print(f"{args.output}: {meta['model']}, input {meta['input_width']}x"
              f"{meta['input_height']}, {meta['feature_dim']}-d, {meta['weights_dtype']} "
              f"weights, {info['bytes'] / 1e6:.2f} MB, sha256 {info['sha256'][:16]}...")
    return 0


def run_member(args: argparse.Namespace) -> int:
    """Write one member of an ensemble as a standalone model; returns 0."""
    from dashtraj.outputs import atomic_output

    _need_onnx()
    from dashtraj.train.reid_ensemble import extract_member

    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        meta = extract_member(args.ensemble, args.index, tmp)
    info = _written(args.output, meta)
    if args.json:
        print(json.dumps(info))
    else:
        print(f"{args.output}: member {args.index} of {args.ensemble}, {meta.get('model')} "
              f"{meta.get('input_height')}x{meta.get('input_width')}, "
              f"{info['bytes'] / 1e6:.2f} MB, sha256 {info['sha256'][:16]}...")
    return 0


def _drive_set_arguments(p: argparse.ArgumentParser) -> None:
    from dashtraj.cli._args import (
        fraction,
        int_at_least,
        non_negative_float,
        positive_float,
        seed,
    )
    from dashtraj.datasets.reid import DriveReidConfig

    c = DriveReidConfig()
    p.add_argument("--every", type=positive_float, default=c.every_s, metavar="S",
                   help=f"sampling period, seconds (default {c.every_s:g})")
    p.add_argument("--size", type=int_at_least(16), default=c.size, metavar="PX",
                   help=f"crop long side (default {c.size})")
    p.add_argument("--min-box-height", type=non_negative_float, default=c.min_box_height_px,
                   metavar="PX", help=f"smallest box kept (default {c.min_box_height_px:g})")
    p.add_argument("--min-visible", type=fraction, default=c.min_visible_fraction,
                   help=f"smallest visible fraction kept (default {c.min_visible_fraction:g})")
    p.add_argument("--test-fraction", type=fraction, default=c.test_fraction,
                   help=f"share of identities held out (default {c.test_fraction:g})")
    p.add_argument("--seed", type=seed, default=c.seed, help="split seed (default 0)")
    p.add_argument("--json", action="store_true", help="print the counts as JSON")


def run_drive_set(args: argparse.Namespace) -> int:
    """Write a VeRi-layout set from drives with truth; prints the counts; returns 0."""
    from pathlib import Path

    from dashtraj.datasets.drive import Drive, open_with_truth
    from dashtraj.datasets.frames import DatasetError
    from dashtraj.datasets.reid import DriveReidConfig, drive_reid_set
    from dashtraj.outputs import atomic_output, check_output

    out = check_output(args.output, overwrite=args.overwrite, kind="dir")
    drives, seen = [], {}
    for p in args.drives:  # one drive twice would make each of its vehicles two identities
        key = Path(p).resolve()
        if key in seen:
            raise DatasetError(f"drive {p} is given twice (also as {seen[key]}); each drive "
                               "once, or its vehicles become two identities each")
        seen[key] = p
        d = open_with_truth(p, "no identities for a ReID set", DatasetError)
        if not isinstance(d, Drive):
            raise DatasetError(f"{p} is a simulated recording, not a drive (reid-dataset "
                               "builds sets from recordings)")
        drives.append(d)
    cfg = DriveReidConfig(every_s=args.every, size=args.size, margin=0.1,
                          min_visible_fraction=args.min_visible,
                          min_box_height_px=args.min_box_height,
                          test_fraction=args.test_fraction, seed=args.seed)
    with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
        info = drive_reid_set(drives, tmp, cfg)
    if args.json:
        print(json.dumps(info["counts"]))
    else:
        c = info["counts"]
        print(f"{out}: {len(info['identities'])} identities, {len(info['cameras'])} cameras; "
              + ", ".join(f"{s} {c[s]['images']} images of {c[s]['ids']} ids" for s in c))
    return 0


def _moving_arguments(p: argparse.ArgumentParser, split: str) -> None:
    """The arguments of ``moving-queries`` (split "test") and ``moving-train`` ("train")."""
    from dashtraj.cli._args import positive_float, positive_int

    p.add_argument("data", metavar="DATA", help="a reid-dataset output folder (with reid.json)")
    p.add_argument("recordings", nargs="+", metavar="RUN", help="recording directories")
    p.add_argument("--every", type=positive_float, default=None, metavar="S",
                   help="sampling period, seconds (default: the set's, 0.5)")
    p.add_argument("--overwrite", action="store_true",
                   help=f"replace an existing {'query' if split == 'test' else 'training'} set")
    if split == "train":
        p.add_argument("--append", action="store_true",
                       help="add the recordings' crops to the existing image_train_moving "
                            "(cameras and recording numbers continue; the result equals one "
                            "run over the earlier recordings and these)")
    p.add_argument("--workers", type=positive_int, default=1, metavar="N",
                   help="recordings rendered at once, each in its own process (default 1; "
                        "the same crops)")
    p.add_argument("--json", action="store_true", help="print the counts as JSON")
    p.set_defaults(func=run_moving, split=split, append=False)


def run_moving(args: argparse.Namespace) -> int:
    """Add the moving-observer query set (``split`` "test") or training crops ("train")
    to a reid-dataset folder; returns 0."""
    import dataclasses
    import tempfile
    from pathlib import Path

    from dashtraj.datasets.reid import (
        MOVING_STEMS,
        MOVING_TRAIN_FIRST_CAM,
        ReidConfig,
        moving_crops,
        moving_labels_path,
    )
    from dashtraj.outputs import replace_together
    from dashtraj.reid.evaluate import VeriLayoutError
    from dashtraj.world.recording import Recording

    split = args.split
    stem = MOVING_STEMS[split]
    root = Path(args.data)
    meta_path = root / "reid.json"
    if not meta_path.is_file():
        raise VeriLayoutError(f"{root}: no reid.json (not a 'dashtraj reid-dataset' folder)")
    try:
        info = json.loads(meta_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise VeriLayoutError(f"{meta_path} is not valid JSON: {exc}") from None
    if not (isinstance(info, dict) and isinstance(info.get("config"), dict)):
        raise VeriLayoutError(f"{meta_path} has no \"config\" object (not a 'dashtraj "
                              "reid-dataset' folder)")
    dest = root / f"image_{stem}"
    if args.append and args.overwrite:
        raise VeriLayoutError("--append and --overwrite: choose one")
    if dest.exists() and not (args.overwrite or args.append):
        raise VeriLayoutError(f"{dest} exists; --overwrite replaces it"
                              + (", --append adds to it" if split == "train" else ""))
    names = {f.name for f in dataclasses.fields(ReidConfig)}
    cfg_d = {k: (tuple(v) if isinstance(v, list) else v)
             for k, v in info["config"].items() if k in names and k != "recordings"}
    if args.every is not None:
        cfg_d["every_s"] = args.every
    prev = info.get("train_moving") if args.append else None
    if args.append:
        if prev is None or not dest.is_dir():
            raise VeriLayoutError(f"--append: {root} has no image_train_moving to add to "
                                  "(run without --append first)")
        if args.every is not None and args.every != prev["every_s"]:
            raise VeriLayoutError(f"--every {args.every}: {dest} was sampled every "
                                  f"{prev['every_s']} s")
        cfg_d["every_s"] = prev["every_s"]
    try:
        cfg = ReidConfig(**cfg_d)
    except (TypeError, ValueError) as exc:
        raise VeriLayoutError(f"{meta_path}: bad config: {exc}") from None
    recs = [Recording.open(p) for p in args.recordings]
    first = {}
    if prev is not None:
        had = {Path(r).resolve() for r in prev["recordings"]}
        again = [str(r.path) for r in recs if Path(r.path).resolve() in had]
        if again:
            raise VeriLayoutError(f"--append: {again[0]} is already in {dest}")
        first = {"first_cam": max((c["cam"] for c in prev["cameras"]),
                                  default=MOVING_TRAIN_FIRST_CAM - 1) + 1,
                 "first_recording": len(prev["recordings"])}
    with tempfile.TemporaryDirectory(dir=root, prefix=".moving-") as tmp:
        staged = Path(tmp)
        res = moving_crops(recs, tmp, cfg, split, workers=args.workers, **first)
        if prev is not None:  # the earlier crops join the new ones in the staged folder
            res = _merge_moving(dest, staged, split, info, res)
        info["counts"][stem] = res["counts"]
        if split == "test":
            info["moving_cameras"] = res["cameras"]
            info["config"]["recordings"] = [str(r.path) for r in recs]
            info["config"]["every_s"] = cfg.every_s
        else:
            info["train_moving"] = {
                "cameras": (prev["cameras"] if prev else []) + res["cameras"],
                "every_s": cfg.every_s,
                "recordings": (prev["recordings"] if prev else []) + [str(r.path) for r in recs]}
        (staged / "reid.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n",
                                          encoding="utf-8")
        # the image folder, its name list, its labels and reid.json (which counts them)
        # change as one
        labels = moving_labels_path(staged, stem)
        replace_together([(staged / f"image_{stem}", dest),
                          (staged / f"name_{stem}.txt", root / f"name_{stem}.txt"),
                          *([(labels, moving_labels_path(root, stem))]
                            if labels.is_file() else []),
                          (staged / "reid.json", meta_path)])
    c = res["counts"]
    if args.json:
        print(json.dumps(c))
    else:
        print(f"{dest}: {c['images']} crops of {c['ids']} {split} ids from "
              f"{len(res['cameras'])} moving observers ({c[f'skipped_not_{split}']} crops of "
              "other identities skipped)")
    return 0


def _merge_moving(dest, tmp, split: str, info: dict, res: dict) -> dict:
    """Hard-link (or copy) the earlier crops of ``dest`` (listed in the name list beside
    it) into the staged folder ``tmp`` beside the new ones and write the merged name list
    there; returns ``res`` with the counts of the whole set."""
    import os
    import shutil

    from dashtraj.datasets.reid import (
        MOVING_STEMS,
        moving_labels_path,
        read_moving_labels,
        write_moving_labels,
    )
    from dashtraj.reid.evaluate import VeriLayoutError

    stem = MOVING_STEMS[split]
    names_path = dest.parent / f"name_{stem}.txt"
    staged = tmp / f"image_{stem}"
    old = names_path.read_text(encoding="utf-8").split() if names_path.is_file() else []
    for n in old:
        if not (dest / n).is_file():
            raise VeriLayoutError(f"{names_path}: {n} is listed but {dest} lacks it")
        try:
            os.link(dest / n, staged / n)
        except OSError:
            shutil.copyfile(dest / n, staged / n)
    new = (tmp / f"name_{stem}.txt").read_text(encoding="utf-8").split()
    names = sorted(old + new)
    (tmp / f"name_{stem}.txt").write_text("".join(f"{n}\n" for n in names), encoding="utf-8")
    # the crops' labels: the earlier ones join the new; a set made before the labels
    # (2026-12-07) has none, and the merged set then has none either (not half of them)
    old_labels, new_labels = (moving_labels_path(dest.parent, stem),
                              moving_labels_path(tmp, stem))
    if old_labels.is_file():
        merged = {**read_moving_labels(old_labels), **read_moving_labels(new_labels)}
        write_moving_labels(new_labels, [(n, *v) for n, v in merged.items()])
    else:
        new_labels.unlink()
    key = f"skipped_not_{split}"
    skipped = info["counts"].get(stem, {}).get(key, 0) + res["counts"][key]
    return {**res, "counts": {"images": len(names), "ids": len({n[:4] for n in names}),
                              key: skipped}}
