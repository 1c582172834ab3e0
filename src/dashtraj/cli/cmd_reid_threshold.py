"""`dashtraj reid-threshold`: calibrate the track decision threshold of a ReID model on
training recordings' sightings databases, and store it beside the model."""

from __future__ import annotations

import json
from pathlib import Path

from dashtraj.cli._args import HelpFormatter, fraction, int_at_least, seed
from dashtraj.outputs import add_output_args

DESCRIPTION = """\
Calibrate the per-track "target or not" threshold of a ReID model on TRAINING data: the crops
of sightings databases (`dashtraj perceive`) of recordings simulated with training seeds and
training identities (`simulate --identities 0-650`), never a test run. Each crop's identity
is its vehicle's catalog identity, its camera the observer; a query is one crop, a "track" the
crops of one identity by another observer, its distance the median (--aggregate) of the
query's cosine distances to them (`dashtraj.reidentify.decision.calibrate_threshold`). The
threshold is the highest recall with --target-precision on those pairs (--rule precision) or
the equal error rate point (--rule eer).

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
    p.add_argument("--rule", choices=("precision", "eer"), default="precision",
                   help="threshold rule (default precision)")
    p.add_argument("--target-precision", type=fraction, default=0.99,
                   help="rule precision: the precision to reach on the pairs (default 0.99)")
    p.add_argument("--aggregate", choices=("median", "mean", "min", "kmin-mean"),
                   default="median", help="track aggregator (default median)")
    p.add_argument("--max-queries", type=int_at_least(1), default=2000,
                   help="query crops drawn (default 2000)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the query draw")
    p.add_argument("-o", "--output", default=None,
                   help="threshold JSON (default: M.threshold.json beside the model)")
    add_output_args(p)
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path
    from dashtraj.reidentify.decision import calibrate_threshold
    from dashtraj.reidentify.vision import (
        RECOMPUTE,
        Threshold,
        crop_embeddings,
        sha256_of,
        threshold_path,
    )
    from dashtraj.store import SightingsDB

    model = Path(args.model) if args.model else shipped_model_path()
    out = Path(args.output) if args.output else threshold_path(model)
    check_output(out, overwrite=args.overwrite, kind="file")
    embedder = ReidEmbedder(model)
    embs, ids, cams, sources = [], [], [], []
    for i, db_path in enumerate(args.databases):
        with SightingsDB.open(db_path, writable=True) as db:
            run_info = db.run_info()
            det = {(d.observer_id, d.frame, d.idx): d.truth_vehicle_id for d in db.detections()}
            keys, e = crop_embeddings(db, embedder)
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
        sources.append({"database": str(db_path), "recording": str(rec),
                        "town": (rec_meta.get("config") or {}).get("map"),
                        "seed": (rec_meta.get("config") or {}).get("seed"),
                        "identity_range": (rec_meta.get("config") or {}).get("identity_range"),
                        "detector": cfg.get("detector"), "look": cfg.get("look"),
                        "size": cfg.get("size"), "crops": len(keep)})
    e = np.concatenate(embs) if embs else np.zeros((0, 512), np.float32)
    if len(set(ids)) < 2:
        raise DashtrajError(f"{args.databases[0]}: fewer than two identities with crops; "
                            "calibration needs training recordings with traffic")
    cal = calibrate_threshold(e, ids, cams, rule=args.rule, target_precision=args.target_precision,
                              aggregate=args.aggregate, max_queries=args.max_queries,
                              rng=np.random.default_rng(args.seed))
    th = Threshold(cal, sha256_of(model), {
        "model": model.name, "sources": sources, "crops": len(ids), "identities": len(set(ids)),
        "query_draw_seed": args.seed, "max_queries": args.max_queries,
        "recompute": RECOMPUTE})
    with atomic_output(out, overwrite=args.overwrite, kind="file") as tmp:
        tmp.write_text(json.dumps(th.to_dict(), indent=1) + "\n")
    if args.json:
        print(json.dumps(th.to_dict(), indent=2))
        return 0
    print(f"{model.name}: threshold {cal.threshold:.4f} ({cal.rule}, {cal.aggregate}) on "
          f"{len(ids)} crops of {len(set(ids))} training identities: precision "
          f"{cal.precision:.3f}, recall {cal.recall:.3f} on {cal.positives} positive / "
          f"{cal.negatives} negative pairs")
    print(f"written: {out}")
    return 0
