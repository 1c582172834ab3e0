"""A recording's observer frames, rendered, and the ``dashtraj render`` export.

For each observer of a recording and each sampled time t (every ``every_s`` seconds
on the recording's state grid, 20 Hz by default), the camera stands where
``dashtraj.world.camera.camera_poses`` mounts it on the observer (the recording's
``CameraSpec``: x_m forward, y_m right, z_m up from the observer's ground point,
pitched by ``pitch_deg``), so the rendered labels agree with the simulator's truth
(``truth.parquet``). Every other vehicle stands at its state (x, y, z, yaw; CARLA
world, metres, degrees) with the look of its identity (``vehicles.csv`` → catalog).

Instance ids in the rendered ``Frame`` are ``vehicle_id + 1`` (the renderer needs ids
≥ 1); ``RecordingFrame.vehicle_ids`` lists the vehicle id of each label in order.

Export (``export_frames``): ``DIR/<observer_id>/<frame:06d>.jpg`` (frame = state step
index, round(t / step_s)), JPEG quality 95, and ``DIR/labels.parquet`` with one row per
vehicle whose silhouette covers at least one pixel of the image (columns in
``LABEL_COLUMNS``; boxes in pixels, (x0, y0, x1, y1), exclusive ends; -1 where a
vehicle has no visible pixel).
"""

from __future__ import annotations

import io
import itertools
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from dashtraj.errors import DashtrajError

LABEL_COLUMNS = (
    "observer_id", "t", "frame", "image", "vehicle_id", "identity_id", "label", "class_id",
    "vis_x0", "vis_y0", "vis_x1", "vis_y1", "sil_x0", "sil_y0", "sil_x1", "sil_y1",
    "visible_fraction", "truncation", "distance_m",
)  # fmt: skip
"""Columns of the labels table written by ``export_frames``."""

JPEG_QUALITY = 95


class DatasetError(DashtrajError):
    """A dataset cannot be built from its inputs; the message names the file or element."""


@dataclass(frozen=True)
class RecordingFrame:
    """One rendered observer frame.

    Attributes:
        observer_id: the observer's vehicle id. t: seconds. frame: state step index.
        frame_data: the renderer's ``Frame`` (rgb, instance, depth, k, labels).
        vehicle_ids: (N,) vehicle id of each entry of ``frame_data.labels``.
        identity_ids: (N,) catalog identity id of each entry of ``frame_data.labels``.
    """

    observer_id: int
    t: float
    frame: int
    frame_data: object
    vehicle_ids: tuple[int, ...]
    identity_ids: tuple[int, ...]


def image_camera(recording, size: tuple[int, int] | None):
    """The `CameraSpec` of the rendered images (the recording's, resized)."""
    spec = recording.config.camera
    if size is None:
        return spec
    return replace(spec, width_px=int(size[0]), height_px=int(size[1]))


def parse_size(text: str) -> tuple[int, int]:
    """``"640x360"`` → (640, 360) pixels. Raises DatasetError naming the bad value."""
    try:
        w, h = (int(v) for v in str(text).lower().split("x"))
    except ValueError as e:
        raise DatasetError(f"bad image size {text!r}; expected WxH, e.g. 640x360") from e
    from dashtraj.world.camera import MAX_IMAGE_SIDE_PX as HI
    from dashtraj.world.camera import MIN_IMAGE_SIDE_PX as LO

    if w < LO or h < LO:
        raise DatasetError(f"image size {text!r} is too small (at least {LO}x{LO} pixels)")
    if w > HI or h > HI:
        raise DatasetError(f"image size {text!r} is too large (at most {HI}x{HI} pixels)")
    return w, h


def vehicle_identity(row: dict, source: str = "vehicles.csv"):
    """The catalog look (``VehicleIdentity``) of a ``vehicles.csv`` row.

    Uses ``catalog.identities()[identity_id]`` when its blueprint and colour match the
    row; otherwise builds the identity from the row's blueprint_id and color.
    Raises DatasetError naming ``source`` and the vehicle for an unknown blueprint/colour.
    """
    from dashtraj.world import catalog

    pool = catalog.identities()
    iid = int(row["identity_id"])
    if 0 <= iid < len(pool):
        ident = pool[iid]
        if ident.model.blueprint_id == row["blueprint_id"] and ident.color_name == row["color"]:
            return ident
    try:
        model = catalog.get_model(row["blueprint_id"])
        rgb = catalog.COLORS[row["color"]]
    except (catalog.UnknownBlueprintError, KeyError) as e:
        raise DatasetError(f"{source}: vehicle {row['vehicle_id']}: {e}") from e
    return catalog.VehicleIdentity(iid, model, row["color"], rgb)


def sample_steps(recording, every_s: float) -> np.ndarray:
    """State step indices (sorted, int) on the ``every_s`` grid that the states cover.

    Raises DatasetError if ``every_s`` is not a positive multiple of the state step.
    """
    step = float(recording.meta.get("step_s", recording.config.traffic.step_s))
    k = round(every_s / step)
    if every_s <= 0 or k < 1 or abs(k * step - every_s) > 1e-6:
        raise DatasetError(f"--every {every_s:g} s is not a positive multiple of the "
                           f"recording's state step {step:g} s ({recording.path})")
    t = np.unique(recording.states.column("t").to_numpy())
    steps = np.round(t / step).astype(np.int64)
    return steps[steps % k == 0]


def observer_ids(recording) -> list[int]:
    """Vehicle ids with role ``observer`` in ``vehicles.csv``, ascending."""
    return sorted(int(v["vehicle_id"]) for v in recording.vehicles if v["role"] == "observer")


def open_renderer(map_path, width: int, height: int, fov_deg: float, msaa: int = 4,
                  threads: int | None = 0, ctx=None):
    """A ``Renderer`` of the OpenDRIVE map at ``map_path`` (image W x H pixels, FOV deg).

    ``threads=0`` rasterizes on the calling thread (one core; bytes do not depend on it).
    Raises ``RenderUnavailableError`` when no GL context can be created.
    """
    from dashtraj.render.scene import Renderer
    from dashtraj.roads import RoadMap

    road_map = RoadMap.from_file(map_path)
    return Renderer(road_map, width, height, fov_deg, msaa=msaa, threads=threads, ctx=ctx)


def recording_renderer(recording, size: tuple[int, int] | None = None, msaa: int = 4,
                       look=None):
    """A renderer of ``recording``'s map for its camera (``size`` (W, H) pixels, or None
    for the camera's own), FOV the camera's; with ``look`` (a ``LookConfig``) set."""
    spec = recording.config.camera
    w, h = size if size is not None else (spec.width_px, spec.height_px)
    renderer = open_renderer(recording.map_path, w, h, spec.fov_deg, msaa=msaa)
    if look is not None:
        renderer.set_look(look)
    return renderer


def recording_frames(recording, every_s: float = 0.5, size: tuple[int, int] | None = None,
                     observers: Iterable[int] | None = None, msaa: int = 4,
                     renderer=None, look_for=None) -> Iterator[RecordingFrame]:
    """Render a recording's observer frames, observer by observer, time ascending.

    Args:
        recording: a ``dashtraj.world.recording.Recording``.
        every_s: sampling period, seconds (a multiple of the state step).
        size: (W, H) pixels, or None for the recording's ``CameraSpec`` size. The FOV
            stays the recording's, so boxes scale with the image.
        observers: observer vehicle ids, or None for all (role ``observer``).
        msaa: colour-pass samples.
        renderer: a ``Renderer`` of this map with the right size and FOV to reuse;
            None opens one (and releases it when the iterator is exhausted).
        look_for: None, or ``look_for(observer_id, frame) -> LookConfig`` called before
            each frame is rendered (domain randomization); the renderer keeps the
            last look.

    Yields:
        ``RecordingFrame`` per (observer, sampled time) at which the observer has a state.

    Raises:
        DatasetError: an observer id that is not an observer of the recording.
    """
    from dashtraj.world.camera import camera_poses

    spec = recording.config.camera
    w, h = size if size is not None else (spec.width_px, spec.height_px)
    obs_all = observer_ids(recording)
    obs = obs_all if observers is None else [int(o) for o in observers]
    bad = [o for o in obs if o not in obs_all]
    if bad:
        raise DatasetError(f"{recording.path / 'vehicles.csv'}: vehicles {bad} are not "
                           f"observers; observers are {obs_all}")
    idents = {int(v["vehicle_id"]): vehicle_identity(v, str(recording.path / "vehicles.csv"))
              for v in recording.vehicles}
    step = float(recording.meta.get("step_s", recording.config.traffic.step_s))
    steps = sample_steps(recording, every_s)
    st = recording.states
    t_all = st.column("t").to_numpy()
    k_all = np.round(t_all / step).astype(np.int64)
    keep = np.isin(k_all, steps)
    cols = {c: st.column(c).to_numpy()[keep] for c in ("vehicle_id", "x", "y", "z", "yaw")}
    k_all = k_all[keep]
    order = np.lexsort((cols["vehicle_id"], k_all))
    k_all = k_all[order]
    cols = {c: v[order] for c, v in cols.items()}
    bounds = np.flatnonzero(np.r_[True, k_all[1:] != k_all[:-1], True])
    own = renderer is None
    if own:
        renderer = recording_renderer(recording, size, msaa)
    elif (renderer.width, renderer.height) != (w, h) or abs(renderer.fov_deg - spec.fov_deg) > 1e-9:
        raise DatasetError(f"renderer is {renderer.width}x{renderer.height} FOV "
                           f"{renderer.fov_deg:g}, frames need {w}x{h} FOV {spec.fov_deg:g}")
    try:
        for o in obs:
            for a, b in itertools.pairwise(bounds.tolist()):
                vid = cols["vehicle_id"][a:b].astype(np.int64)
                hit = np.flatnonzero(vid == o)
                if len(hit) == 0:
                    continue
                i = a + int(hit[0])
                cx, cy, cz, cyaw = camera_poses(spec, cols["x"][i], cols["y"][i], cols["z"][i],
                                                cols["yaw"][i])
                pose = (float(cx), float(cy), float(cz), float(cyaw), spec.pitch_deg, 0.0)
                others = [j for j in range(a, b) if int(cols["vehicle_id"][j]) != o]
                vehicles = [(int(cols["vehicle_id"][j]) + 1, idents[int(cols["vehicle_id"][j])],
                             float(cols["x"][j]), float(cols["y"][j]), float(cols["z"][j]),
                             float(cols["yaw"][j])) for j in others]
                if look_for is not None:
                    renderer.set_look(look_for(o, int(k_all[a])))
                frame = renderer.render(pose, vehicles, labels=True)
                ids = tuple(v[0] - 1 for v in vehicles)
                k = int(k_all[a])
                yield RecordingFrame(o, round(k * step, 9), k, frame, ids,
                                     tuple(idents[v].identity_id for v in ids))
    finally:
        if own:
            renderer.release()


def source_frames(source, every_s: float, size: tuple[int, int] | None = None,
                  observers: Iterable[int] | None = None, msaa: int = 4
                  ) -> Iterator[RecordingFrame]:
    """The observer frames of a recording (rendered: `recording_frames`) or of a drive
    (its images read, with the truth's labels when it has a ``truth.csv``:
    `dashtraj.datasets.drive.Drive.frames`), observer by observer, time ascending.
    DatasetError for ``size`` on a drive (its images are what they are) or an unknown
    observer."""
    from dashtraj.datasets.drive import Drive

    if not isinstance(source, Drive):
        return recording_frames(source, every_s, size, observers, msaa=msaa)
    if size is not None:
        raise DatasetError(f"{source.path} is a drive: its images are used at their own size "
                           "(no --size)")
    obs = source.observer_ids if observers is None else [int(o) for o in observers]
    bad = [o for o in obs if o not in source.poses]
    if bad:
        raise DatasetError(f"{source.path / 'poses.csv'}: no observer {bad[0]}; observers are "
                           f"{source.observer_ids}")
    return (rf for o in obs for rf in source.frames(o, every_s))


class RenderAhead:
    """A recording's observer frames rendered in a background thread, up to ``depth``
    frames ahead of their use, so that the caller's work on one frame (detection,
    tracking) overlaps the rendering of the next ones.

    The thread opens its own renderer (a GL context is current in one thread only) and
    renders the ``observers`` in order, each with `recording_frames`; `frames` yields
    one observer's frames (the observers must be taken in that order). The frames are
    exactly those of `recording_frames` with the same arguments: the renderer draws the
    same poses in the same order, whatever the caller does meanwhile. Pure-Python work
    of the caller and of the thread takes turns (Python's GIL); the overlap comes from
    work that releases the GIL while it runs, such as an onnxruntime model run.

    Use as a context manager (`close` stops the thread and releases the renderer); an
    error in the thread (e.g. ``RenderUnavailableError``) is raised by `frames`. The
    process's GL setup (`dashtraj.render.gl.prepare_process`, which writes environment
    variables) runs on the calling thread first, with llvmpipe on the rendering thread
    alone (``LP_NUM_THREADS=0``, as `open_renderer`'s default).

    Args:
        recording: a ``dashtraj.world.recording.Recording``.
        observers: observer vehicle ids, in the order they will be taken.
        every_s, size, msaa: as for `recording_frames`.
        look: a ``LookConfig`` for the renderer, or None for its default.
        depth: frames rendered ahead (at least 1).
    """

    _POLL_S = 0.1

    def __init__(self, recording, observers: Iterable[int], every_s: float,
                 size: tuple[int, int] | None = None, msaa: int = 0, look=None,
                 depth: int = 3):
        import queue
        import threading

        from dashtraj.render.gl import prepare_process

        prepare_process(0)  # its os.environ writes must not race the thread's getenv
        self._obs = [int(o) for o in observers]
        self._next = 0
        self._out: queue.Queue = queue.Queue(maxsize=max(1, int(depth)))
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(recording, every_s, size, msaa, look),
            name="dashtraj-render", daemon=True)
        self._thread.start()

    def _put(self, item) -> bool:
        import queue

        while not self._stop.is_set():
            try:
                self._out.put(item, timeout=self._POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _run(self, recording, every_s, size, msaa, look) -> None:
        try:
            renderer = recording_renderer(recording, size, msaa, look)
            try:
                for o in self._obs:
                    for rf in recording_frames(recording, every_s, size, [o], msaa=msaa,
                                               renderer=renderer):
                        if not self._put(("frame", rf)):
                            return
                    if not self._put(("end", o)):
                        return
            finally:
                renderer.release()
        except BaseException as exc:  # handed to the consumer, which raises it
            self._put(("error", exc))

    def frames(self, observer_id: int) -> Iterator[RecordingFrame]:
        """The frames of the next observer (``observer_id``, which must be it), in time
        order, as `recording_frames` yields them."""
        import queue

        if self._next >= len(self._obs) or self._obs[self._next] != int(observer_id):
            want = self._obs[self._next] if self._next < len(self._obs) else None
            raise ValueError(f"RenderAhead: observer {observer_id} requested, the next one "
                             f"is {want}")
        self._next += 1
        while True:
            try:
                kind, item = self._out.get(timeout=self._POLL_S)
            except queue.Empty:
                if self._thread.is_alive():
                    continue
                raise RuntimeError("RenderAhead: the render thread stopped") from None
            if kind == "frame":
                yield item
            elif kind == "end":
                return
            else:
                raise item

    def close(self) -> None:
        """Stop the thread (it finishes the frame it is drawing) and wait for it."""
        import queue

        self._stop.set()
        while self._thread.is_alive():
            try:
                self._out.get(timeout=self._POLL_S)
            except queue.Empty:
                pass
        self._thread.join()

    def __enter__(self) -> RenderAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def encode_jpeg(rgb: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 image (Pillow, no EXIF; deterministic)."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).save(buf, format="JPEG", quality=int(quality))
    return buf.getvalue()


def crop_vehicle(rgb: np.ndarray, box, margin: float = 0.1, long_side_px: int | None = None):
    """Crop a box (x0, y0, x1, y1; pixels, exclusive ends) out of an (H, W, 3) image.

    The box grows by ``margin`` × its width/height on each side, clipped to the image;
    with ``long_side_px`` the crop is resized (bicubic) so its longer side is that many
    pixels, keeping the aspect ratio. Returns a Pillow ``Image``.
    """
    from PIL import Image

    x0, y0, x1, y1 = (float(v) for v in box)
    mw, mh = margin * (x1 - x0), margin * (y1 - y0)
    h, w = rgb.shape[:2]
    a0, b0 = max(0, math.floor(x0 - mw)), max(0, math.floor(y0 - mh))
    a1, b1 = min(w, math.ceil(x1 + mw)), min(h, math.ceil(y1 + mh))
    img = Image.fromarray(np.ascontiguousarray(rgb[b0:b1, a0:a1]))
    if long_side_px:
        s = long_side_px / max(img.width, img.height)
        size = (max(1, round(img.width * s)), max(1, round(img.height * s)))
        img = img.resize(size, Image.Resampling.BICUBIC)
    return img


def label_rows(rf: RecordingFrame, image: str) -> list[dict]:
    """Label-table rows (``LABEL_COLUMNS``) of the vehicles whose silhouettes touch the image."""
    rows = []
    for lab, vid, iid in zip(rf.frame_data.labels, rf.vehicle_ids, rf.identity_ids, strict=True):
        if lab.silhouette_box is None:
            continue
        vb = lab.visible_box if lab.visible_box is not None else (-1, -1, -1, -1)
        sb = lab.silhouette_box
        rows.append({
            "observer_id": rf.observer_id, "t": rf.t, "frame": rf.frame, "image": image,
            "vehicle_id": int(vid), "identity_id": int(iid), "label": lab.detection_class,
            "class_id": int(lab.detection_class_id),
            "vis_x0": int(vb[0]), "vis_y0": int(vb[1]), "vis_x1": int(vb[2]), "vis_y1": int(vb[3]),
            "sil_x0": int(sb[0]), "sil_y0": int(sb[1]), "sil_x1": int(sb[2]), "sil_y1": int(sb[3]),
            "visible_fraction": float(lab.visible_fraction), "truncation": float(lab.truncation),
            "distance_m": float(lab.distance_m),
        })
    return rows


@dataclass(frozen=True)
class ExportSummary:
    """What ``export_frames`` wrote: frame and label counts per observer, the paths."""

    out_dir: Path
    frames: int
    labels: int
    in_view: int
    per_observer: dict
    labels_path: Path
    preview_dir: Path | None


def write_recording_truth(recording, path, times) -> None:
    """Write a recording's vehicles at ``times`` (seconds, steps of the recording) as a
    drive's ``truth.csv`` (`dashtraj.datasets.drive_truth`): footprint centre, yaw and
    the catalog model's half extents of every vehicle with a state then."""
    from dashtraj.datasets.drive_truth import write_truth

    step = float(recording.meta.get("step_s", recording.config.traffic.step_s))
    want = np.round(np.asarray(times, np.float64) / step).astype(np.int64)
    st = recording.states
    k = np.round(st.column("t").to_numpy() / step).astype(np.int64)
    keep = np.isin(k, want)
    cols = {c: st.column(c).to_numpy()[keep] for c in ("vehicle_id", "x", "y", "z", "yaw")}
    where = str(recording.path / "vehicles.csv")
    info = {}
    for v in recording.vehicles:
        model = vehicle_identity(v, where).model
        info[int(v["vehicle_id"])] = (v.get("role", ""), model.blueprint_id, model.vehicle_class,
                                      model.length_m / 2, model.width_m / 2, model.height_m / 2)
    rows = []
    for kk, vid, x, y, z, yaw in zip(k[keep], cols["vehicle_id"], cols["x"], cols["y"],
                                     cols["z"], cols["yaw"], strict=True):
        role, bp, cls, hl, hw, hh = info[int(vid)]
        rows.append((round(int(kk) * step, 9), int(vid), role, bp, cls, x, y, z, yaw, hl, hw, hh))
    write_truth(path, rows)


def export_frames(recording, out_dir, every_s: float = 0.5, size: tuple[int, int] | None = None,
                  observers: Iterable[int] | None = None, preview: bool = False,
                  progress=None, compare_dir=None, image_format: str = "jpg",
                  depth: bool = False) -> ExportSummary:
    """Write a recording's observer frames as JPEGs (or PNGs) and their labels as Parquet.

    Files: ``out_dir/<observer_id>/<frame:06d>.jpg`` (``.png`` with ``image_format``
    "png": lossless), ``out_dir/labels.parquet`` (``LABEL_COLUMNS``), and the drive files
    (``drive.json``, ``poses.csv``, ``map.xodr``, ``truth.csv``, ``target_route.csv``:
    `dashtraj.datasets.drive`, `dashtraj.datasets.drive_truth`), so the
    folder is a drive that ``dashtraj perceive`` reads like a real one; with ``preview``
    also ``out_dir/preview/<observer>/<frame>.png``
    (boxes drawn), ``out_dir/preview/contact_sheet.jpg`` (crops per vehicle) and
    ``out_dir/preview/look_sheet.png`` (before/after the realistic look, beside the
    nearest frame of ``compare_dir`` if given; ``dashtraj.datasets.look_sheet``).
    Deterministic: the same inputs give byte-identical files.

    Args:
        progress: called with no argument after each frame, or None.
        depth: also write ``out_dir/<observer_id>/<frame:06d>.depth.png``, the frame's
            depth in CARLA's depth camera encoding (`dashtraj.datasets.drive_truth`).
        compare_dir: folder of reference frames (e.g. CARLA's) for the look sheet.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dashtraj.datasets import preview as pv

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    per_obs: dict[int, int] = {}
    from dashtraj.datasets.drive import DrivePose, write_drive

    if image_format not in ("jpg", "png"):
        raise DatasetError(f"image format {image_format!r}: expected jpg or png")
    sheet = pv.ContactSheet() if preview else None
    poses: list[DrivePose] = []
    for rf in recording_frames(recording, every_s, size, observers):
        rel = f"{rf.observer_id}/{rf.frame:06d}.{image_format}"
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if image_format == "png":
            from PIL import Image

            Image.fromarray(rf.frame_data.rgb).save(p, format="PNG")
        else:
            p.write_bytes(encode_jpeg(rf.frame_data.rgb))
        if depth:
            from PIL import Image

            from dashtraj.datasets.drive_truth import encode_depth

            Image.fromarray(encode_depth(rf.frame_data.depth)).save(
                out / f"{rf.observer_id}/{rf.frame:06d}.depth.png", format="PNG")
        cx, cy, cz, cyaw, cpitch, _ = rf.frame_data.camera_pose
        poses.append(DrivePose(rf.observer_id, rf.frame, rf.t, cx, cy, cz, cyaw, cpitch))
        rows.extend(label_rows(rf, rel))
        per_obs[rf.observer_id] = per_obs.get(rf.observer_id, 0) + 1
        if preview:
            pp = out / "preview" / str(rf.observer_id) / f"{rf.frame:06d}.png"
            pp.parent.mkdir(parents=True, exist_ok=True)
            pv.draw_labels(rf.frame_data.rgb, rf.frame_data.labels).save(pp, format="PNG")
            sheet.add_frame(rf)
        if progress is not None:
            progress()
    types = {"t": pa.float64(), "image": pa.string(), "label": pa.string(),
             "visible_fraction": pa.float64(), "truncation": pa.float64(),
             "distance_m": pa.float64()}
    schema = pa.schema([(c, types.get(c, pa.int32())) for c in LABEL_COLUMNS])
    table = pa.table({c: [r[c] for r in rows] for c in LABEL_COLUMNS}, schema=schema)
    labels_path = out / "labels.parquet"
    pq.write_table(table, labels_path)
    write_drive(out, recording.map_path, image_camera(recording, size), poses,
                recording.meta.get("observer_roles", {}))
    write_recording_truth(recording, out / "truth.csv", sorted({p.t for p in poses}))
    route = recording.path / "target_route.csv"
    if route.is_file():  # the target's true route, as carla-record writes it
        import shutil

        shutil.copyfile(route, out / "target_route.csv")
    preview_dir = None
    if preview:
        preview_dir = out / "preview"
        preview_dir.mkdir(parents=True, exist_ok=True)
        sheet.render().save(preview_dir / "contact_sheet.jpg", format="JPEG", quality=90)
        from dashtraj.datasets.look_sheet import look_sheet

        look_sheet(recording, preview_dir / "look_sheet.png", every_s, size, observers,
                   reference_dir=compare_dir)
    return ExportSummary(out, sum(per_obs.values()), len(rows),
                         sum(1 for r in rows if r["vis_x1"] > r["vis_x0"]), per_obs,
                         labels_path, preview_dir)
