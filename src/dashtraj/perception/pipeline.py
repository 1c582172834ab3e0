"""``dashtraj perceive``: a recording's observer frames → the sightings database.

Per observer, frame by frame (every `PerceiveConfig.every_s` seconds): render the
frame (`dashtraj.datasets.frames.recording_frames`; nothing is written to disk),
detect, localize, track, map-match, and crop the detections within the ReID range.
Batches of `batch_frames` frames are sent to the single writer (the calling process),
which commits each batch in one transaction (`SightingsDB.add_frames`). With an offline
localizer (``smoothed``) the frames are written with its forward (causal) estimate and
the observer's last batch rewrites every detection's position with the smoothed one
(same transaction as its last frames; the crops, cut while the frame was in memory,
are those within the ReID range by the forward estimate). With
``workers > 1`` observers are processed in parallel processes (spawned; each opens
its own renderer), and the database content is the same as with one worker; into a
PostgreSQL database (``db_path`` a URL: `dashtraj.store.backend`) each worker writes its
observers' batches itself, in its own connection (many writers), where SQLite's workers
send them to the one writer. Within a
process the work is pipelined (`PerceiveConfig.parallel_frames`): a thread renders the
frames ahead (`dashtraj.datasets.frames.RenderAhead`), a pool of threads runs the
detector model on several frames at once (onnxruntime releases Python's GIL while it
runs), and the calling thread tracks, localizes and crops them in order; the database
content is the same as without.
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing as mp
import queue as queue_mod
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from dashtraj.datasets.drive import Drive, is_drive
from dashtraj.datasets.frames import image_camera
from dashtraj.errors import DashtrajError
from dashtraj.perception.detect import DEFAULT_MIN_SCORE
from dashtraj.perception.detections import (
    AGNOSTIC_NMS_IOU,
    ORIENTATION_OF_CLASS,
    VEHICLE_CLASS_OF_CLASS,
    build_detector,
    depicted_vehicles,
)
from dashtraj.perception.localize import CameraPose, build_localizer
from dashtraj.perception.mapmatch import map_match
from dashtraj.perception.posenoise import noise_process
from dashtraj.perception.selfcal import PitchCalibrator
from dashtraj.perception.track import CONFIRM_SCORE, LiveRelink, Relink, build_tracker
from dashtraj.store import (
    CropRow,
    DetectionRow,
    LocationUpdate,
    PoseRow,
    SightingsDB,
    TrackRow,
)
from dashtraj.store.backend import is_url


class PerceiveError(DashtrajError):
    """Bad perception settings or a worker that failed (the message says which)."""


@dataclass(frozen=True, slots=True)
class PerceiveConfig:
    """Settings of one perception run; round-trips through JSON (`to_dict`/`from_dict`).

    Attributes:
        detector: "oracle" or a path to an .onnx model. tracker: "sort" or "ego".
        localizer: "paper", "ground", "fused", "tracked", "smoothed" or "mapped". mu_h: Eq. 3's
            constant (None: default).
        every_s: frame period, seconds (a multiple of the recording's step).
        size: (W, H) of the rendered images, pixels, or None for the recording's camera.
        msaa: colour-pass samples of the renderer (0 = none; boxes do not depend on it).
        reid_range_m: detections estimated this close keep their crop, metres.
        crop_long_side_px: crops larger than this are scaled down to it, pixels.
        jpeg_quality: crop JPEG quality. batch_frames: frames per committed batch.
        look: a `dashtraj.render.look` preset name for the frames, or None for the
            renderer's default look.
        threads: onnxruntime threads of each run of the detector model (None: 1).
        parallel_frames: frames detected at once, in threads, while a thread renders
            the next frames (None: 2 in one process, 1 per worker with ``workers > 1``,
            so that k workers keep k cores busy; 0: render, detect and the rest in turn on
            one thread). The database is the same whatever the value.
        agnostic_nms_iou: the detector model's class-agnostic NMS IoU (default
            `AGNOSTIC_NMS_IOU`; None: its class-aware NMS only;
            `dashtraj.perception.detections._ModelDetector`).
        min_score: the detector model's smallest kept score (the detector's own score,
            before a ``classifier`` scales it).
        classifier: the detector model's second stage, a box classifier ONNX path
            (`dashtraj.perception.detect.BoxClassifier`: each box's classes, and a refining
            one's background and box), or None.
        confirm_score: the ``ego`` tracker reports a track once one of its boxes scored
            at least this much (`EgoTracker.confirm_score`; the oracle's boxes score 1).
        pose_noise: errors added to every observer's camera pose before it is used
            (`dashtraj.perception.posenoise`: (xy_m, yaw_deg, pitch_deg, tau_s), a real
            drive's GNSS/INS), or None for the exact poses; the truth stays exact.
        pose_noise_seed: the seed of those errors (with the observer id).
        calibrate_pitch: correct every observer's camera pitch by what the vehicles it
            sees say of the horizon (`dashtraj.perception.selfcal.PitchCalibrator`): for
            drives whose camera mount or INS pitch is known only to a degree or so.
        live_relink: the ``ego`` tracker's ids re-linked by appearance as the frames come
            (`dashtraj.perception.track.LiveRelink`; every box at least
            ``Relink.min_box_px`` high at 720 rows embedded by ``reid_model``): the tracks
            of one vehicle that a gap split share one id, and a track that went on with
            another vehicle's boxes is cut.
        reid_model: the ReID .onnx model of ``live_relink`` (None: the shipped one).
    """

    detector: str = "oracle"
    tracker: str = "ego"
    localizer: str = "smoothed"
    mu_h: float | None = None
    every_s: float = 0.1
    size: tuple[int, int] | None = None
    msaa: int = 0
    reid_range_m: float = 15.0
    crop_long_side_px: int = 256
    jpeg_quality: int = 90
    batch_frames: int = 50
    observers: tuple[int, ...] | None = field(default=None)
    look: str | None = None
    threads: int | None = None
    parallel_frames: int | None = None
    agnostic_nms_iou: float | None = AGNOSTIC_NMS_IOU
    min_score: float = DEFAULT_MIN_SCORE
    classifier: str | None = None
    confirm_score: float = CONFIRM_SCORE
    pose_noise: tuple[float, float, float, float] | None = None
    pose_noise_seed: int = 0
    calibrate_pitch: bool = False
    live_relink: bool = False
    reid_model: str | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> PerceiveConfig:
        d = dict(d)
        if d.get("size") is not None:
            d["size"] = tuple(d["size"])
        for key in ("observers", "pose_noise"):
            if d.get(key) is not None:
                d[key] = tuple(d[key])
        d.setdefault("confirm_score", 0.0)  # written before the rule: every track reported
        return cls(**d)


@dataclass
class Batch:
    """Rows of a batch of frames of one observer, ready for `SightingsDB.add_frames`."""

    observer_id: int
    poses: list = field(default_factory=list)
    detections: list = field(default_factory=list)
    crops: list = field(default_factory=list)
    tracks: list = field(default_factory=list)
    updates: list = field(default_factory=list)
    """`LocationUpdate` rows: detections written earlier get new positions (an offline
    localizer's, when the observer's frames ended)."""


def camera_pose_of(frame, spec) -> CameraPose:
    """`CameraPose` of a rendered frame (road elevation = camera z − mount height)."""
    cx, cy, cz, cyaw, cpitch, _ = frame.frame_data.camera_pose
    return CameraPose(cx, cy, cz, cyaw, cpitch, cz - spec.z_m)


class _TrackStats:
    def __init__(self):
        self.stats: dict[int, dict] = {}

    def add(self, tid: int, t: float, vclass: str, truth: int) -> None:
        s = self.stats.setdefault(tid, {"first": t, "last": t, "n": 0, "cls": {}, "truth": {}})
        s["last"] = t
        s["n"] += 1
        s["cls"][vclass] = s["cls"].get(vclass, 0) + 1
        if truth >= 0:
            s["truth"][truth] = s["truth"].get(truth, 0) + 1

    def rows(self, observer_id: int, ids) -> list[TrackRow]:
        out = []
        for tid in sorted(ids):
            s = self.stats[tid]
            cls = max(sorted(s["cls"]), key=lambda c: s["cls"][c])
            truth = (max(sorted(s["truth"]), key=lambda v: s["truth"][v]) if s["truth"]
                     else None)
            out.append(TrackRow(observer_id, int(tid), cls, s["first"], s["last"], s["n"],
                                truth))
        return out


def _detected(frames, detector, in_flight: int):
    """(frame, detections) for each frame of ``frames`` in order. With ``in_flight`` ≥ 1,
    up to that many frames are detected at once in a pool of threads (a model run
    releases Python's GIL), ahead of the caller's use."""
    if in_flight < 1:
        for rf in frames:
            yield rf, detector.detect(rf)
        return
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(in_flight, thread_name_prefix="dashtraj-detect") as pool:
        pending: deque = deque()
        try:
            for rf in frames:
                pending.append((rf, pool.submit(detector.detect, rf)))
                if len(pending) > in_flight:
                    f_rf, fut = pending.popleft()
                    yield f_rf, fut.result()
            while pending:
                f_rf, fut = pending.popleft()
                yield f_rf, fut.result()
        finally:
            for _, fut in pending:
                fut.cancel()


def observer_batches(recording, observer_id: int, config: PerceiveConfig, road_map,
                     renderer=None, frames_dir: Path | None = None,
                     frames=None, in_flight: int = 0) -> Iterator[Batch]:
    """Process one observer's frames; yields a `Batch` every `batch_frames` frames.

    ``frames``: the observer's `RecordingFrame`s (e.g. `RenderAhead.frames`), or None to
    render them here with ``renderer``. ``in_flight``: frames detected at once in
    threads (`_detected`; 0: in turn, on this thread)."""
    from dashtraj.datasets.frames import crop_vehicle, encode_jpeg, recording_frames

    spec = image_camera(recording, config.size)
    detector = build_detector(config.detector, 2 if config.threads is None else config.threads,
                              config.agnostic_nms_iou, config.min_score, config.classifier)
    tracker = build_tracker(config.tracker, spec, config.confirm_score)
    localizer = build_localizer(config.localizer, config.mu_h, road_map=road_map)
    # tracked/smoothed/mapped run an ego filter of their own: with the same settings it
    # is this tracker, updated once per frame (the same ids as updating both)
    shared = hasattr(localizer, "share_tracker") and localizer.share_tracker(tracker)
    noise = noise_process(config.pose_noise, config.pose_noise_seed, observer_id)
    live = embedder = None
    if config.live_relink:
        from dashtraj.reid.embed import ReidEmbedder

        embedder = ReidEmbedder(relink_model_path(config),
                                2 if config.threads is None else config.threads)
        live = LiveRelink()
        min_px = Relink.min_box_px * spec.height_px / 720.0
    calibrator = PitchCalibrator() if config.calibrate_pitch else None
    if calibrator is not None and getattr(localizer, "offline", False):
        localizer.pitch_calibrator = calibrator  # it re-localizes with the offline pitch
    tstats = _TrackStats()
    mount = recording.config.camera
    batch = Batch(observer_id)
    touched: set[int] = set()
    n = 0
    done: list[int] = []  # frame numbers, in order
    if frames is None:
        frames = recording_frames(recording, config.every_s, config.size, [observer_id],
                                  msaa=config.msaa, renderer=renderer)
    for rf, det in _detected(frames, detector, in_flight):
        pose = camera_pose_of(rf, spec)
        if noise is not None:  # what the observer's GNSS/INS would say
            pose = noise.apply(pose, rf.t)
        if calibrator is not None:  # the pitch the vehicles in view say
            pose = calibrator.correct(det.boxes, det.class_ids, spec, pose, rf.t)
        h = math.radians(pose.yaw_deg)
        gx = pose.x - mount.x_m * math.cos(h) + mount.y_m * math.sin(h)
        gy = pose.y - mount.x_m * math.sin(h) - mount.y_m * math.cos(h)
        batch.poses.append(PoseRow(observer_id, rf.frame, rf.t, gx, gy, pose.ground_z,
                                   pose.yaw_deg, pose.x, pose.y, pose.z, pose.yaw_deg,
                                   pose.pitch_deg))
        if frames_dir is not None:
            p = frames_dir / str(observer_id) / f"{rf.frame:06d}.jpg"
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(encode_jpeg(rf.frame_data.rgb))
        if getattr(localizer, "sequential", False):
            loc = localizer.localize(det.boxes, det.class_ids, spec, pose, t=rf.t,
                                     scores=det.scores)
        else:
            loc = localizer.localize(det.boxes, det.class_ids, spec, pose)
        done.append(rf.frame)
        ids = localizer.track_ids if shared else tracker.update(det, rf.t, pose)
        rgb = rf.frame_data.rgb
        if live is not None:  # the shared localizer updated ``tracker`` itself
            ids = live.update(rf.t, tracker.track_of, ids, det.class_ids, tracker.positions,
                              embedder.embed_boxes(rgb, det.boxes, min_px))
        mm = map_match(road_map, loc.x, loc.y)
        shown = det.truth_ids.copy()  # matched: its truth; unmatched: what the box shows
        unmatched = shown < 0
        if unmatched.any():
            shown[unmatched] = depicted_vehicles(rf, det.boxes[unmatched])
        for i in range(len(det)):
            c = int(det.class_ids[i])
            tid = int(ids[i])
            truth = int(det.truth_ids[i])
            vclass = VEHICLE_CLASS_OF_CLASS[c]
            b = det.boxes[i]
            batch.detections.append(DetectionRow(
                observer_id, rf.frame, i, rf.t, tid if tid > 0 else None,
                float(b[0]), float(b[1]), float(b[2]), float(b[3]), float(det.scores[i]), c,
                vclass, ORIENTATION_OF_CLASS[c], *_position(loc, mm, i),
                truth if truth >= 0 else None, int(shown[i]) if shown[i] >= 0 else None))
            if tid > 0:
                tstats.add(tid, rf.t, vclass, truth)
                touched.add(tid)
            if loc.distance_m[i] <= config.reid_range_m:
                big = max(b[2] - b[0], b[3] - b[1]) * 1.2 > config.crop_long_side_px
                img = crop_vehicle(rgb, b, 0.1,
                                   config.crop_long_side_px if big else None)
                batch.crops.append(CropRow(observer_id, rf.frame, i,
                                           encode_jpeg(np.asarray(img), config.jpeg_quality),
                                           img.width, img.height))
        n += 1
        if n % config.batch_frames == 0:
            batch.tracks = tstats.rows(observer_id, touched)
            touched = set()
            yield batch
            batch = Batch(observer_id)
    batch.tracks = tstats.rows(observer_id, touched)
    if getattr(localizer, "offline", False):
        batch.updates = _location_updates(observer_id, done, localizer.smoothed(), road_map)
    yield batch


def _position(loc, mm, i: int) -> tuple:
    """Detection ``i``'s position columns (distance_m … lateral_m of ``detections``)."""
    return (float(loc.distance_m[i]), float(loc.bearing_deg[i]), float(loc.x[i]),
            float(loc.y[i]), float(mm.z[i]), int(mm.road_id[i]), int(mm.section_id[i]),
            int(mm.lane_id[i]), float(mm.s[i]), float(mm.lateral_m[i]))


def _location_updates(observer_id: int, frames: list[int], locs, road_map
                      ) -> list[LocationUpdate]:
    """Rows rewriting each detection's position (frame by frame, ``locs[i]`` of
    ``frames[i]``), map-matched again."""
    out = []
    for frame, loc in zip(frames, locs, strict=True):
        mm = map_match(road_map, loc.x, loc.y)
        out.extend(LocationUpdate(observer_id, frame, i, *_position(loc, mm, i))
                   for i in range(len(loc.x)))
    return out


def _process_config(config: PerceiveConfig, workers: int) -> PerceiveConfig:
    """``config`` with its automatic settings chosen for a process among ``workers``:
    `PerceiveConfig.threads` 1; `PerceiveConfig.parallel_frames` 2 in one process, 1 per
    worker process (so that k workers keep k cores busy)."""
    return replace(config,
                   threads=1 if config.threads is None else config.threads,
                   parallel_frames=((2 if workers <= 1 else 1) if config.parallel_frames is None
                                    else config.parallel_frames))


def _all_batches(recording, observers: list[int], configs: list[PerceiveConfig], road_map,
                 frames_dir: Path | None) -> Iterator[tuple[int, int, Batch | None]]:
    """(output, observer, batch) for every batch of every observer in order, then (output,
    observer, None) when that observer is done for that output. ``configs`` are a
    process's (`_process_config`), one per output, with the same frames (`_frames_key`):
    each frame is rendered once and every output's pipeline (detector, tracker, localizer)
    takes it in turn, a batch at a time. With ``parallel_frames`` ≥ 1 the frames are
    rendered ahead in a thread (`RenderAhead`) and detected that many at once; with 0
    everything runs in turn on this thread. The batches are the same either way, and the
    same as perceiving each output alone. A drive's frames are read from its images
    instead. ``frames_dir``: the frames written as JPEGs once (by the first output)."""
    import itertools

    from dashtraj.datasets.frames import RenderAhead, recording_frames, recording_renderer

    config = configs[0]  # the frames' settings, the same in every config
    look = None
    if config.look is not None:
        from dashtraj.render.look import preset

        look = preset(config.look)
    with contextlib.ExitStack() as stack:
        if isinstance(recording, Drive):  # its images are on disk: nothing to render
            frames_of = lambda o: recording.frames(o, config.every_s)  # noqa: E731
        elif config.parallel_frames:
            ahead = stack.enter_context(RenderAhead(
                recording, observers, config.every_s, config.size, config.msaa, look,
                depth=config.parallel_frames + 2))
            frames_of = ahead.frames
        else:
            renderer = recording_renderer(recording, config.size, config.msaa, look)
            stack.callback(renderer.release)
            frames_of = lambda o: recording_frames(  # noqa: E731
                recording, config.every_s, config.size, [o], msaa=config.msaa,
                renderer=renderer)
        for o in observers:
            sources = (itertools.tee(frames_of(o), len(configs)) if len(configs) > 1
                       else [frames_of(o)])
            runs = [observer_batches(recording, o, c, road_map, None,
                                     frames_dir if k == 0 else None, src, c.parallel_frames)
                    for k, (c, src) in enumerate(zip(configs, sources, strict=True))]
            live = list(range(len(runs)))
            while live:  # a batch of each in turn: the frames between them are kept once
                for k in list(live):
                    b = next(runs[k], None)
                    if b is None:
                        live.remove(k)
                    yield k, o, b


def _frames_key(config: PerceiveConfig) -> tuple:
    """The settings that make a run's frames (outputs perceived together share them)."""
    return (config.every_s, config.size, config.msaa, config.look, config.observers)


def open_source(path: str | Path):
    """What ``perceive`` reads: a drive folder (`dashtraj.datasets.drive.Drive`: images
    and camera poses on disk) or a simulated recording (its frames rendered on the fly;
    an interrupted recording's warning silenced)."""
    import warnings

    from dashtraj.world.recording import Recording

    if is_drive(path):
        return Drive.open(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return Recording.open(path)


SOURCE_FILES = ("meta.json", "states.parquet", "vehicles.csv", "map.xodr")
"""The files that define a simulated recording (its frames are rendered from them)."""
DRIVE_FILES = ("drive.json", "poses.csv", "truth.csv", "map.xodr")
"""The files that define a drive besides its images (the cameras' poses, its truth)."""


def source_sha256(recording) -> str:
    """The sha256 of what a perception run reads, whatever its path: a recording's
    `SOURCE_FILES`, a drive's `DRIVE_FILES` (``meta`` ``source_sha256`` of a sightings
    database: `dashtraj.store.append` appends only observers of the same source)."""
    from dashtraj.digest import files_sha256

    return files_sha256(recording.path,
                        DRIVE_FILES if isinstance(recording, Drive) else SOURCE_FILES)


def detector_sha256(detector: str) -> str:
    """``"oracle"``, or the sha256 of the detector model file."""
    from dashtraj.digest import file_sha256

    return detector if detector == "oracle" else file_sha256(detector)


def run_meta(recording, config: PerceiveConfig) -> dict[str, str]:
    """The ``meta`` rows a perception run adds: ``source_sha256``, ``detector_sha256``,
    and with `PerceiveConfig.live_relink` ``relink_model_sha256`` (its ReID model's)."""
    meta = {"source_sha256": source_sha256(recording),
            "detector_sha256": detector_sha256(config.detector)}
    if config.live_relink:
        from dashtraj.digest import file_sha256

        meta["relink_model_sha256"] = file_sha256(relink_model_path(config))
    return meta


def relink_model_path(config: PerceiveConfig) -> Path:
    """The ReID model of `PerceiveConfig.live_relink`."""
    from dashtraj.reid.embed import shipped_model_path

    return Path(config.reid_model) if config.reid_model else shipped_model_path()


def perceive_identity(recording, config: PerceiveConfig) -> dict:
    """What a run of ``config`` on ``recording`` would be, for
    `dashtraj.store.append.same_run` (checked before any work by ``perceive --append``)."""
    from dashtraj.store.append import run_identity

    return run_identity(run_meta(recording, config),
                        recording.meta.get("map", {}).get("sha256"),
                        image_camera(recording, config.size).to_dict(), config.to_dict())


def check_relink_config(config: PerceiveConfig) -> None:
    """PerceiveError for `PerceiveConfig.live_relink` with a tracker other than ``ego``
    (the re-linking needs every detection's track, `EgoTracker.track_of`) or a ReID model
    file that is not there."""
    if not config.live_relink:
        return
    if config.tracker != "ego":
        raise PerceiveError(f"--live-relink re-links the ego tracker's tracks; --tracker is "
                            f"{config.tracker!r}")
    if not relink_model_path(config).is_file():
        raise PerceiveError(f"--reid-model {config.reid_model!r}: no such file")


def check_drive_config(config: PerceiveConfig, drive: Drive) -> None:
    """Refuse the settings that need a renderer (PerceiveError naming the option): a
    drive's images are what they are; and the ``oracle`` detector on a drive without
    ``truth.csv``."""
    if config.detector == "oracle" and drive.truth is None:
        raise PerceiveError(f"{drive.path} has no truth.csv for --detector oracle; give a "
                            "detector model (--detector M.onnx, e.g. the shipped "
                            "src/dashtraj/data/detector/detector.onnx)")
    for name, value, default in (("size", config.size, None), ("msaa", config.msaa, 0),
                                 ("look", config.look, None)):
        if value != default:
            raise PerceiveError(f"--{name} applies to rendered recordings; a drive's images "
                                "are used as they are")


def _worker(recording_path: str, observers: list[int], config_dicts: list[dict], workers: int,
            out_q, frames_dir: str | None, db_urls: list[str | None] | None = None) -> None:
    """Process entry point: run `observer_batches` for each observer and each output and
    send the batches to the writer, tagged with their output, or, for an output with a
    URL in ``db_urls`` (PostgreSQL: many writers), write them there in this process's own
    connection and send the frame counts."""
    try:
        from dashtraj.roads import RoadMap

        configs = [_process_config(PerceiveConfig.from_dict(d), workers) for d in config_dicts]
        urls = list(db_urls) if db_urls else [None] * len(configs)
        rec = open_source(recording_path)
        road_map = RoadMap.from_file(rec.map_path)
        with contextlib.ExitStack() as stack:
            dbs = [stack.enter_context(SightingsDB.open(u, writable=True)) if u else None
                   for u in urls]
            for k, o, b in _all_batches(rec, observers, configs, road_map,
                                        Path(frames_dir) if frames_dir else None):
                db = dbs[k]
                if db is None:
                    out_q.put(("batch", (k, b)) if b is not None else ("done", (k, o)))
                elif b is None:
                    db.finish_observer(o)
                else:
                    db.add_frames(b.poses, b.detections, b.crops, b.tracks, b.updates)
                    out_q.put(("frames", (k, len(b.poses))))
    except BaseException as exc:  # reported to the writer, which raises
        out_q.put(("error", f"{type(exc).__name__}: {exc}"))
    out_q.put(("exit", None))


@dataclass(frozen=True)
class PerceiveSummary:
    """What a run wrote: observers, frames, detections, tracks, crops (``db_path``: the
    file, or the PostgreSQL URL without its password)."""

    db_path: Path | str
    observers: int
    frames: int
    detections: int
    tracks: int
    crops: int


def perceive(recording, db_path: str | Path, config: PerceiveConfig = PerceiveConfig(),
             workers: int = 1, progress: Callable[[int], None] | None = None,
             frames_dir: str | Path | None = None) -> PerceiveSummary:
    """Perceive every observer of ``recording`` into a new database at ``db_path``.

    Args:
        recording: a `dashtraj.world.recording.Recording` (its frames rendered), or a
            `dashtraj.datasets.drive.Drive` (its images read; see `check_drive_config`).
        db_path: the database file to create (must not exist; see `atomic_output`), or a
            PostgreSQL URL whose schema must not exist (`pg_atomic_output`).
        config: the settings. workers: observer processes (1 = in this process).
        progress: called with the number of frames done after each batch.
        frames_dir: write the rendered frames as JPEGs under it (``<observer>/<frame>.jpg``).

    Raises:
        PerceiveError: unknown observers, or a worker failed.
    """
    return perceive_each(recording, [(db_path, config)], workers, progress, frames_dir)[0]


def perceive_each(recording, outputs: Sequence[tuple[str | Path, PerceiveConfig]],
                  workers: int = 1, progress: Callable[[int], None] | None = None,
                  frames_dir: str | Path | None = None) -> list[PerceiveSummary]:
    """Perceive ``recording`` into several new databases at once, one per (path, config)
    of ``outputs``, each frame rendered once: e.g. the error budget's exact boxes and
    detector model (`dashtraj.ablation`). Every database is the one `perceive` writes
    with its config alone, to the byte of its rows; the configs must agree on the
    frames (``every_s``, ``size``, ``msaa``, ``look``, ``observers``) and may differ in
    everything else (detector, tracker, localizer, …). Paths, URLs, the other arguments
    and errors as `perceive` (every path must not exist: see `atomic_output`); ``progress``
    counts the first output's frames.

    Raises:
        PerceiveError: as `perceive`, or configs whose frames differ, or no output.
    """
    from dashtraj.datasets.frames import observer_ids
    from dashtraj.roads import RoadMap

    if not outputs:
        raise PerceiveError("perceive_each: no output")
    configs = [c for _, c in outputs]
    frames = {_frames_key(c) for c in configs}
    if len(frames) > 1:
        raise PerceiveError("perceive_each: the outputs' frames differ (every_s, size, msaa, "
                            f"look, observers): {sorted(frames, key=repr)}")
    config = configs[0]
    for c in configs:
        if isinstance(recording, Drive):
            check_drive_config(c, recording)
        build_detector(c.detector)  # fail early on a bad name
        build_tracker(c.tracker)
        build_localizer(c.localizer)
        check_relink_config(c)
    if config.look is not None:
        from dashtraj.render.look import preset

        preset(config.look)
    all_obs = observer_ids(recording)
    obs = all_obs if config.observers is None else list(config.observers)
    bad = [o for o in obs if o not in all_obs]
    if bad:
        raise PerceiveError(f"--observers {bad}: not observers of {recording.path}; observers "
                            f"are {all_obs}")
    roles = recording.meta.get("observer_roles", {})
    spec = image_camera(recording, config.size)
    fdir = Path(frames_dir) if frames_dir is not None else None
    with contextlib.ExitStack() as stack:
        dbs = [stack.enter_context(SightingsDB.create(path)) for path, _ in outputs]
        for db, c in zip(dbs, configs, strict=True):
            db.write_run(str(recording.path), recording.meta.get("map", {}).get("source"),
                         recording.meta.get("map", {}).get("sha256"), spec.to_dict(),
                         c.to_dict(), [(o, roles.get(str(o))) for o in obs])
            db.set_meta(run_meta(recording, c))
        if workers <= 1 or len(obs) <= 1:
            road_map = RoadMap.from_file(recording.map_path)
            for k, o, b in _all_batches(recording, obs,
                                        [_process_config(c, 1) for c in configs], road_map,
                                        fdir):
                if b is None:
                    dbs[k].finish_observer(o)
                    continue
                dbs[k].add_frames(b.poses, b.detections, b.crops, b.tracks, b.updates)
                if progress is not None and k == 0:
                    progress(len(b.poses))
        else:
            _run_workers(recording, obs, configs, workers, dbs, progress, fdir,
                         [str(p) if is_url(p) else None for p, _ in outputs])
        summaries = []
        for db in dbs:
            db.finish_run()
            summaries.append(PerceiveSummary(db.path, len(obs), db.count("poses"),
                                             db.count("detections"), db.count("tracks"),
                                             db.count("crops")))
    return summaries


def _run_workers(recording, obs, configs, workers, dbs, progress, fdir,
                 db_urls: list[str | None]) -> None:
    ctx = mp.get_context("spawn")
    q = ctx.Queue(maxsize=4 * workers)
    k = min(workers, len(obs))
    urls = db_urls if any(db_urls) else None
    procs = [ctx.Process(target=_worker, daemon=True,
                         args=(str(recording.path), obs[i::k], [c.to_dict() for c in configs],
                               k, q, str(fdir) if fdir else None, urls)) for i in range(k)]
    for p in procs:
        p.start()
    live = k
    try:
        while live:
            try:
                kind, item = q.get(timeout=5.0)
            except queue_mod.Empty:
                if not any(p.is_alive() for p in procs):
                    raise PerceiveError("a perception worker died without a word") from None
                continue
            if kind == "batch":
                out, b = item
                dbs[out].add_frames(b.poses, b.detections, b.crops, b.tracks, b.updates)
                if progress is not None and out == 0:
                    progress(len(b.poses))
            elif kind == "frames":
                out, n = item
                if progress is not None and out == 0:
                    progress(n)
            elif kind == "done":
                out, o = item
                dbs[out].finish_observer(o)
            elif kind == "error":
                raise PerceiveError(f"perception worker failed: {item}")
            elif kind == "exit":
                live -= 1
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
            p.join(timeout=5)


def write_mot(db_path: str | Path, out_dir: str | Path) -> list[Path]:
    """MOTChallenge txt of a database's tracks, one file per observer: ``<observer>.txt``
    with lines frame, id, left, top, width, height, conf, −1, −1, −1 (frame = 1-based index
    of the processed frame; boxes in pixels). Returns the files written."""
    from dashtraj.store import SightingsDB

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    with SightingsDB.open(db_path) as db:
        for o in db.observers():
            oid = o["observer_id"]
            index = {p.frame: i + 1 for i, p in enumerate(db.poses(oid))}
            lines = [f"{index[d.frame]},{d.track_id},{d.x0:.2f},{d.y0:.2f},{d.x1 - d.x0:.2f},"
                     f"{d.y1 - d.y0:.2f},{d.score:.3f},-1,-1,-1"
                     for d in db.detections(oid) if d.track_id is not None]
            p = out / f"{oid}.txt"
            p.write_text("".join(line + "\n" for line in lines), encoding="utf-8")
            written.append(p)
    return written
