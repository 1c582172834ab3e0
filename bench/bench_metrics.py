"""Benchmark dashtraj's SSPD + Hausdorff against traj-dist-rs and traj-dist.

Two seeded random-walk trajectories of 1,000 points each (steps ~ N(0, 3 m)).
For each implementation: median wall time of SSPD + Hausdorff over the repeats,
and the absolute difference of its values from dashtraj's (must be <= 1e-9).

    python bench/bench_metrics.py [--repeats 15] [--points 1000] [--seed 0] [--json]

Peers are used only if importable: `traj_dist_rs` (pip install traj-dist-rs) and
`traj_dist.distance` (traj-dist, Cython; needs cython<3 to build).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable

import numpy as np

from dashtraj.trajectory.metrics import hausdorff, sspd

TOLERANCE = 1e-9


def _walks(points: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = np.cumsum(rng.normal(scale=3.0, size=(points, 2)), axis=0)
    b = np.cumsum(rng.normal(scale=3.0, size=(points, 2)), axis=0)
    return a, b


def _time(fn: Callable[[], tuple[float, float]], repeats: int) -> tuple[float, tuple[float, float]]:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        values = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), values


def _peers(a: np.ndarray, b: np.ndarray) -> dict[str, Callable[[], tuple[float, float]] | None]:
    peers: dict[str, Callable[[], tuple[float, float]] | None] = {}
    try:
        import traj_dist_rs

        def rs() -> tuple[float, float]:
            return (
                traj_dist_rs.sspd(a, b, "euclidean"),
                traj_dist_rs.hausdorff(a, b, "euclidean"),
            )

        peers["traj-dist-rs"] = rs
    except ImportError:
        peers["traj-dist-rs"] = None
    try:
        import traj_dist.distance as tdist

        def td() -> tuple[float, float]:
            return tdist.sspd(a, b), tdist.hausdorff(a, b)

        peers["traj-dist"] = td
    except ImportError:
        peers["traj-dist"] = None
    return peers


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; print a table (or JSON with --json); 1 if a peer disagrees."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--points", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)

    a, b = _walks(args.points, args.seed)
    ours_s, (ours_sspd, ours_h) = _time(lambda: (sspd(a, b), hausdorff(a, b)), args.repeats)
    result: dict = {
        "points": args.points,
        "seed": args.seed,
        "repeats": args.repeats,
        "dashtraj": {"median_s": ours_s, "sspd_m": ours_sspd, "hausdorff_m": ours_h},
        "peers": {},
    }
    ok = True
    for name, fn in _peers(a, b).items():
        if fn is None:
            result["peers"][name] = None
            continue
        peer_s, (p_sspd, p_h) = _time(fn, args.repeats)
        diff = max(abs(p_sspd - ours_sspd), abs(p_h - ours_h))
        agree = diff <= TOLERANCE
        ok &= agree
        result["peers"][name] = {
            "median_s": peer_s,
            "sspd_m": p_sspd,
            "hausdorff_m": p_h,
            "max_abs_diff_m": diff,
            "agrees_1e-9": agree,
            "dashtraj_time_over_peer": ours_s / peer_s,
        }

    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"{args.points}-point random walks, seed {args.seed}, median of {args.repeats}: "
            f"SSPD {ours_sspd:.6f} m, Hausdorff {ours_h:.6f} m"
        )
        print(f"  dashtraj      {ours_s * 1e3:9.3f} ms")
        for name, peer in result["peers"].items():
            if peer is None:
                print(f"  {name}: not installed")
                continue
            verdict = "agree" if peer["agrees_1e-9"] else "DISAGREE"
            print(
                f"  {name:13s} {peer['median_s'] * 1e3:9.3f} ms  "
                f"(dashtraj/peer time {peer['dashtraj_time_over_peer']:.2f}x; values "
                f"{verdict} to 1e-9, max diff {peer['max_abs_diff_m']:.1e} m)"
            )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
