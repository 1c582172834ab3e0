"""Evaluation on the VeRi-776 protocol (numpy only).

A VeRi-layout folder holds ``image_query/`` (queries), ``image_test/`` (the gallery) and
usually ``image_train/``; each image is named ``<id>_c<cam>_<rest>.jpg`` (VeRi-776's
own names, e.g. ``0002_c002_00030600_0.jpg``, and dashtraj's ``reid-dataset`` names).
For each query the gallery is ranked by distance; gallery images of the query's
identity seen by the query's camera are removed first (VeRi's rule: a match must come
from another camera). Then, over the queries that keep at least one true match:

- CMC rank-k: the share of queries with a true match among the first k (the paper's
  Eq. 10, averaged);
- AP: the mean over the true matches of the precision at each match's rank; mAP the
  mean AP;
- INP (Ye et al. 2021): (number of true matches) / (rank of the hardest, i.e. last,
  true match); mINP the mean.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dashtraj.errors import DashtrajError

VERI_NAME = re.compile(r"^(\d+)_c(\d+)_.*\.(?:jpe?g|png)$", re.IGNORECASE)
"""Identity and camera of a VeRi image name: ``<id>_c<cam>_<anything>.jpg``."""
QUERY_SETS = ("image_query", "image_query_moving")


class VeriLayoutError(DashtrajError):
    """A folder is not in the VeRi-776 layout; the message names the folder or file."""


class NoTrueMatchError(DashtrajError, ValueError):
    """No query has an image of its identity from another camera in the gallery, so
    there is nothing to rank (VeRi's rule excludes the query's own camera)."""


@dataclass(frozen=True)
class VeriSplit:
    """The images of one folder of a VeRi-layout set.

    paths: image files, sorted by name. pids: identity per image (the name's id).
    camids: camera per image (the name's c<cam>).
    """

    paths: tuple[Path, ...]
    pids: np.ndarray
    camids: np.ndarray

    def __len__(self) -> int:
        return len(self.paths)


def read_split(folder: str | Path) -> VeriSplit:
    """All images of a VeRi folder (``image_train``, ``image_query``, ...).

    Raises VeriLayoutError: the folder is missing, empty, or holds a file whose name is
    not ``<id>_c<cam>_....jpg``.
    """
    d = Path(folder)
    if not d.is_dir():
        raise VeriLayoutError(f"{d}: no such folder (a VeRi-776 layout needs image_query/ and "
                              "image_test/ with <id>_c<cam>_....jpg images)")
    paths, pids, cams = [], [], []
    for p in sorted(d.iterdir()):
        if not p.is_file() or p.name.startswith("."):
            continue
        m = VERI_NAME.match(p.name)
        if m is None:
            if p.suffix.lower() in (".jpg", ".jpeg", ".png"):
                raise VeriLayoutError(f"{p}: not a VeRi image name (<id>_c<cam>_....jpg)")
            continue  # e.g. Thumbs.db
        paths.append(p)
        pids.append(int(m.group(1)))
        cams.append(int(m.group(2)))
    if not paths:
        raise VeriLayoutError(f"{d}: no <id>_c<cam>_....jpg images")
    return VeriSplit(tuple(paths), np.asarray(pids, np.int64), np.asarray(cams, np.int64))


def open_veri(root: str | Path, query: str = "image_query") -> tuple[VeriSplit, VeriSplit]:
    """(query, gallery) of a VeRi-layout folder; the gallery is ``image_test``.

    Raises VeriLayoutError naming what is missing.
    """
    r = Path(root)
    if not r.is_dir():
        raise VeriLayoutError(f"--data {r}: " + ("a file, not a folder" if r.exists()
                                                 else "no such folder"))
    missing = [n for n in (query, "image_test") if not (r / n).is_dir()]
    if missing:
        raise VeriLayoutError(f"--data {r}: not a VeRi-776 layout folder (missing "
                              f"{', '.join(n + '/' for n in missing)}; expected image_query/, "
                              "image_test/ and optionally image_train/)")
    return read_split(r / query), read_split(r / "image_test")


def within_truncation(root: str | Path, q: VeriSplit, query: str,
                      max_truncation: float) -> VeriSplit:
    """The images of ``q`` (the folder ``query`` of ``root``) whose vehicle lies at most
    ``max_truncation`` outside the camera's frame (the share of its projected silhouette:
    0 whole, 1 all outside), from the crop labels ``labels_<stem>.csv`` that `dashtraj
    reid moving-queries` and ``moving-train`` write beside ``image_<stem>/``.

    Raises VeriLayoutError: no labels file (ring folders, and moving sets made before
    2026-12-07, have none), a bad one, or an image it does not list.
    """
    from dashtraj.datasets.frames import DatasetError
    from dashtraj.datasets.reid import moving_labels_path, read_moving_labels

    path = moving_labels_path(root, query.removeprefix("image_"))
    if not path.is_file():
        raise VeriLayoutError(f"{path} is missing (the crop labels that 'dashtraj reid "
                              "moving-queries' and 'moving-train' write since 2026-12-07; "
                              "rerun it with --overwrite)")
    try:
        labels = read_moving_labels(path)
    except DatasetError as exc:
        raise VeriLayoutError(str(exc)) from None
    keep = []
    for i, p in enumerate(q.paths):
        if p.name not in labels:
            raise VeriLayoutError(f"{path}: no row for {p.name}")
        if labels[p.name][0] <= max_truncation:
            keep.append(i)
    return VeriSplit(tuple(q.paths[i] for i in keep), q.pids[keep], q.camids[keep])


def l2_normalize(x: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (zero rows stay zero), float32."""
    x = np.asarray(x, np.float32)
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return x / np.maximum(n, 1e-12)


def distance_matrix(qf: np.ndarray, gf: np.ndarray) -> np.ndarray:
    """Squared Euclidean distances (n_query, n_gallery), float64, clipped at 0.

    The paper ranks by the L2 distance between feature vectors; the square ranks the same.
    """
    q = np.asarray(qf, np.float64)
    g = np.asarray(gf, np.float64)
    d = (q * q).sum(1)[:, None] + (g * g).sum(1)[None, :] - 2.0 * q @ g.T
    return np.maximum(d, 0.0)


def has_true_match(q: VeriSplit, g: VeriSplit) -> np.ndarray:
    """(n_query,) bool: the gallery holds an image of the query's identity from another
    camera (VeRi's rule; a query without one is skipped by `evaluate_rank`)."""
    same_id = g.pids[None, :] == q.pids[:, None]
    return (same_id & (g.camids[None, :] != q.camids[:, None])).any(axis=1)


def evaluate_rank(distmat: np.ndarray, q_pids, g_pids, q_camids, g_camids,
                  max_rank: int = 50) -> dict:
    """CMC, mAP and mINP under VeRi's rule (module docstring).

    Args:
        distmat: (n_query, n_gallery) distances; smaller is more similar. Ties are
            broken by gallery order (stable sort).
        q_pids, g_pids, q_camids, g_camids: identities and cameras.
        max_rank: length of the CMC curve returned.

    Returns:
        {"cmc": float array (max_rank,), "map", "minp", "rank1", "rank5", "rank10",
        "queries": queries evaluated, "skipped": queries without a true match left}.
        Fractions in [0, 1].
    """
    d = np.asarray(distmat, np.float64)
    q_pids, g_pids = np.asarray(q_pids), np.asarray(g_pids)
    q_camids, g_camids = np.asarray(q_camids), np.asarray(g_camids)
    nq, ng = d.shape
    if len(q_pids) != nq or len(g_pids) != ng:
        raise ValueError(f"distance matrix {d.shape} does not match {len(q_pids)} queries and "
                         f"{len(g_pids)} gallery images")
    cmc_sum = np.zeros(max_rank)
    aps, inps, skipped = [], [], 0
    for _, m in _veri_ranked(d, q_pids, g_pids, q_camids, g_camids):
        if not m.any():
            skipped += 1
            continue
        hits = np.flatnonzero(m)  # 0-based ranks of the true matches
        first = hits[0]
        if first < max_rank:
            cmc_sum[first:] += 1
        k = np.arange(1, len(hits) + 1)
        aps.append(float(np.mean(k / (hits + 1))))
        inps.append(len(hits) / (hits[-1] + 1))
    n = nq - skipped
    if n == 0:
        raise NoTrueMatchError("no query has a true match in the gallery from another camera "
                               "(VeRi's rule excludes the query's own camera)")
    cmc = cmc_sum / n
    return {"cmc": cmc, "map": float(np.mean(aps)), "minp": float(np.mean(inps)),
            "rank1": float(cmc[0]), "rank5": float(cmc[min(4, max_rank - 1)]),
            "rank10": float(cmc[min(9, max_rank - 1)]), "queries": n, "skipped": skipped}


def _veri_ranked(d: np.ndarray, q_pids, g_pids, q_camids, g_camids):
    """Per query, VeRi's ranking: (gallery indices by distance, ties by gallery order,
    with the query identity's images from the query's camera removed; whether each is
    a true match)."""
    order = np.argsort(d, axis=1, kind="stable")
    matches = g_pids[order] == q_pids[:, None]
    keep = ~(matches & (g_camids[order] == q_camids[:, None]))
    for i in range(d.shape[0]):
        yield order[i][keep[i]], matches[i][keep[i]]


def evaluate_features(qf, gf, q: VeriSplit, g: VeriSplit, normalize: bool = True,
                      rerank: dict | None = None, errors: bool = False) -> dict:
    """``evaluate_rank`` on the squared L2 distances of (optionally L2-normalised) features.

    ``rerank``: None, or the keyword arguments (``k1``, ``k2``, ``lambda_value``) of
    ``dashtraj.reid.rerank.k_reciprocal_rerank``, which then re-ranks the distances (it
    sees every query and gallery image; VeRi's same-camera rule applies to the result);
    the figures of the plain distances come beside, under ``"without_rerank"``.
    ``errors``: also list the rank-1 errors of the (re-ranked) distances under
    ``"rank1_errors"`` (``rank1_errors``).
    """
    if normalize:
        qf, gf = l2_normalize(qf), l2_normalize(gf)
    d = distance_matrix(qf, gf)
    plain = evaluate_rank(d, q.pids, g.pids, q.camids, g.camids)
    if rerank is None:
        return {**plain, "rank1_errors": rank1_errors(d, q, g)} if errors else plain
    from dashtraj.reid.rerank import k_reciprocal_rerank

    d = k_reciprocal_rerank(d, distance_matrix(qf, qf), distance_matrix(gf, gf), **rerank)
    out = {**evaluate_rank(d, q.pids, g.pids, q.camids, g.camids), "without_rerank": plain}
    return {**out, "rank1_errors": rank1_errors(d, q, g)} if errors else out


def rank1_errors(distmat: np.ndarray, q: VeriSplit, g: VeriSplit) -> list[dict]:
    """The queries whose nearest gallery image is another identity, under VeRi's rule (the
    query identity's images from the query's camera removed first), in query order.

    Each: ``query`` and ``nearest`` (file names), ``query_id`` and ``nearest_id``,
    ``distance`` (to the nearest), ``true_rank`` (1-based rank of the first true match)
    and ``true_distance``. Queries without a true match from another camera are left out,
    as ``evaluate_rank`` skips them. Ties are broken by gallery order, as there.
    """
    d = np.asarray(distmat, np.float64)
    out = []
    for i, (o, m) in enumerate(_veri_ranked(d, q.pids, g.pids, q.camids, g.camids)):
        if not m.any() or m[0]:
            continue
        first = int(np.argmax(m))
        out.append({"query": q.paths[i].name, "query_id": int(q.pids[i]),
                    "nearest": g.paths[o[0]].name, "nearest_id": int(g.pids[o[0]]),
                    "distance": float(d[i, o[0]]), "true_rank": first + 1,
                    "true_distance": float(d[i, o[first]])})
    return out


def identity_keys(root: str | Path) -> dict[int, str]:
    """Each identity's catalog key (``model/colour``) from the ``reid.json`` that
    ``dashtraj reid-dataset`` writes, by the id in the image names; {} for a folder
    without one (the real VeRi-776). Raises VeriLayoutError for an unreadable one."""
    import json

    path = Path(root) / "reid.json"
    if not path.is_file():
        return {}
    try:
        ids = json.loads(path.read_text(encoding="utf-8"))["ids"]
        return {int(e["id"]): str(e["key"]) for e in ids}
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise VeriLayoutError(f"{path}: not the reid.json of 'dashtraj reid-dataset' (no "
                              f"readable ids list with id and key: {exc})") from None
