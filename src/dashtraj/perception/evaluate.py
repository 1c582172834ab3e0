"""Evaluations of the perception stages against the renderer's truth (or a drive's
``truth.csv``: its vehicles' 3-D boxes projected into each frame, hugging the vehicles'
pixels where the frame has a depth image; `dashtraj.datasets.drive_truth`).

- `tracker_eval`: every tracker (ours and the BoxMOT peers that can run) is fed the same
  detections of every observer's frames, in one pass over the rendered frames; scored
  with HOTA, IDF1 and MOTA (`dashtraj.perception.mot_metrics`) against the renderer's
  identities (the oracle's boxes and vehicle ids: visible box ≥ 8 px high, ≥ 10 % of
  the silhouette visible). The tracker's output for a detection is the detection's box
  with the track id (−1, unconfirmed, is no output).
- `localization_eval`: every estimator localizes the same detections (a sequential one,
  ``tracked`` or ``smoothed``, sees every frame at perceive's rate as well); errors against
  the true vehicle centre (CARLA world, ground plane) and the true ground distance from
  the camera; RMSE and median in the bands < 20 m and 20–60 m of true distance.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.perception.detect import DEFAULT_MIN_SCORE
from dashtraj.perception.detections import (
    AGNOSTIC_NMS_IOU,
    OracleDetector,
    build_detector,
    truth_of,
)
from dashtraj.perception.localize import build_localizer
from dashtraj.perception.mot_metrics import Sequence, counts, summarize
from dashtraj.perception.pipeline import camera_pose_of, image_camera
from dashtraj.perception.track import (
    CONFIRM_SCORE,
    LiveRelink,
    Relink,
    backfill,
    build_tracker,
)

BANDS_M = {"lt20": (0.0, 20.0), "20_60": (20.0, 60.0)}


@dataclass
class EvalFrame:
    """One rendered frame's detections, truth and pose (no image kept unless asked)."""

    observer_id: int
    frame: int
    t: float
    pose: object
    detections: object
    truth: object
    rgb: np.ndarray | None
    scored: object = None
    true_pose: object = None
    """The exact camera pose when ``pose`` is perturbed (``pose_noise``), else None."""
    pitch_calibrator: object = None
    """The observer's `PitchCalibrator` that corrected ``pose`` (``calibrate_pitch``;
    it has seen this frame and the observer's earlier ones), else None."""


IGNORE_BELOW_PX = 20.0
IGNORE_BELOW_VISIBLE = 0.3
"""The detector protocol's ignore regions (its model card: vehicles under 20 px high or
more than 70 % occluded are not expected to be found; px at 1280 x 720, scaled with the
image height): truth boxes of the oracle that fall under either are ignore regions in the
``ignore_regions`` scores of `tracker_eval`."""


def eval_frames(recording, detector: str = "oracle", every_s: float = 0.1, size=None,
                observers=None, keep_rgb: bool = False,
                agnostic_iou: float | None = AGNOSTIC_NMS_IOU,
                min_score: float = DEFAULT_MIN_SCORE, pose_noise=None,
                pose_noise_seed: int = 0, calibrate_pitch: bool = False
                ) -> Iterator[EvalFrame]:
    """Render each observer's frames (a drive's: read, with its truth); yield detections
    and truth (observer by observer).
    ``agnostic_iou``, ``min_score``: a detector model's class-agnostic NMS and smallest kept
    score (`build_detector`). ``pose_noise``, ``pose_noise_seed``: the frames' camera poses
    perturbed as `PerceiveConfig.pose_noise` does (the truth stays exact).
    ``calibrate_pitch``: then their pitch corrected as `PerceiveConfig.calibrate_pitch`
    does (causally; `EvalFrame.pitch_calibrator` holds each observer's calibrator)."""
    from dashtraj.datasets.frames import source_frames
    from dashtraj.perception.posenoise import noise_process
    from dashtraj.perception.selfcal import PitchCalibrator

    spec = image_camera(recording, size)
    det = build_detector(detector, agnostic_iou=agnostic_iou, min_score=min_score)
    floor_px = OracleDetector.min_height_px  # the scored truth is a subset of the truth
    floor_vis = OracleDetector.min_visible_fraction
    noise: dict = {}
    cals: dict = {}
    for rf in source_frames(recording, every_s, size, observers, msaa=0):
        if rf.observer_id not in noise:
            noise[rf.observer_id] = noise_process(pose_noise, pose_noise_seed, rf.observer_id)
            cals[rf.observer_id] = PitchCalibrator() if calibrate_pitch else None
        exact = camera_pose_of(rf, spec)
        proc = noise[rf.observer_id]
        pose = exact if proc is None else proc.apply(exact, rf.t)
        found = det.detect(rf)
        cal = cals[rf.observer_id]
        if cal is not None:
            pose = cal.correct(found.boxes, found.class_ids, spec, pose, rf.t)
        yield EvalFrame(rf.observer_id, rf.frame, rf.t, pose, found,
                        truth_of(rf), rf.frame_data.rgb if keep_rgb else None,
                        truth_of(rf, max(IGNORE_BELOW_PX * spec.height_px / 720.0, floor_px),
                                 max(IGNORE_BELOW_VISIBLE, floor_vis)),
                        None if pose is exact else exact, cal)


class EvalError(DashtrajError):
    """What is to be evaluated has no truth to score against."""


def open_recording(path):
    """A simulated recording (its frames rendered; an interrupted one's warning
    silenced), or a drive with a ``truth.csv`` (its images read, its truth boxes
    projected: `dashtraj.datasets.drive_truth`). EvalError for a drive without truth."""
    from dashtraj.datasets.drive import open_with_truth

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return open_with_truth(path, "nothing to score against", EvalError)


def _score_frame(seq: Sequence, iseq: Sequence, gt, sc, on_ignored: np.ndarray,
                 ids: np.ndarray, boxes: np.ndarray) -> None:
    """Add one frame's tracker output (``ids``, −1 = unreported) to the plain sequence
    (every oracle truth box) and to the ignore-region one (the boxes on ignored vehicles
    removed)."""
    ok = ids > 0
    seq.add(gt.truth_ids, gt.boxes, ids[ok], boxes[ok])
    ok &= ~on_ignored
    iseq.add(sc.truth_ids, sc.boxes, ids[ok], boxes[ok])


def tracker_eval(recordings, trackers=("sort", "ego"), peers=None, detector: str = "oracle",
                 every_s: float = 0.1, size=None,
                 agnostic_iou: float | None = AGNOSTIC_NMS_IOU,
                 min_score: float = DEFAULT_MIN_SCORE,
                 confirm_score: float = CONFIRM_SCORE, pose_noise=None,
                 pose_noise_seed: int = 0, calibrate_pitch: bool = False,
                 embedder=None, relink_settings: dict | None = None,
                 relink_embedder=None) -> dict:
    """HOTA / IDF1 / MOTA per tracker over every observer of every recording.

    Args:
        recordings: `Recording` objects. trackers: our tracker names.
        peers: {name: factory(spec) → tracker with ``update(det, t, pose, rgb)``}, or None.
        confirm_score: ``ego``'s `EgoTracker.confirm_score`.
        pose_noise, pose_noise_seed: the trackers get the observers' poses perturbed
            (`eval_frames`; `dashtraj.perception.posenoise`).
        calibrate_pitch: and their pitch self-calibrated (`eval_frames`).
        embedder: a `ReidEmbedder`, or None. With one, a tracker that reports each
            detection's track is also scored as ``"<name>+relink"``: its output with its
            tracks cut where their look changes and the tracks of one vehicle that a gap
            split re-linked by appearance
            (`dashtraj.perception.track.Relink`, ``relink_settings`` its settings; every
            box at least ``Relink.min_box_px`` high at 720 rows is embedded), and as
            ``"<name>+backfill+relink"``, its backfilled output re-linked, and as
            ``"<name>+live-relink"``, its output re-linked online as it comes
            (`dashtraj.perception.track.LiveRelink`, with ``relink_settings``' join and
            cut settings).
        relink_embedder: the offline re-linking's (``+relink``, ``+backfill+relink``)
            own `ReidEmbedder`, or None: ``embedder`` for both. ``+live-relink`` always
            uses ``embedder``.

    Returns:
        {tracker: {"hota", "deta", "assa", "idf1", "mota", "idsw", ..., "updates",
        "updates_per_s", "ignore_regions": {"hota", "idf1", "mota", ...}}} plus
        "sequences" and "frames". A tracker that reports each detection's track
        (``track_of``: ``ego``) is scored a second time as ``"<name>+backfill"``, its output
        with offline confirmation (`dashtraj.perception.track.Backfill`: a track's first
        boxes, before min_hits confirmed it, get its id; ``perceive`` keeps the online ids).
        The top-level scores count every truth box of the oracle (≥ 8 px high, ≥ 10 %
        visible); "ignore_regions" scores the same tracker
        output MOTChallenge-style with the boxes under `IGNORE_BELOW_PX` high or
        `IGNORE_BELOW_VISIBLE` visible as ignore regions: they are no truth, and tracker
        boxes on them (the detection's matched vehicle) are removed before scoring.
    """
    peers = peers or {}
    names = list(trackers) + list(peers)
    offline = [n for n in trackers if hasattr(build_tracker(n), "track_of")]
    rl_names = ([n + s for n in offline
                 for s in ("+relink", "+backfill+relink", "+live-relink")]
                if embedder is not None else [])
    all_counts: dict[str, list] = {n: [] for n in names + [n + "+backfill" for n in offline]
                                   + rl_names}
    ign_counts: dict[str, list] = {n: [] for n in all_counts}
    kept: dict[str, list] = {n: [] for n in offline}  # this observer's frames, for backfill
    relink_settings = relink_settings or {}
    min_px = Relink(**relink_settings).min_box_px  # at 720 rows
    relinks: dict[str, Relink] = {}
    live_settings = {k: v for k, v in relink_settings.items()
                     if k in LiveRelink.__dataclass_fields__}
    lives: dict[str, tuple] = {}  # name: (LiveRelink, Sequence, Sequence of ignore regions)

    def flush() -> None:
        for n in names:
            all_counts[n].append(counts(seqs[n]))
            ign_counts[n].append(counts(iseqs[n]))
        for n in offline:
            frames = kept[n]
            ids = backfill([f[-2] for f in frames], [f[-1] for f in frames])
            a, b = Sequence(), Sequence()
            for (gt, sc, on_ignored, boxes, _, _), x in zip(frames, ids, strict=True):
                _score_frame(a, b, gt, sc, on_ignored, x, boxes)
            all_counts[n + "+backfill"].append(counts(a))
            ign_counts[n + "+backfill"].append(counts(b))
            if n in relinks:
                for name, base in (("+relink", [f[-2] for f in frames]),
                                   ("+backfill+relink", ids)):
                    a, b = Sequence(), Sequence()
                    for (gt, sc, on_ignored, boxes, _, _), x in zip(
                            frames, relinks[n].apply(base), strict=True):
                        _score_frame(a, b, gt, sc, on_ignored, x, boxes)
                    all_counts[n + name].append(counts(a))
                    ign_counts[n + name].append(counts(b))
            if n in lives:
                all_counts[n + "+live-relink"].append(counts(lives[n][1]))
                ign_counts[n + "+live-relink"].append(counts(lives[n][2]))
            frames.clear()

    seconds = dict.fromkeys(names, 0.0)
    n_frames = n_seq = 0
    for rec in recordings:
        spec = image_camera(rec, size)
        current = None
        state: dict = {}
        seqs: dict = {}
        iseqs: dict = {}
        for ef in eval_frames(rec, detector, every_s, size,
                              keep_rgb=bool(peers) or embedder is not None,
                              agnostic_iou=agnostic_iou, min_score=min_score,
                              pose_noise=pose_noise, pose_noise_seed=pose_noise_seed,
                              calibrate_pitch=calibrate_pitch):
            if ef.observer_id != current:
                if current is not None:
                    flush()
                current = ef.observer_id
                n_seq += 1
                state = {n: build_tracker(n, spec, confirm_score) for n in trackers}
                state.update({n: f(spec) for n, f in peers.items()})
                if embedder is not None:
                    relinks = {n: Relink(**relink_settings) for n in offline}
                    lives = {n: (LiveRelink(**live_settings), Sequence(), Sequence())
                             for n in offline}
                seqs = {n: Sequence() for n in names}
                iseqs = {n: Sequence() for n in names}
            n_frames += 1
            d, gt, sc = ef.detections, ef.truth, ef.scored
            ignored = np.setdiff1d(gt.truth_ids, sc.truth_ids)
            on_ignored = np.isin(d.truth_ids, ignored)
            min_h = min_px * spec.height_px / 720.0
            emb = embedder.embed_boxes(ef.rgb, d.boxes, min_h) if embedder is not None else None
            emb_off = (relink_embedder.embed_boxes(ef.rgb, d.boxes, min_h)
                       if embedder is not None and relink_embedder is not None else emb)
            for n in names:
                t0 = time.perf_counter()
                if n in peers:
                    ids = state[n].update(d, ef.t, ef.pose, ef.rgb)
                else:
                    ids = state[n].update(d, ef.t, ef.pose)
                seconds[n] += time.perf_counter() - t0
                if n in kept:
                    kept[n].append((gt, sc, on_ignored, d.boxes, ids, state[n].track_of.copy()))
                if n in relinks:
                    relinks[n].add(ef.t, d.class_ids, state[n].positions, emb_off)
                if n in lives:
                    live, a, b = lives[n]
                    x = live.update(ef.t, state[n].track_of, ids, d.class_ids,
                                    state[n].positions, emb)
                    _score_frame(a, b, gt, sc, on_ignored, x, d.boxes)
                _score_frame(seqs[n], iseqs[n], gt, sc, on_ignored, ids, d.boxes)
        if current is not None:
            flush()
    out: dict = {"sequences": n_seq, "frames": n_frames}
    for n in all_counts:
        r = summarize(all_counts[n])
        r["updates"] = n_frames
        sec = seconds.get(n.split("+")[0], 0.0)
        r["updates_per_s"] = n_frames / sec if sec > 0 else None
        r["ignore_regions"] = summarize(ign_counts[n])
        out[n] = r
    return out


def truth_positions(rec):
    """``where(ef, vehicle_ids) -> (x, y)``: the true footprint centres of vehicles in an
    `EvalFrame` (a recording's state at the frame's step; a drive's truth at its time)."""
    from dashtraj.datasets.drive import Drive

    if isinstance(rec, Drive):
        def where(ef, vids):
            m = rec.truth.at(ef.t)
            j = np.searchsorted(m.vehicle_ids, vids)
            return m.x[j], m.y[j]

        return where
    keys, xs, ys, n_v = _truth_positions(rec)

    def where(ef, vids):
        j = np.searchsorted(keys, ef.frame * n_v + vids)
        return xs[j], ys[j]

    return where


def _truth_positions(rec):
    st = rec.states
    step = float(rec.meta.get("step_s", rec.config.traffic.step_s))
    k = np.round(st.column("t").to_numpy() / step).astype(np.int64)
    v = st.column("vehicle_id").to_numpy().astype(np.int64)
    n_v = int(v.max()) + 1
    key = k * n_v + v
    order = np.argsort(key)
    return key[order], st.column("x").to_numpy()[order], st.column("y").to_numpy()[order], n_v


def localization_eval(recordings, localizers=("paper", "ground", "fused", "tracked"),
                      detector: str = "oracle", every_s: float = 0.5, size=None,
                      mu_h: float | None = None, track_every_s: float = 0.1,
                      agnostic_iou: float | None = AGNOSTIC_NMS_IOU,
                      min_score: float = DEFAULT_MIN_SCORE, pose_noise=None,
                      pose_noise_seed: int = 0, calibrate_pitch: bool = False
                      ) -> tuple[dict, dict]:
    """Position and distance errors per estimator, in bands of true distance.

    ``pose_noise``, ``pose_noise_seed``: the estimators get the observers' poses perturbed
    (`eval_frames`; `dashtraj.perception.posenoise`); the errors are against the truth.
    ``calibrate_pitch``: and their pitch self-calibrated (`eval_frames`; the offline
    estimators re-localize with the offline estimate, as in `perceive`).

    Only detections matched to a vehicle count (all, with the oracle), in the frames every
    ``every_s`` seconds. A sequential estimator (``tracked``, ``smoothed``, ``mapped``: the
    recording's map) is fed every
    frame at ``track_every_s`` (perceive's default period), a new one per observer, and
    scored on the same frames as the others (an offline one, ``smoothed``, once the
    observer's frames ended; ``mapped`` too). Returns
    (summary {estimator: {"rmse_lt20_m", "median_lt20_m", "rmse_20_60_m",
    "median_20_60_m", "dist_rmse_lt20_m", "dist_rmse_20_60_m", "n_lt20", "n_20_60",
    "ignore_regions": the same figures over the detections of vehicles the detector
    protocol expects to be found (not under `IGNORE_BELOW_PX` high or `IGNORE_BELOW_VISIBLE`
    visible: `tracker_eval`'s ignore regions); every detection is still localized with the
    others in its frame}},
    samples {"true_m": (N,), "scored": (N,) bool, not on an ignore region; estimator: (N,)
    estimated distance, estimator + "_err": (N,) position error}).
    """
    from dashtraj.perception.localize import NEEDS_MAP

    road_map = None
    locs = {n: build_localizer(n, mu_h) for n in localizers}
    seq = [n for n, loc in locs.items() if getattr(loc, "sequential", False)]
    offline = [n for n in seq if getattr(locs[n], "offline", False)]
    period = min(track_every_s, every_s) if seq else every_s
    true_d: list = []
    on_scored: list = []
    est: dict = {n: [] for n in localizers}
    err: dict = {n: [] for n in localizers}
    scored: list = []  # this observer's scored frames: (index in its sequence, mask, tx, ty)

    def flush() -> None:  # an offline estimator scores an observer once it has all frames
        if not scored:
            return
        for n in offline:
            out = locs[n].smoothed()
            for i, m, tx, ty in scored:
                err[n].append(np.hypot(out[i].x[m] - tx, out[i].y[m] - ty))
                est[n].append(out[i].distance_m[m])
        scored.clear()

    for rec in recordings:
        spec = image_camera(rec, size)
        where = truth_positions(rec)
        if NEEDS_MAP & set(localizers):
            from dashtraj.roads import RoadMap

            road_map = RoadMap.from_file(rec.map_path)
        current = None
        index = 0
        for ef in eval_frames(rec, detector, period, size, agnostic_iou=agnostic_iou,
                              min_score=min_score, pose_noise=pose_noise,
                              pose_noise_seed=pose_noise_seed,
                              calibrate_pitch=calibrate_pitch):
            d = ef.detections
            if ef.observer_id != current:
                flush()
                current = ef.observer_id
                index = 0
                locs.update({n: build_localizer(n, mu_h, road_map=road_map) for n in seq})
                for n in offline:
                    locs[n].pitch_calibrator = ef.pitch_calibrator
            seq_out = {n: locs[n].localize(d.boxes, d.class_ids, spec, ef.pose, t=ef.t)
                       for n in seq}  # every frame, all detections: the tracks need them
            index += 1
            m = d.truth_ids >= 0
            k = ef.t / every_s
            if not m.any() or abs(k - round(k)) > 1e-6:
                continue
            tx, ty = where(ef, d.truth_ids[m])
            cam = ef.pose if ef.true_pose is None else ef.true_pose  # the true distance
            true_d.append(np.hypot(tx - cam.x, ty - cam.y))
            on_scored.append(np.isin(d.truth_ids[m], ef.scored.truth_ids))
            scored.append((index - 1, m, tx, ty))
            for n, loc in locs.items():
                if n in offline:
                    continue
                if n in seq_out:
                    o = seq_out[n]
                    err[n].append(np.hypot(o.x[m] - tx, o.y[m] - ty))
                    est[n].append(o.distance_m[m])
                    continue
                r = loc.localize(d.boxes[m], d.class_ids[m], spec, ef.pose)
                est[n].append(r.distance_m)
                err[n].append(np.hypot(r.x - tx, r.y - ty))
        flush()
    td = np.concatenate(true_d) if true_d else np.zeros(0)
    ok = np.concatenate(on_scored) if on_scored else np.zeros(0, bool)
    summary: dict = {}
    samples: dict = {"true_m": td, "scored": ok}
    for n in localizers:
        e = np.concatenate(err[n]) if err[n] else np.zeros(0)
        de = (np.concatenate(est[n]) if est[n] else np.zeros(0))
        samples[n] = de
        samples[n + "_err"] = e
        summary[n] = _band_errors(td, de, e, np.ones(len(td), bool))
        summary[n]["ignore_regions"] = _band_errors(td, de, e, ok)
    return summary, samples


def _band_errors(td: np.ndarray, de: np.ndarray, e: np.ndarray, keep: np.ndarray) -> dict:
    """Position RMSE and median, distance RMSE and counts per band of true distance, over
    the detections ``keep`` selects."""
    row: dict = {}
    for band, (lo, hi) in BANDS_M.items():
        sel = keep & (td >= lo) & (td < hi)
        k = int(sel.sum())
        row[f"n_{band}"] = k
        row[f"rmse_{band}_m"] = float(np.sqrt(np.mean(e[sel] ** 2))) if k else None
        row[f"median_{band}_m"] = float(np.median(e[sel])) if k else None
        row[f"dist_rmse_{band}_m"] = (float(np.sqrt(np.mean((de[sel] - td[sel]) ** 2)))
                                      if k else None)
    return row


def scatter_png(samples: dict, localizers, path) -> None:
    """Estimated vs true distance per estimator (PNG at ``path``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(localizers), figsize=(4.2 * len(localizers), 4.2),
                             squeeze=False)
    td = samples["true_m"]
    for ax, n in zip(axes[0], localizers, strict=True):
        ax.scatter(td, samples[n], s=3, alpha=0.4)
        hi = float(max(60.0, td.max() if len(td) else 60.0))
        ax.plot([0, hi], [0, hi], "k--", lw=0.8)
        ax.set_xlim(0, hi)
        ax.set_ylim(0, hi)
        ax.set_title(n)
        ax.set_xlabel("true distance (m)")
        ax.set_ylabel("estimated distance (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
