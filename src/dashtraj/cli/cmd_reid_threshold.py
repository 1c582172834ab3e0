"""`dashtraj reid-threshold`: calibrate the track decision threshold of a ReID model on
training recordings' sightings databases, and store it beside the model."""

from __future__ import annotations

import json
from pathlib import Path

from dashtraj.cli._args import HelpFormatter, fraction, int_at_least, non_negative_float, seed
from dashtraj.outputs import add_output_args

DESCRIPTION = """\
Calibrate the per-track "target or not" threshold of a ReID model on TRAINING data: the crops
of sightings databases (`dashtraj perceive`) of recordings simulated with training seeds and
training identities (`simulate --identities 0-650`), never a test run. Each crop's identity
is its vehicle's catalog identity, its camera the observer; a "track" is the crops of one
identity by one observer; a query is the mean of a track's crops (--query track: query
expansion, the default) or one crop (--query crop: the paper's), and its distance to a track
of another observer the median (--aggregate) of its cosine distances to that track's crops
(`dashtraj.reidentify.decision.calibrate_threshold`). Only crops at least --min-box-px tall
and at least --border-px from the image border are used, as in the run. The threshold is the
highest recall with --target-precision on those pairs (--rule precision), with at most
--max-far of the negative pairs accepted (--rule far: what `make reid-threshold` uses) or the
equal error rate point (--rule eer); the query and crop filter are stored with it, and the
run decides the same way (a run's query track, which a tracker can carry across vehicles, is
averaged only over its crops within the threshold of the query crop; the calibration's tracks
are pure).

Writes M.threshold.json beside the model (-o to write elsewhere) with the model's sha256 and
the provenance (databases, recordings, towns, seeds, look, pair counts); `experiments
--sightings vision` refuses a threshold calibrated on another model. `make reid-threshold`
does it all for the shipped model."""


def register(sub) -> None:
    p = sub.add_parser("reid-threshold", help="calibrate a ReID model's track decision threshold "
                       "on training recordings", description=DESCRIPTION,
                       formatter_class=HelpFormatter)
    p.add_argument("databases", nargs="+", metavar="DB",
                   help="sightings databases (perceive) of TRAINING recordings")
    p.add_argument("--model", default=None, metavar="M.onnx",
                   help="ReID model (default: the shipped one)")
    p.add_argument("--rule", choices=("precision", "eer", "far"), default="precision",
                   help="threshold rule (default precision)")
    p.add_argument("--max-far", type=fraction, default=0.02,
                   help="rule far: the highest false-accept rate on the negative pairs "
                        "(default 0.02)")
    p.add_argument("--target-precision", type=fraction, default=0.99,
                   help="rule precision: the precision to reach on the pairs (default 0.99)")
    p.add_argument("--aggregate", choices=("median", "mean", "min", "kmin-mean"),
                   default="median", help="track aggregator (default median)")
    p.add_argument("--query", choices=("track", "crop"), default=None,
                   help="the query: a track's mean (query expansion; default) or one crop "
                        "(the paper)")
    p.add_argument("--min-box-px", type=non_negative_float, default=None,
                   help="crops with shorter boxes are not used, pixels (default 24)")
    p.add_argument("--border-px", type=float, default=None,
                   help="crops whose box comes this close to the image border are not used, "
                        "pixels; negative: use them (default 2)")
    p.add_argument("--max-queries", type=int_at_least(1), default=2000,
                   help="queries drawn (default 2000)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the query draw")
    p.add_argument("-o", "--output", default=None,
                   help="threshold JSON (default: M.threshold.json beside the model)")
    add_output_args(p)
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from dashtraj.cli._args import ArgumentError
    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path
    from dashtraj.reidentify.decision import (
        EXPANDED_RECIPE,
        Recipe,
        adequate_crops,
        calibrate_threshold,
    )
    from dashtraj.reidentify.vision import (
        RECOMPUTE,
        Threshold,
        crop_embeddings,
        sha256_of,
        threshold_path,
    )
    from dashtraj.store import SightingsDB
    from dashtraj.store.backend import display_name

    model = Path(args.model) if args.model else shipped_model_path()
    out = Path(args.output) if args.output else threshold_path(model)
    check_output(out, overwrite=args.overwrite, kind="file")
    d = EXPANDED_RECIPE
    border = d.border_px if args.border_px is None else args.border_px
    if border is not None and not np.isfinite(border):
        raise ArgumentError(f"--border-px {args.border_px!r}: expected a finite number")
    recipe = Recipe(args.aggregate, args.query or d.query,
                    float(d.min_box_px if args.min_box_px is None else args.min_box_px),
                    None if border is None or border < 0 else float(border))
    embedder = ReidEmbedder(model)
    embs, ids, cams, sources = [], [], [], []
    for i, db_path in enumerate(args.databases):
        with SightingsDB.open(db_path, writable=True) as db:
            run_info = db.run_info()
            dets = {(d.observer_id, d.frame, d.idx): d for d in db.detections()}
            cam = run_info["camera"]
            if not all(isinstance(cam.get(k), int) and cam[k] > 0
                       for k in ("width_px", "height_px")):
                raise DashtrajError(f"{db.path}: the run's camera has no image size "
                                    f"(width_px, height_px): {cam!r}")
            keys, e = crop_embeddings(db, embedder)
        boxes = np.array([[dets[k].x0, dets[k].y0, dets[k].x1, dets[k].y1] if k in dets
                          else [0.0, 0.0, 0.0, 0.0] for k in keys]).reshape(-1, 4)
        good = adequate_crops(boxes, int(cam["width_px"]), int(cam["height_px"]), recipe)
        det = {k: (dets[k].truth_vehicle_id if g else None)
               for k, g in zip(keys, good, strict=True) if k in dets}
        rec_meta, identity = {}, {}
        rec = Path(run_info["recording"])
        try:
            rec_meta = json.loads((rec / "meta.json").read_text())
            import csv

            with open(rec / "vehicles.csv", newline="") as f:
                identity = {int(r["vehicle_id"]): int(r["identity_id"]) for r in csv.DictReader(f)}
        except (OSError, ValueError, KeyError):
            pass  # identities then stay per database (vehicle ids)
        keep = [j for j, k in enumerate(keys) if det.get(k) is not None]
        for j in keep:
            v = det[keys[j]]
            ids.append(identity.get(v, 1_000_000 * (i + 1) + v))
            cams.append(1000 * i + keys[j][0])
        embs.append(e[keep])
        cfg = run_info.get("config") or {}
        sources.append({"database": display_name(db_path), "recording": str(rec),
                        "town": (rec_meta.get("config") or {}).get("map"),
                        "seed": (rec_meta.get("config") or {}).get("seed"),
                        "identity_range": (rec_meta.get("config") or {}).get("identity_range"),
                        "detector": cfg.get("detector"), "look": cfg.get("look"),
                        "size": cfg.get("size"), "crops": len(keep)})
    e = np.concatenate(embs) if embs else np.zeros((0, 0), np.float32)
    if len(set(ids)) < 2:
        raise DashtrajError(f"{args.databases[0]}: fewer than two identities with crops; "
                            "calibration needs training recordings with traffic")
    cal = calibrate_threshold(e, ids, cams, rule=args.rule, target_precision=args.target_precision,
                              max_queries=args.max_queries,
                              rng=np.random.default_rng(args.seed), recipe=recipe,
                              max_far=args.max_far)
    th = Threshold(cal, sha256_of(model), {
        "model": model.name, "sources": sources, "crops": len(ids), "identities": len(set(ids)),
        "query_draw_seed": args.seed, "max_queries": args.max_queries,
        "recompute": RECOMPUTE})
    with atomic_output(out, overwrite=args.overwrite, kind="file") as tmp:
        tmp.write_text(json.dumps(th.to_dict(), indent=1) + "\n")
    if args.json:
        print(json.dumps(th.to_dict(), indent=2))
        return 0
    print(f"{model.name}: threshold {cal.threshold:.4f} ({cal.rule}, {cal.aggregate}, query "
          f"{cal.query}, crops >= {cal.min_box_px:g} px"
          f"{'' if cal.border_px is None else f', >= {cal.border_px:g} px from the border'}) on "
          f"{len(ids)} crops of {len(set(ids))} training identities: precision "
          f"{cal.precision:.3f}, recall {cal.recall:.3f} on {cal.positives} positive / "
          f"{cal.negatives} negative pairs")
    print(f"written: {out}")
    return 0
