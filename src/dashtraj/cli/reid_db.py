"""`dashtraj reid embed DB` and `dashtraj reid query DB` (sub-commands of `cmd_reid`'s
``reid``): appearance vectors for a sightings database's crops, and tracks ranked by
appearance against an image or a track."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register_db_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``embed`` and ``query`` to the ``reid`` sub-commands."""
    from dashtraj.cli._args import int_at_least, positive_int
    from dashtraj.outputs import add_output_args
    from dashtraj.reidentify.decision import AGGREGATORS
    from dashtraj.reidentify.rank import DEFAULT_AGGREGATE

    e = sub.add_parser(
        "embed", help="add an embedding for every crop of a sightings database (idempotent)",
        description="Embed every crop of a sightings database (dashtraj perceive RUN -o DB) "
                    "that has no vector of this model yet, with the ONNX ReID model, and store "
                    "the vectors in the database (table embeddings, keyed by crop and model "
                    "sha256). A rerun adds nothing; another model adds its own rows. Pages of "
                    "--batch crops are committed one by one: a killed run keeps every "
                    "committed page, and a rerun finishes the rest.")
    e.add_argument("db", metavar="DB", help="sightings database (perceive's output)")
    e.add_argument("--model", default=None, metavar="M.onnx",
                   help="ONNX model (default: the shipped one)")
    e.add_argument("--batch", type=positive_int, default=64, metavar="N",
                   help="crops per batch and per transaction (default 64)")
    e.add_argument("--threads", type=positive_int, default=2,
                   help="onnxruntime threads (default 2)")
    e.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    e.add_argument("--json", action="store_true", help="print the summary as JSON")
    e.set_defaults(func=run_embed)

    q = sub.add_parser(
        "query", help="rank a sightings database's tracks by appearance against an image or "
                      "a track",
        description="Search the embedded crops of a sightings database (run 'dashtraj reid "
                    "embed DB' first) for an image (--image) or a track (--track ID: the mean "
                    "of its crops' L2-normalised embeddings, re-normalised; the track itself is "
                    "left out), and rank the tracks by their crops' cosine distances "
                    "(1 - cosine similarity) aggregated per track (--aggregate; default "
                    "kmin-mean: the mean of the closest half of its crops). Prints the top "
                    "--k tracks; -o writes a contact sheet (query crops above each track's "
                    "best crop).")
    q.add_argument("db", metavar="DB", help="sightings database with embeddings")
    src = q.add_mutually_exclusive_group(required=True)
    src.add_argument("--image", metavar="Q.jpg", help="query image (a vehicle crop)")
    src.add_argument("--track", type=int_at_least(0), metavar="ID", help="query track id")
    q.add_argument("--observer", type=int_at_least(0), default=None, metavar="O",
                   help="the observer of --track (needed when several have that track id)")
    q.add_argument("--k", type=positive_int, default=10, help="tracks to return (default 10)")
    q.add_argument("--aggregate", default=DEFAULT_AGGREGATE, choices=tuple(AGGREGATORS),
                   help=f"per-track aggregation of crop distances (default {DEFAULT_AGGREGATE})")
    q.add_argument("--model", default=None, metavar="M.onnx",
                   help="ONNX model whose embeddings to search (default: the shipped one)")
    q.add_argument("--threads", type=positive_int, default=2,
                   help="onnxruntime and faiss threads (default 2)")
    q.add_argument("-o", "--output", default=None, metavar="SHEET.png",
                   help="write a contact sheet PNG")
    add_output_args(q)
    q.add_argument("--json", action="store_true", help="print the ranking as JSON")
    q.set_defaults(func=run_query)


def _model_path(arg: str | None) -> Path:
    from dashtraj.reid.embed import ModelFileError, shipped_model_path

    p = Path(arg) if arg is not None else shipped_model_path()
    if not p.is_file():
        raise ModelFileError(f"--model {p}: no such ONNX model")
    return p


def run_embed(args: argparse.Namespace) -> int:
    """Embed the database's missing crops; prints a summary; returns 0."""
    from dashtraj.reid.database import embed_database
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.store import SightingsDB
    from dashtraj.store.backend import display_name

    model = _model_path(args.model)
    name = display_name(args.db)
    with SightingsDB.open(args.db, writable=True) as db:
        if db.count("crops") == 0:  # before loading the model
            from dashtraj.reid.database import EmbedError

            raise EmbedError(f"{name} has no crops (perceive keeps crops of detections "
                             "within its --reid-range); nothing to embed")
        emb = ReidEmbedder(model, threads=args.threads)
        bar = None
        if not args.quiet and not args.json and sys.stderr.isatty():
            from tqdm import tqdm

            from dashtraj.reid.database import file_sha256

            bar = tqdm(total=db.count_missing_embeddings(file_sha256(model)), unit="crop",
                       file=sys.stderr, desc="embed")
        try:
            s = embed_database(db, emb, batch_size=args.batch,
                               progress=bar.update if bar is not None else None)
        except KeyboardInterrupt:
            if bar is not None:
                bar.close()
                bar = None
            print(f"interrupted: the crops embedded so far are kept in {name}; rerun to "
                  "embed the rest", file=sys.stderr)
            raise
        finally:
            if bar is not None:
                bar.close()
    out = {"db": name, "model": s.model, "model_sha256": s.model_sha256, "dim": s.dim,
           "crops": s.crops, "already": s.already, "added": s.added, "batches": s.batches,
           "wall_s": s.wall_s, "crops_per_s": s.crops_per_s}
    if args.json:
        print(json.dumps(out))
    else:
        rate = f" in {s.wall_s:.1f} s ({s.crops_per_s:.0f} crops/s)" if s.added else ""
        print(f"{name}: {s.added} crops embedded{rate} with {s.model} ({s.dim}-d, sha256 "
              f"{s.model_sha256[:12]}...); {s.already} of {s.crops} had a vector of this "
              "model already")
    return 0


def _query_track(db, emb, track: int, observer: int | None):
    """(observer, track, rows of emb) of the query track; errors name what is wrong."""
    import numpy as np

    from dashtraj.errors import DashtrajError

    owners = sorted(t.observer_id for t in db.tracks() if t.track_id == track)
    if observer is not None:
        known = [o["observer_id"] for o in db.observers()]
        if observer not in known:
            raise DashtrajError(f"--observer {observer}: not an observer of {db.path} "
                                f"(observers: {', '.join(map(str, known))})")
        if observer not in owners:
            raise DashtrajError(f"--track {track}: observer {observer} of {db.path} has no such "
                                "track")
    elif not owners:
        raise DashtrajError(f"--track {track}: no such track in {db.path} "
                            f"({len(db.tracks())} tracks)")
    elif len(owners) > 1:
        raise DashtrajError(f"--track {track}: observers {', '.join(map(str, owners))} of "
                            f"{db.path} each have a track {track}; give --observer")
    else:
        observer = owners[0]
    rows = np.flatnonzero((emb.observer_id == observer) & (emb.track_id == track))
    if len(rows) == 0:
        raise DashtrajError(f"--track {track} of observer {observer} has no embedded crops (its "
                            "detections were all beyond perceive's --reid-range)")
    return observer, track, rows


def _read_image(path: str):
    from PIL import Image, UnidentifiedImageError

    from dashtraj.errors import DashtrajError

    p = Path(path)
    if not p.is_file():
        raise DashtrajError(f"--image {p}: " + ("a folder, not an image file" if p.is_dir()
                                                 else "no such file"))
    try:
        with Image.open(p) as im:
            return im.convert("RGB")
    except (UnidentifiedImageError, OSError) as exc:
        raise DashtrajError(f"--image {p}: not a readable image ({exc})") from exc


def run_query(args: argparse.Namespace) -> int:
    """Rank the database's tracks against the query; prints them; returns 0."""
    import time

    import numpy as np

    from dashtraj.cli._args import ArgumentError
    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import check_output
    from dashtraj.reid.database import EmbedError, decode_crop, file_sha256
    from dashtraj.reidentify.rank import TrackGallery, query_vector
    from dashtraj.store import SightingsDB
    from dashtraj.store.backend import display_name

    if args.output is not None:
        if Path(args.output).suffix.lower() != ".png":
            raise ArgumentError(f"-o {args.output}: name a .png file")
        check_output(args.output, overwrite=args.overwrite, kind="file")
    if args.observer is not None and args.track is None:
        raise ArgumentError("--observer goes with --track")
    model = _model_path(args.model)
    name = display_name(args.db)
    with SightingsDB.open(args.db) as db:
        if db.count("crops") == 0:
            raise EmbedError(f"{name} has no crops (perceive keeps crops of detections "
                             "within its --reid-range); nothing to search")
        sha = file_sha256(model)
        import faiss  # noqa: F401  (imported before the clock starts: ~0.1 s once)

        t0 = time.perf_counter()
        emb = db.embeddings(sha)
        load_s = time.perf_counter() - t0
        image = None
        if args.image is not None:
            from dashtraj.reid.embed import ReidEmbedder

            image = _read_image(args.image)
            v = ReidEmbedder(model, threads=args.threads).embed([image])
            if v.shape[1] != emb.dim:
                raise DashtrajError(f"--model {model.name} outputs {v.shape[1]}-d vectors but "
                                    f"{name} holds {emb.dim}-d embeddings of it")
            exclude, q_rows, query = None, np.zeros(0, np.int64), {"image": str(args.image)}
            t1 = time.perf_counter()
            q = query_vector(v)
        else:
            obs, trk, q_rows = _query_track(db, emb, args.track, args.observer)
            exclude = (obs, trk)
            t1 = time.perf_counter()
            q = query_vector(emb.vectors[q_rows])
            truth = np.unique(emb.truth_vehicle_id[q_rows], return_counts=True)
            q_truth = int(truth[0][np.argmax(truth[1])])
            query = {"observer_id": obs, "track_id": trk, "crops": len(q_rows),
                     "vector": "mean of the track's L2-normalised crop embeddings, "
                               "re-normalised",
                     "truth_vehicle_id": None if q_truth < 0 else q_truth}
        index = TrackGallery(emb, threads=args.threads)
        t2 = time.perf_counter()
        r = index.rank(q, k=args.k, aggregate=args.aggregate, exclude=exclude)
        t3 = time.perf_counter()
        query_s = t3 - t1
        sheet_crops = None
        if args.output is not None:
            pick = q_rows[np.linspace(0, len(q_rows) - 1, min(5, len(q_rows))).round()
                          .astype(int)] if len(q_rows) else q_rows
            keys = [emb.keys()[i] for i in pick] + [(t.observer_id, t.best_frame, t.best_idx)
                                                    for t in r.tracks]
            sheet_crops = {(c.observer_id, c.frame, c.idx): decode_crop(c.jpeg, (
                c.observer_id, c.frame, c.idx)) for c in db.crops(keys=keys)}
            q_keys = [emb.keys()[i] for i in pick]
    out = {"db": name, "model": emb.model, "model_sha256": emb.model_sha256,
           "query": query, "aggregate": r.aggregate, "distance": "cosine (1 - q.g)",
           "k": args.k, "tracks_searched": r.tracks_searched, "crops_searched": r.crops_searched,
           "load_ms": 1000 * load_s, "index_ms": 1000 * (t2 - t1),
           "search_ms": 1000 * (t3 - t2), "query_ms": 1000 * query_s,
           "results": [t.to_dict() for t in r.tracks], "sheet": args.output}
    if args.output is not None:
        _write_sheet(args, image, q_keys, query, r, sheet_crops)
    if args.json:
        print(json.dumps(out))
        return 0
    what = (f"image {args.image}" if args.image is not None else
            f"track {query['track_id']} of observer {query['observer_id']} "
            f"({query['crops']} crops, mean embedding)")
    print(f"{name}: {what} against {r.crops_searched} crops of {r.tracks_searched} tracks "
          f"({emb.model}, {r.aggregate} cosine distance per track) in "
          f"{1000 * query_s:.1f} ms (read {1000 * load_s:.0f} ms, index "
          f"{1000 * (t2 - t1):.1f} ms, search {1000 * (t3 - t2):.1f} ms)")
    print(f"{'rank':>4} {'observer':>8} {'track':>6} {'distance':>9} {'crops':>6} "
          f"{'class':<10} {'best t (s)':>10}")
    for t in r.tracks:
        print(f"{t.rank:>4} {t.observer_id:>8} {t.track_id:>6} {t.distance:>9.4f} "
              f"{t.crops:>6} {t.vehicle_class:<10} {t.best_t:>10.1f}")
    if args.output is not None:
        print(f"contact sheet: {args.output}")
    return 0


def _write_sheet(args, image, q_keys, query, ranking, crops) -> None:
    from dashtraj.outputs import atomic_output
    from dashtraj.reidentify.sheet import contact_sheet

    if image is not None:
        q_imgs, q_labels = [image], [["query image", Path(args.image).name[:18]]]
    else:
        q_imgs = [crops[k] for k in q_keys]
        q_labels = [[f"query obs {k[0]} trk {query['track_id']}", f"frame {k[1]}"]
                    for k in q_keys]
    truth = query.get("truth_vehicle_id")
    results, labels, match = [], [], []
    for t in ranking.tracks:
        results.append(crops[(t.observer_id, t.best_frame, t.best_idx)])
        labels.append([f"#{t.rank} obs {t.observer_id} trk {t.track_id}",
                       f"d={t.distance:.3f} ({t.crops} crops)"])
        match.append(None if truth is None or t.truth_vehicle_id is None
                     else t.truth_vehicle_id == truth)
    sheet = contact_sheet(q_imgs, q_labels, results, labels, match)
    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        sheet.save(tmp, format="PNG")
