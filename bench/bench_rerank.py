"""Benchmark of dashtraj.reid.rerank (k-reciprocal re-ranking) against the authors' code.

The peer is ``re_ranking`` of torchreid 0.2.5 (``torchreid/reid/utils/rerank.py``: the
authors' numpy code, adapted to distance matrices), run on the same matrices in the same
run. torchreid itself needs torch and a C build, so this fetches its source
distribution from the package index (``pip download --no-deps``, cached under
``--cache``) and loads that one file. The check is independent: the two implementations
share no code.

Data: unit 512-d vectors clustered like embeddings (``--ids`` identities × ``--per``
views; one query per identity, the other views the gallery), distances as
``dashtraj reid eval`` computes them (squared L2). Printed: the largest difference of the
re-ranked distances, whether the top-10 gallery order agrees, mAP / rank-1 without and
with re-ranking, and the wall time of each implementation with the ratio.

Usage:
    .venv/bin/python bench/bench_rerank.py [--ids 500] [--per 9] [--json out.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tarfile
import time
from pathlib import Path

import numpy as np

PEER = "torchreid==0.2.5"
PEER_FILE = "torchreid-0.2.5/torchreid/reid/utils/rerank.py"


def load_peer(cache: Path):
    """torchreid's ``re_ranking`` function, or None (with the reason printed)."""
    cache.mkdir(parents=True, exist_ok=True)
    sdist = cache / "torchreid-0.2.5.tar.gz"
    if not sdist.exists():
        r = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary",
                            ":all:", "-q", "-d", str(cache), PEER], capture_output=True, text=True)
        if r.returncode != 0 or not sdist.exists():
            print(f"peer unavailable: pip download {PEER} failed: {r.stderr.strip()[-300:]}")
            return None
    src = cache / "rerank_torchreid.py"
    if not src.exists():
        with tarfile.open(sdist) as t:
            src.write_bytes(t.extractfile(PEER_FILE).read())
    spec = importlib.util.spec_from_file_location("rerank_torchreid", src)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.re_ranking


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ids", type=int, default=500)
    ap.add_argument("--per", type=int, default=9)
    ap.add_argument("--noise", type=float, default=0.1, help="per-dimension view noise")
    ap.add_argument("--cache", type=Path, default=Path(".bench_cache"))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)

    from dashtraj.reid.evaluate import distance_matrix, evaluate_rank, l2_normalize
    from dashtraj.reid.rerank import k_reciprocal_rerank

    rng = np.random.default_rng(0)
    centres = l2_normalize(rng.normal(size=(args.ids, 512)))
    f = l2_normalize(np.repeat(centres, args.per, 0)
                     + args.noise * rng.normal(size=(args.ids * args.per, 512)))
    pid = np.repeat(np.arange(args.ids), args.per)
    cam = np.tile(np.arange(args.per), args.ids)
    qi = np.arange(0, len(f), args.per)
    gi = np.setdiff1d(np.arange(len(f)), qi)
    q, g = f[qi], f[gi]
    ids = (pid[qi], pid[gi], cam[qi], cam[gi])
    qg, qq, gg = distance_matrix(q, g), distance_matrix(q, q), distance_matrix(g, g)
    plain = evaluate_rank(qg, *ids)
    t = time.perf_counter()
    ours = k_reciprocal_rerank(qg, qq, gg)
    t_ours = time.perf_counter() - t
    rr = evaluate_rank(ours, *ids)
    out = {"queries": len(q), "gallery": len(g), "ours_s": t_ours,
           "plain": {"rank1": plain["rank1"], "map": plain["map"]},
           "reranked": {"rank1": rr["rank1"], "map": rr["map"]}}
    print(f"{len(q)} queries x {len(g)} gallery (512-d): mAP {100 * plain['map']:.2f} % -> "
          f"{100 * rr['map']:.2f} % re-ranked, rank-1 {100 * plain['rank1']:.2f} % -> "
          f"{100 * rr['rank1']:.2f} %")
    peer = load_peer(args.cache)
    if peer is not None:
        t = time.perf_counter()
        ref = peer(qg, qq, gg, k1=20, k2=6, lambda_value=0.3)
        t_peer = time.perf_counter() - t
        top = 10
        agree = float((np.argsort(ref, 1, kind="stable")[:, :top]
                       == np.argsort(ours, 1, kind="stable")[:, :top]).mean())
        diff = float(np.abs(ref - ours).max())
        out.update({"peer": PEER, "peer_s": t_peer, "speedup": t_peer / t_ours,
                    "max_abs_diff": diff, "top10_agreement": agree})
        print(f"torchreid re_ranking: max |difference| {diff:.2e}, top-{top} order agreement "
              f"{100 * agree:.2f} %; time {t_ours:.2f} s (dashtraj) vs {t_peer:.2f} s "
              f"(torchreid): {t_peer / t_ours:.1f}x")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
