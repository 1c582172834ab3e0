"""Benchmark of the sightings database: an SQLite file against a PostgreSQL schema.

Writes a perception run's worth of rows through `dashtraj.store.SightingsDB` (per frame
8 detections, a 12 kB crop for 2 of them, every track replaced each batch, as
``perceive`` writes them: one transaction per ``--batch`` frames) and reads it back
(every detection; the sightings query that ``reconstruct`` and the re-identification
run on), into each backend in the same run:

- one writer: frames/s;
- ``--writers`` processes at once, each writing its own observers into the same run
  (``perceive --workers N`` into a URL; SQLite takes one writer at a time, so its
  writers queue for the file's lock): frames/s over all of them;
- reads: detections/s of every detection, sightings/s of the sightings query (those
  within 15 m, with their observer's pose).

PostgreSQL is ``--pg-url`` (a server of yours; the run goes into a fresh schema that is
dropped afterwards) or, by default, a PostgreSQL 16 that the pgserver wheel (dev extra)
starts under a temporary folder. Prints each figure and the ratio PostgreSQL / SQLite.

Usage:
    .venv/bin/python bench/bench_store.py [--frames 600] [--observers 4] [--writers 4]
        [--batch 50] [--pg-url URL] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def _rows(observer: int, frames: range, seed: int, batch: int):
    from dashtraj.store import CropRow, DetectionRow, PoseRow, TrackRow

    rng = np.random.default_rng(seed)
    crop = rng.integers(0, 256, 12_000, dtype=np.uint8).tobytes()
    batches = []
    for a in range(frames.start, frames.stop, batch):
        poses, dets, crops = [], [], []
        for f in range(a, min(a + batch, frames.stop)):
            t = f * 0.1
            poses.append(PoseRow(observer, f, t, *rng.normal(size=9).tolist()))
            for i in range(8):
                x0, y0 = rng.uniform(0, 1200), rng.uniform(300, 600)
                dets.append(DetectionRow(observer, f, i, t, 100 + i, x0, y0, x0 + 60, y0 + 40,
                                         0.9, i % 15, "car", "back", 8.0 + i, -3.0 + i,
                                         *rng.normal(size=3).tolist(), 4, 0, -1, 33.5, 0.2,
                                         i, i))
                if i < 2:
                    crops.append(CropRow(observer, f, i, crop, 60, 40))
        tracks = [TrackRow(observer, 100 + i, "car", 0.0, a * 0.1, a, i) for i in range(8)]
        batches.append((poses, dets, crops, tracks))
    return batches


def _write(target: str, observers: list[int], frames: int, batch: int) -> float:
    """Write the observers' frames into an existing run; seconds spent."""
    from dashtraj.store import SightingsDB

    data = [b for o in observers for b in _rows(o, range(frames), o, batch)]
    t0 = time.perf_counter()
    with SightingsDB.open(target, writable=True) as db:
        for poses, dets, crops, tracks in data:
            db.add_frames(poses, dets, crops, tracks)
        for o in observers:
            db.finish_observer(o)
    return time.perf_counter() - t0


def _worker(args) -> float:
    return _write(*args)


def _new_run(target: str, observers: list[int]) -> None:
    from dashtraj.store import SightingsDB

    with SightingsDB.create(target) as db:
        db.write_run("bench", "town01", None, {"width_px": 1280, "height_px": 720}, {},
                     [(o, None) for o in observers])


def bench_backend(make_target, frames: int, n_obs: int, writers: int, batch: int) -> dict:
    from dashtraj.store import SightingsDB

    out = {}
    obs = list(range(1, n_obs + 1))
    target = make_target("one")
    _new_run(target, obs)
    wall = _write(target, obs, frames, batch)
    out["frames_per_s_one_writer"] = round(n_obs * frames / wall, 1)
    with SightingsDB.open(target) as db:
        t0 = time.perf_counter()
        n = len(db.detections())
        out["detections_per_s_read"] = round(n / (time.perf_counter() - t0), 1)
        t0 = time.perf_counter()
        m = len(db.sightings(max_distance_m=15.0))
        out["sightings_per_s_query"] = round(m / (time.perf_counter() - t0), 1)
    target = make_target("many")
    _new_run(target, obs)
    parts = [obs[i::writers] for i in range(writers)]
    with mp.get_context("spawn").Pool(writers) as pool:
        t0 = time.perf_counter()
        pool.map(_worker, [(target, p, frames, batch) for p in parts if p])
        wall = time.perf_counter() - t0
    with SightingsDB.open(target) as db:
        assert db.count("poses") == n_obs * frames
    out[f"frames_per_s_{writers}_writers"] = round(n_obs * frames / wall, 1)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=600, help="frames per observer")
    ap.add_argument("--observers", type=int, default=4)
    ap.add_argument("--writers", type=int, default=4, help="processes writing at once")
    ap.add_argument("--batch", type=int, default=50, help="frames per transaction")
    ap.add_argument("--pg-url", default=None,
                    help="PostgreSQL URL of your server (default: a pgserver one)")
    ap.add_argument("--json", default=None, help="also write the results here")
    args = ap.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="bench-store-") as td:
        lite = bench_backend(lambda name: str(Path(td) / f"{name}.db"), args.frames,
                             args.observers, args.writers, args.batch)
        srv = None
        url = args.pg_url
        if url is None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                import pgserver

                srv = pgserver.get_server(Path(td) / "pg", cleanup_mode="stop")
            url = srv.get_uri()
        sep = "&" if "?" in url else "?"
        names = []

        def pg_target(name: str) -> str:
            names.append(f"bench_store_{name}")
            return f"{url}{sep}schema={names[-1]}"

        try:
            pg = bench_backend(pg_target, args.frames, args.observers, args.writers,
                               args.batch)
        finally:
            import psycopg

            from dashtraj.store.backend import parse_url

            with psycopg.connect(parse_url(pg_target("x")).conninfo, autocommit=True) as c:
                for n in names[:-1]:
                    c.execute(f'DROP SCHEMA IF EXISTS "{n}" CASCADE')
            if srv is not None:
                srv.cleanup()
    res = {"config": vars(args), "sqlite": lite, "postgresql": pg,
           "ratio_postgresql_over_sqlite": {k: round(pg[k] / lite[k], 2) for k in lite
                                            if lite[k]}}
    print(f"sightings database, {args.observers} observers x {args.frames} frames, "
          f"{args.batch} frames per transaction")
    print(f"{'(higher is faster)':28s} {'SQLite':>10s} {'PostgreSQL':>11s} {'PG / SQLite':>12s}")
    for k, r in res["ratio_postgresql_over_sqlite"].items():
        print(f"{k:28s} {lite[k]:10.1f} {pg[k]:11.1f} {r:12.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
