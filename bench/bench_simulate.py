"""Benchmark: 4 observers + 1 target + 20 agents, 180 s at 20 Hz, no rendering.

Times `dashtraj.world.recording.simulate` end to end (traffic, ground-truth boxes
every 0.1 s, parquet writing) and prints seconds and the multiple of real time
(goal: >= 18x on one core).

    .venv/bin/python bench/bench_simulate.py [--town town01|town10|PATH.xodr] [--repeat 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from dashtraj.world.recording import RunConfig, simulate


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--town", default="town10")
    ap.add_argument("--duration", type=float, default=180.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    cfg = RunConfig(map=args.town, seed=7, duration_s=args.duration, n_observers=4, n_agents=20)
    best = float("inf")
    with tempfile.TemporaryDirectory() as tmp:
        simulate(RunConfig(map=args.town, duration_s=1.0), Path(tmp) / "warm")
        for k in range(args.repeat):
            t0 = time.perf_counter()
            s = simulate(cfg, Path(tmp) / f"r{k}")
            best = min(best, time.perf_counter() - t0)
    print(f"{args.town}: {s.vehicles} vehicles, {s.frames} frames, {s.truth_rows} truth rows; "
          f"best of {args.repeat}: {best:.2f} s = {args.duration / best:.0f}x real time "
          f"(goal >= 18x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
