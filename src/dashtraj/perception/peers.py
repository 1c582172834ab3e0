"""BoxMOT's trackers (ByteTrack, OC-SORT, BoT-SORT with ECC camera-motion compensation) as
peers on the same detections, when the ``boxmot`` package can be imported.

BoxMOT needs torch, which the run time does not install: the peers live in the
``bench`` extra's world and are skipped (with the reason) where the import fails.
Each adapter takes the frame's `Detections` and image and returns, per detection, the
BoxMOT track id (−1 when BoxMOT reported no track for it), read from BoxMOT's
``det_ind`` output column.
"""

from __future__ import annotations

import numpy as np

PEER_NAMES: tuple[str, ...] = ("bytetrack", "ocsort", "botsort")


def _import_boxmot():
    try:
        import boxmot
    except Exception as exc:  # ImportError or a broken torch install
        return None, f"{type(exc).__name__}: {exc}"
    return boxmot, None


class _BoxmotAdapter:
    def __init__(self, tracker, name: str):
        self.tracker = tracker
        self.name = name

    def update(self, det, t, pose, rgb) -> np.ndarray:
        n = len(det)
        dets = np.column_stack([det.boxes, det.scores, det.class_ids]).astype(np.float32) \
            if n else np.zeros((0, 6), np.float32)
        img = rgb[..., ::-1].copy() if rgb is not None else np.zeros((720, 1280, 3), np.uint8)
        out = self.tracker.update(dets, img)
        ids = np.full(n, -1, np.int64)
        if out is not None and len(out):
            out = np.asarray(out)
            di = out[:, 7].astype(np.int64)
            ok = (di >= 0) & (di < n)
            ids[di[ok]] = out[ok, 4].astype(np.int64) + 1  # BoxMOT counts ids from 0
        return ids


def boxmot_peers(names=PEER_NAMES) -> tuple[dict, str | None]:
    """({name: factory(spec) → adapter}, None) or ({}, why BoxMOT cannot run here)."""
    boxmot, why = _import_boxmot()
    if boxmot is None:
        return {}, why
    factories = {}
    for name in names:
        if name == "bytetrack":
            cls = getattr(boxmot, "ByteTrack", None) or getattr(boxmot, "BYTETracker", None)
            factories[name] = (lambda c: lambda spec: _BoxmotAdapter(c(), "bytetrack"))(cls)
        elif name == "ocsort":
            cls = getattr(boxmot, "OcSort", None) or getattr(boxmot, "OCSORT", None)
            factories[name] = (lambda c: lambda spec: _BoxmotAdapter(c(), "ocsort"))(cls)
        elif name == "botsort":
            cls = getattr(boxmot, "BotSort", None) or getattr(boxmot, "BoTSORT", None)

            def make(spec, c=cls):  # no ReID model: motion, IoU and ECC camera compensation
                return _BoxmotAdapter(c(use_embeddings=False, cmc_method="ecc"), "botsort")
            factories[name] = make
    return factories, None
