"""Time one reconstruction of a 20-sighting trip on Town10HD (target: <= 50 ms for HMM).

A seeded synthetic trip (`dashtraj.trajectory.synth.make_trips`) with at least 20
sightings; its first 20 are reconstructed with each method. The map and its lane
graph are loaded and warmed once (as a long-running service would); each repeat
is a whole `reconstruct` call with its own route cache. Prints the median wall
time in milliseconds per method.

    python bench/bench_reconstruct.py [--repeats 21] [--seed 0] [--map PATH] [--json]

Skips (exit 0, a message) when the real CARLA map is not available.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from dashtraj.roads import RoadMap
from dashtraj.trajectory.reconstruct import METHODS, reconstruct
from dashtraj.trajectory.synth import make_trips

DEFAULT_MAP = Path(__file__).resolve().parents[2] / "shared" / "maps" / "carla" / "Town10HD.xodr"
TARGET_MS = 50.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=21)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--map", type=Path, default=DEFAULT_MAP)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    path = args.map
    if not path.is_file():  # a clean clone without ../shared: the built-in town10
        from dashtraj.world.towns import town_path

        print(f"bench_reconstruct: {path} not available; using the built-in town10")
        path = town_path("town10")
    m = RoadMap.from_file(path)
    m.lane_graph()
    rng = np.random.default_rng(args.seed)
    trip = next(t for t in iter(lambda: make_trips(m, 1, rng)[0], None)
                if len(t.sightings) >= 20)
    sightings = list(trip.sightings[:20])
    out = {"map": m.name, "sightings": len(sightings), "repeats": args.repeats, "median_ms": {}}
    for method in METHODS:
        times = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reconstruct(m, sightings, method=method)  # warm the spatial index
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                reconstruct(m, sightings, method=method)
                times.append((time.perf_counter() - t0) * 1e3)
        out["median_ms"][method] = statistics.median(times)
    if args.json:
        print(json.dumps(out))
    else:
        for method, ms in out["median_ms"].items():
            flag = "" if method != "hmm" else (" (target <= 50 ms: "
                                               f"{'met' if ms <= TARGET_MS else 'MISSED'})")
            print(f"reconstruct {method:<14} {len(sightings)} sightings on "
                  f"{Path(m.name).name}: median {ms:.1f} ms over {args.repeats}{flag}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
