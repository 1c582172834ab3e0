"""A vehicle re-identification set after the paper's CARLA ReID dataset (§II.B).

Every identity (model × colour, ``catalog.identities(n_ids)``, canonical order) is
placed alone at the same spot of a built-in town — the middle of the longest straight
road piece (a ``line`` geometry of a non-junction road), in its lane −1, heading along
the road — and photographed by a fixed ring of ``n_cameras`` cameras ("85 fixed
locations ... at various distances around the vehicle"). Camera i (1-based) is drawn
from ``numpy.random.default_rng([seed, i])``: azimuth around the vehicle (degrees from
its heading, stratified: (i − 1 + u) · 360 / n), ground distance 4–15 m and height
1.2–3.5 m, uniform; the ground distance is shortened so the camera stays within
``max_lateral_m`` of the vehicle sideways (on the road and sidewalks, outside the
buildings). Every camera looks at the vehicle's box centre. As the paper's fixed
CARLA cameras, every ring camera has the same lens and sensor: ``fov_deg`` (90°) over
an ``image_size`` (800 × 600, CARLA's default RGB camera) image, so a far vehicle
covers fewer pixels and its crop is upscaled (softer), as in the paper. With
``fov_deg=None`` the older zoom ring is used instead: a square ``size`` image whose FOV
is the narrowest of ``FOV_BINS_DEG`` that holds the vehicle's bounding sphere with a
10 % border, so every crop has about the output resolution.
A fixed-lens camera renders only the centred window of its image around the vehicle
(same focal length and pixel grid, so the same pixels; tested with camera effects off).
Camera effects of the look (vignetting, noise, blur, exposure; ``dashtraj.render.look``)
are drawn over the rendered window, so vignetting is centred on the window rather than
on the full 800 × 600 frame (measured: mean |Δ| 0.4 levels without effects, 20 with the
default look's effects).

Crops: the vehicle's visible box (``VehicleLabel.visible_box``) grown by ``margin`` on
each side, resized (bicubic) so the long side is ``size`` pixels, JPEG quality 95.
A camera that sees fewer than ``MIN_VISIBLE_PIXELS`` of the vehicle writes nothing.

Layout (VeRi-776)::

    out/image_train/  out/image_query/  out/image_test/   [out/image_query_moving/]
    out/name_train.txt  out/name_query.txt  out/name_test.txt  [out/name_query_moving.txt]
    [out/labels_query_moving.csv]   (each moving crop's truncation, visibility, box)
    out/reid.json   (config, id map, cameras, counts)

File names ``<id:04d>_c<cam:03d>_<frame:08d>_<n>.jpg``:

- id = identity_id + 1 (1-based, VeRi style; ``reid.json`` lists the map with each
  identity's key, e.g. ``vehicle.audi.a2/red``, and class);
- ring cameras: cam = 1 … n_cameras, frame = 0, n = 0;
- moving observers (``image_query_moving``): cam = n_cameras + 1 + k for the k-th
  (recording, observer) pair in input order, frame = the recording's state step
  index, n = recording index.

Split (paper: 700 ids, 650 train, 50 test, 424 query, 3,823 gallery): the first
``n_ids − n_test_ids`` ids train, the last ``n_test_ids`` test. Of each test id's
images, ``round(q · n + u)`` (u uniform from ``default_rng([seed, 1, id])``, q =
424 / 4247 so 8–9 of 85) from distinct cameras go to query, at least one and never all;
the rest are the gallery (``image_test``). The name files list the files of their
folder, sorted. Output bytes do not depend on the number of worker processes.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from dashtraj.datasets.frames import (
    JPEG_QUALITY,
    DatasetError,
    crop_vehicle,
    recording_frames,
)

FOV_BINS_DEG = (10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 75.0, 90.0, 110.0)
"""Horizontal (= vertical, square images) fields of view of the ring cameras, degrees."""
WINDOW_BINS_PX = (96, 128, 160, 192, 224, 256, 320, 384, 448, 512, 640)
"""Widths of the centred windows rendered of a fixed-FOV ring camera's image, pixels (even)."""
QUERY_FRACTION = 424 / (424 + 3823)
"""The paper's query share of the test images (424 query, 3,823 gallery)."""
MIN_VISIBLE_PIXELS = 16
NAME_PATTERN = r"^\d{4}_c\d{3}_\d{8}_\d+\.jpg$"
SPLITS = ("train", "query", "test")


@dataclass(frozen=True)
class RingCamera:
    """A fixed camera around the vehicle, in the vehicle's frame.

    index: 1-based camera id (``c<index:03d>``). azimuth_deg: direction from the vehicle
    to the camera, degrees from the vehicle's heading (positive toward its right, CARLA
    yaw sense). distance_m: ground distance to the vehicle centre. height_m: camera
    height above the road, metres.
    """

    index: int
    azimuth_deg: float
    distance_m: float
    height_m: float


@dataclass(frozen=True)
class ReidConfig:
    """Settings of a ReID set; written to ``reid.json``.

    Attributes:
        n_ids: identities (the first n of ``catalog.identities()``).
        n_cameras: ring cameras. size: crop long side, pixels. seed: camera/split seed.
        n_test_ids: test identities (the last ones); None = round(n_ids · 50 / 700),
            at least 1.
        town: built-in town of the stage. margin: crop margin, fraction of the box.
        distance_range_m, height_range_m: ring camera ground distance and height, m.
        max_lateral_m: largest sideways offset of a ring camera from the vehicle, m.
        every_s, min_visible_fraction, min_box_height_px: frames sampled from
            recordings and the crops kept for ``image_query_moving``.
        fov_deg: horizontal FOV of every ring camera, degrees (fixed lens, as the
            paper's cameras); None = a zoom lens fitted per camera (``FOV_BINS_DEG``).
        image_size: (width, height) of a fixed-FOV ring camera's image, pixels.
        randomize: domain randomization of the ring images (``ring_look``): weather,
            sun, scene colours and textures, and camera effects; the drawn looks go to
            ``looks.parquet`` (one row per ring image). Vehicle colours are never
            changed (they are the identity).
        randomize_seed: seed of those draws.
        randomize_per: ``"image"`` (default): every ring image draws its own scene, so
            no look is tied to an identity; ``"identity"``: one scene per identity shared
            by its cameras (camera effects still per camera). With ``"identity"`` every
            image of an identity shares its weather and light, a cue a model can match
            on instead of the vehicle (query and gallery of a test id share it too).
        test_only: render only the test identities (query and gallery), an evaluation
            set; ``image_train`` stays empty.
    """

    n_ids: int = 700
    n_cameras: int = 85
    size: int = 256
    seed: int = 0
    n_test_ids: int | None = None
    town: str = "town10"
    margin: float = 0.1
    distance_range_m: tuple[float, float] = (4.0, 15.0)
    height_range_m: tuple[float, float] = (1.2, 3.5)
    max_lateral_m: float = 9.5
    every_s: float = 0.5
    min_visible_fraction: float = 0.6
    min_box_height_px: float = 40.0
    msaa: int = 4
    recordings: tuple[str, ...] = field(default_factory=tuple)
    fov_deg: float | None = 90.0
    image_size: tuple[int, int] = (800, 600)
    randomize: bool = False
    randomize_seed: int = 0
    randomize_per: str = "image"
    test_only: bool = False

    @property
    def test_ids(self) -> int:
        n = self.n_test_ids if self.n_test_ids is not None else max(1, round(self.n_ids * 50 / 700))
        return int(n)


def ring_cameras(config: ReidConfig) -> list[RingCamera]:
    """The ring's cameras, deterministic per index (see the module docstring)."""
    out = []
    d0, d1 = config.distance_range_m
    h0, h1 = config.height_range_m
    for i in range(1, config.n_cameras + 1):
        rng = np.random.default_rng([config.seed, i])
        az = (i - 1 + rng.uniform()) * 360.0 / config.n_cameras
        d = rng.uniform(d0, d1)
        h = rng.uniform(h0, h1)
        s = abs(math.sin(math.radians(az)))
        if d * s > config.max_lateral_m:
            d = config.max_lateral_m / s
        out.append(RingCamera(i, round(az, 6), round(d, 6), round(h, 6)))
    return out


def stage_pose(road_map) -> tuple[float, float, float, float]:
    """(x, y, z, yaw_deg), CARLA world: middle of the longest straight road piece, lane −1.

    Raises DatasetError when the map has no straight non-junction road with lane −1.
    """
    best = None
    for rid in sorted(road_map.roads):
        road = road_map.roads[rid]
        if road.junction >= 0:
            continue
        for g in road.plan_view.geometries:
            if g.kind == "line" and (best is None or g.length > best[0] + 1e-9):
                best = (g.length, rid, g.s)
    wp = None
    if best is not None:
        wp = road_map.get_waypoint_xodr(best[1], -1, best[2] + best[0] / 2)
    if wp is None:
        raise DatasetError(f"map {road_map.name!r}: no straight road with a lane -1 for the "
                           "ReID stage")
    tr = wp.transform
    return (float(tr.location.x), float(tr.location.y), float(tr.location.z),
            float(tr.rotation.yaw))


def split_of(vid: int, config: ReidConfig) -> str:
    """"train" or "test" for a 1-based ReID id."""
    return "test" if vid > config.n_ids - config.test_ids else "train"


def query_cameras(vid: int, cams: list[int], seed: int) -> set[int]:
    """The cameras of test id ``vid`` whose images go to query (distinct, ≥ 1, < all),
    drawn with ``seed`` (the set's)."""
    if len(cams) < 2:
        return set()
    rng = np.random.default_rng([seed, 1, vid])
    n = math.floor(QUERY_FRACTION * len(cams) + rng.uniform())
    n = min(max(n, 1), len(cams) - 1)
    return {int(c) for c in rng.choice(sorted(cams), size=n, replace=False)}


RANDOMIZE_PER = ("image", "identity")


def ring_look(config: ReidConfig, identity_id: int, cam_index: int):
    """The randomized look of one ring image: weather, sun, materials and the noise/rain
    seed from ``default_rng([randomize_seed, identity_id, cam_index, 1])`` (per image,
    the default) or ``default_rng([randomize_seed, identity_id])`` (``randomize_per=
    "identity"``: shared by all cameras of the identity, as one moment in one place);
    the camera effects from ``default_rng([randomize_seed, identity_id, cam_index])``."""
    from dashtraj.render.randomize import CAMERA_PATHS, frame_rng, random_look

    if config.randomize_per == "identity":
        scene = random_look(frame_rng(config.randomize_seed, identity_id))
    else:
        scene = random_look(frame_rng(config.randomize_seed, identity_id, cam_index, 1))
    return random_look(frame_rng(config.randomize_seed, identity_id, cam_index), base=scene,
                       paths=CAMERA_PATHS)


def _write_ring_looks(out: Path, names: dict, config: ReidConfig) -> dict:
    """``looks.parquet``: one row per ring image (split, image, id, camera, the look's
    ``LookConfig.flat`` columns); returns the ``reid.json`` entry describing it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from dashtraj.render.randomize import describe

    rows = []
    for split in SPLITS:
        for name in sorted(names[split]):
            vid, cam = int(name[:4]), int(name[6:9])
            rows.append({"image": f"image_{split}/{name}", "id": vid, "camera": cam,
                         **ring_look(config, vid - 1, cam).flat()})
    cols = list(rows[0]) if rows else ["image"]
    pq.write_table(pa.table({c: [r[c] for r in rows] for c in cols}), out / "looks.parquet")
    per = ("identity (scene) and camera (effects)" if config.randomize_per == "identity"
           else "image")
    return {"seed": int(config.randomize_seed), "per": per,
            "looks": "looks.parquet", "ranges": describe()}


def veri_name(vid: int, cam: int, frame: int, n: int) -> str:
    """``<id:04d>_c<cam:03d>_<frame:08d>_<n>.jpg``; raises DatasetError when a field overflows."""
    if not (0 < vid <= 9999 and 0 < cam <= 999 and 0 <= frame <= 99_999_999 and n >= 0):
        raise DatasetError(f"VeRi name fields out of range: id {vid}, camera {cam}, "
                           f"frame {frame}, n {n}")
    return f"{vid:04d}_c{cam:03d}_{frame:08d}_{n}.jpg"


class _Stage:
    """Renderers (one per FOV bin, sharing one GL context) of the town with the stage."""

    def __init__(self, config: ReidConfig, map_path: str, out_dir: str):
        from dashtraj.roads import RoadMap

        self.config = config
        self.out = Path(out_dir)
        self.road_map = RoadMap.from_file(map_path)
        self.pose = stage_pose(self.road_map)
        self.cameras = ring_cameras(config)
        self._renderers: dict[tuple, object] = {}
        self._ctx = None

    def renderer(self, view: tuple[int, int, float]):
        """The renderer of a (width px, height px, horizontal FOV deg) view (one per view)."""
        from dashtraj.render.gl import create_context
        from dashtraj.render.scene import Renderer

        r = self._renderers.get(view)
        if r is None:
            if self._ctx is None:
                self._ctx = create_context(threads=0)
            w, h, fov = view
            r = Renderer(self.road_map, w, h, fov, msaa=self.config.msaa, ctx=self._ctx)
            self._renderers[view] = r
        return r

    def release(self) -> None:
        """Free the renderers and the GL context."""
        for r in self._renderers.values():
            r.release()
        self._renderers.clear()
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None

    def camera_pose(self, cam: RingCamera, model) -> tuple[tuple, tuple[int, int, float]]:
        """Camera pose (x, y, z, yaw, pitch, roll) looking at the vehicle, and its view.

        The view is (width px, height px, horizontal FOV deg) of the image rendered.
        Fixed lens (``config.fov_deg``): the centred window of the camera's full
        ``image_size`` image that holds the vehicle's bounding sphere with a 10 % border,
        its width the smallest of ``WINDOW_BINS_PX`` (or the full image): the same focal
        length and pixel grid as the full image, so the same pixels around the vehicle,
        at a fraction of the rendering cost. Zoom lens (None): a ``size`` square image,
        FOV the narrowest of ``FOV_BINS_DEG`` holding the sphere with the border.
        """
        x, y, z, yaw = self.pose
        a = math.radians(yaw + cam.azimuth_deg)
        cx, cy = x + cam.distance_m * math.cos(a), y + cam.distance_m * math.sin(a)
        tz = z + model.height_m / 2
        cz = z + cam.height_m
        cyaw = math.degrees(math.atan2(y - cy, x - cx))
        pitch = -math.degrees(math.atan2(cz - tz, cam.distance_m))
        pose = (cx, cy, cz, cyaw, pitch, 0.0)
        r = 0.5 * math.sqrt(model.length_m ** 2 + model.width_m ** 2 + model.height_m ** 2)
        d3 = math.hypot(cam.distance_m, cz - tz)
        need = 2.0 * math.degrees(math.asin(min(1.0, r / d3))) / 0.9
        if self.config.fov_deg is not None:
            big_w, big_h = self.config.image_size
            f = big_w / (2.0 * math.tan(math.radians(self.config.fov_deg) / 2))
            want = 2.0 * f * math.tan(math.radians(min(need, 179.0)) / 2)
            w = next((b for b in WINDOW_BINS_PX if want <= b < big_w), big_w)
            h = min(w, big_h)
            if w == big_w:
                return pose, (big_w, big_h, float(self.config.fov_deg))
            return pose, (w, h, 2.0 * math.degrees(math.atan(w / (2.0 * f))))
        fov = next((f for f in FOV_BINS_DEG if f >= need), FOV_BINS_DEG[-1])
        return pose, (self.config.size, self.config.size, fov)

    def identity_images(self, identity) -> dict[str, list[str]]:
        """Render, crop and write one identity's images; returns names per split."""
        vid = identity.identity_id + 1
        x, y, z, yaw = self.pose
        crops = {}
        for cam in self.cameras:
            pose, view = self.camera_pose(cam, identity.model)
            if self.config.randomize:
                self.renderer(view).set_look(ring_look(self.config, identity.identity_id,
                                                       cam.index))
            frame = self.renderer(view).render(pose, [(1, identity, x, y, z, yaw)])
            lab = frame.labels[0]
            if lab.visible_box is None or lab.visible_pixels < MIN_VISIBLE_PIXELS:
                continue
            crops[cam.index] = crop_vehicle(frame.rgb, lab.visible_box, self.config.margin,
                                            self.config.size)
        if split_of(vid, self.config) == "train":
            dest = dict.fromkeys(crops, "train")
        else:
            q = query_cameras(vid, list(crops), self.config.seed)
            dest = {c: ("query" if c in q else "test") for c in crops}
        names: dict[str, list[str]] = {s: [] for s in SPLITS}
        for c in sorted(crops):
            name = veri_name(vid, c, 0, 0)
            crops[c].save(self.out / f"image_{dest[c]}" / name, format="JPEG",
                          quality=JPEG_QUALITY)
            names[dest[c]].append(name)
        return names


_WORKER: _Stage | None = None  # set in each worker process by _init_worker only


def _init_worker(config: ReidConfig, map_path: str, out_dir: str) -> None:
    global _WORKER
    _WORKER = _Stage(config, map_path, out_dir)


def _work(identity_id: int) -> dict[str, list[str]]:
    from dashtraj.world import catalog

    return _WORKER.identity_images(catalog.identities()[identity_id])


def build_reid_dataset(config: ReidConfig, out_dir, workers: int = 1, recordings=(),
                       progress=None) -> dict:
    """Render the ReID set (layout and split in the module docstring).

    Args:
        config: a ``ReidConfig``.
        out_dir: output directory (created; same-named files are overwritten).
        workers: processes (each with its own GL context, started with ``spawn`` so no
            context exists before a worker starts); 1 renders in this process.
        recordings: opened ``Recording`` objects whose observers' crops of the test
            identities make ``image_query_moving`` (none: the folder is not written).
        progress: called with no argument after each identity, or None.

    Returns:
        the ``reid.json`` dict (config, id map, cameras, stage pose, counts).

    Raises:
        DatasetError: bad counts (ids beyond the catalog, no train id, ...).
        RenderUnavailableError: no GL context.
    """
    from dashtraj.world import catalog
    from dashtraj.world.towns import town_path

    n_all = len(catalog.identities())
    if not 1 <= config.n_ids <= min(n_all, 9999):
        raise DatasetError(f"--ids {config.n_ids}: the catalog has {n_all} identities")
    if not 1 <= config.test_ids < config.n_ids:
        raise DatasetError(f"{config.test_ids} test ids of {config.n_ids}: need at least one "
                           "train and one test id")
    if not 1 <= config.n_cameras <= 999:
        raise DatasetError(f"--cameras {config.n_cameras}: 1 to 999 (c001 … c999)")
    if config.randomize_per not in RANDOMIZE_PER:
        raise DatasetError(f"--randomize-per {config.randomize_per!r}: one of "
                           f"{', '.join(RANDOMIZE_PER)}")
    out = Path(out_dir)
    for s in (*SPLITS, "query_moving"):
        d = out / f"image_{s}"
        if d.is_dir():  # stale images of an earlier run would not be in the name files
            for old in sorted(d.glob("*.jpg")):
                old.unlink()
        elif s != "query_moving":
            d.mkdir(parents=True)
    map_path = str(town_path(config.town))
    names: dict[str, list[str]] = {s: [] for s in SPLITS}
    ids = [i for i in range(config.n_ids)
           if not config.test_only or split_of(i + 1, config) == "test"]
    if workers <= 1:
        stage = _Stage(config, map_path, str(out))
        try:
            for iid in ids:
                for s, ns in stage.identity_images(catalog.identities()[iid]).items():
                    names[s].extend(ns)
                if progress is not None:
                    progress()
            pose = stage.pose
        finally:
            stage.release()
    else:
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_init_worker,
                      initargs=(config, map_path, str(out))) as pool:
            for res in pool.imap(_work, ids, chunksize=1):
                for s, ns in res.items():
                    names[s].extend(ns)
                if progress is not None:
                    progress()
        from dashtraj.roads import RoadMap

        pose = stage_pose(RoadMap.from_file(map_path))
    counts = {}
    for s in SPLITS:
        (out / f"name_{s}.txt").write_text("".join(f"{n}\n" for n in sorted(names[s])),
                                           encoding="utf-8")
        counts[s] = {"images": len(names[s]), "ids": len({n[:4] for n in names[s]})}
    moving = None
    if recordings:
        moving = moving_queries(recordings, out, config)
        counts["query_moving"] = moving["counts"]
    pool_ids = catalog.identities(config.n_ids)
    info = {
        "format": "veri-776",
        "config": {**asdict(config), "distance_range_m": list(config.distance_range_m),
                   "height_range_m": list(config.height_range_m),
                   "image_size": list(config.image_size),
                   "recordings": [str(r.path) for r in recordings]},
        "test_ids": config.test_ids,
        "stage": {"town": config.town, "x": pose[0], "y": pose[1], "z": pose[2],
                  "yaw_deg": pose[3]},
        "cameras": [asdict(c) for c in ring_cameras(config)],
        "ids": [{"id": i.identity_id + 1, "identity_id": i.identity_id, "key": i.key,
                 "class": i.model.vehicle_class,
                 "split": split_of(i.identity_id + 1, config)} for i in pool_ids],
        "counts": counts,
    }
    if moving is not None:
        info["moving_cameras"] = moving["cameras"]
    if config.randomize:
        info["randomize"] = _write_ring_looks(out, names, config)
    (out / "reid.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n",
                                   encoding="utf-8")
    return info


def moving_queries(recordings, out_dir, config: ReidConfig) -> dict:
    """Crops of the test identities seen by the recordings' moving observers.

    Writes ``image_query_moving/``, ``name_query_moving.txt`` and
    ``labels_query_moving.csv`` (`MOVING_LABEL_FIELDS`): every sampled frame
    (``config.every_s``) where a vehicle whose catalog identity is a test id shows at
    least ``min_visible_fraction`` of itself and a visible box ≥ ``min_box_height_px``
    high. Vehicles of other identities (recordings draw identities from the whole
    catalog) are skipped and counted. Cameras are numbered from ``n_cameras + 1`` (after
    the ring's).

    Returns:
        {"counts": {"images", "ids", "skipped_not_test"}, "cameras": [{"cam",
        "recording", "observer_id"}]}.
    """
    return moving_crops(recordings, out_dir, config, "test")


MOVING_STEMS = {"test": "query_moving", "train": "train_moving"}
"""Split of `moving_crops` → the stem of its folder and list (``image_<stem>/``,
``name_<stem>.txt``) and of its key in ``reid.json``'s counts."""

MOVING_LABEL_FIELDS = ("name", "truncation", "visible_fraction", "box_w_px", "box_h_px")
"""Columns of a moving-crop set's ``labels_<stem>.csv`` (`moving_crops`): the crop's file
name, the renderer's exact labels of the vehicle in that frame (``truncation``: the share
of its projected silhouette outside the image; ``visible_fraction``: its visible pixels
over its silhouette's inside the image) and its visible box's width and height, pixels."""


def moving_labels_path(root: str | Path, stem: str) -> Path:
    """``labels_<stem>.csv`` of a VeRi-layout folder (``stem``: e.g. ``query_moving``)."""
    return Path(root) / f"labels_{stem}.csv"


def write_moving_labels(path: str | Path, rows) -> None:
    """Write `MOVING_LABEL_FIELDS` rows (tuples, any order) sorted by name."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(MOVING_LABEL_FIELDS)
        w.writerows(sorted(rows))


def read_moving_labels(path: str | Path) -> dict[str, tuple[float, ...]]:
    """{name: (truncation, visible_fraction, box_w_px, box_h_px)} of a labels file.

    Raises DatasetError: a header other than `MOVING_LABEL_FIELDS` or a bad row (named
    by its line)."""
    import csv

    p = Path(path)
    out: dict[str, tuple[float, ...]] = {}
    with open(p, newline="", encoding="utf-8") as f:
        rows = csv.reader(f)
        head = next(rows, None)
        if tuple(head or ()) != MOVING_LABEL_FIELDS:
            raise DatasetError(f"{p}: line 1: the header must be {','.join(MOVING_LABEL_FIELDS)}")
        for i, row in enumerate(rows, start=2):
            try:
                if len(row) != len(MOVING_LABEL_FIELDS):
                    raise ValueError(f"{len(row)} fields")
                vals = tuple(float(v) for v in row[1:])
                if not all(math.isfinite(v) for v in vals):
                    raise ValueError("not finite")
            except ValueError as exc:
                raise DatasetError(f"{p}: line {i}: bad row ({exc})") from None
            out[row[0]] = vals
    return out


MOVING_TRAIN_FIRST_CAM = 500
"""First camera number of ``image_train_moving`` (the ring's are 1 … n_cameras, the
moving queries' follow them): well apart from both, within VeRi's three digits."""


def moving_crops(recordings, out_dir, config: ReidConfig, split: str = "test", *,
                 first_cam: int | None = None, first_recording: int = 0,
                 workers: int = 1) -> dict:
    """Crops of one split's identities seen by the recordings' moving observers.

    ``split`` "test": ``image_query_moving/`` and ``name_query_moving.txt`` (see
    `moving_queries`); "train": ``image_train_moving/`` and ``name_train_moving.txt``;
    each with ``labels_<stem>.csv``, every crop's truncation, visible fraction and box,
    the training identities seen from dashcams (the view and the scenes of a run's
    crops), for ``dashtraj reid train --extra-train image_train_moving``; cameras are
    numbered from `MOVING_TRAIN_FIRST_CAM`. Crops of the other split's identities are
    skipped and counted (``skipped_not_test`` / ``skipped_not_train``).

    ``first_cam`` and ``first_recording`` continue a set made earlier (``dashtraj reid
    moving-train --append``): cameras are numbered from ``first_cam`` and the recordings
    indexed (the last field of a name) from ``first_recording``, so that adding
    recordings later names every crop as one run over all of them would.

    ``workers`` > 1 renders that many recordings at once, each in its own process (started
    with ``spawn``, each with its own GL context); the crops and names are the same bytes
    as with one.
    """
    from dashtraj.datasets.frames import observer_ids

    if split not in MOVING_STEMS:
        raise DatasetError(f"moving crops: split {split!r} is not 'test' or 'train'")
    stem = MOVING_STEMS[split]
    first = first_cam if first_cam is not None else (
        config.n_cameras + 1 if split == "test" else MOVING_TRAIN_FIRST_CAM)
    out = Path(out_dir) / f"image_{stem}"
    out.mkdir(parents=True, exist_ok=True)
    cams, cam_of = [], []  # cam_of[i]: recording i's observer id -> camera number
    for rec in recordings:
        cam_of.append({})
        for o in observer_ids(rec):
            cam_of[-1][o] = first + len(cams)
            cams.append({"cam": cam_of[-1][o], "recording": str(rec.path), "observer_id": o})
    if cams and cams[-1]["cam"] > 999:
        raise DatasetError(f"{len(cams)} moving observers from camera {first} "
                           "exceed the 999 camera ids of the VeRi names")
    parallel = workers > 1 and len(recordings) > 1
    jobs = [(str(rec.path) if parallel else rec, str(out), config, split, cam_of[ri],
             first_recording + ri) for ri, rec in enumerate(recordings)]
    names, labels, skipped = [], [], 0
    if parallel:  # a worker opens its recording from the path
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(min(workers, len(jobs))) as p:
            results = p.starmap(_moving_recording, jobs, chunksize=1)
    else:
        results = [_moving_recording(*job) for job in jobs]
    for ls, sk in results:
        labels.extend(ls)
        names.extend(row[0] for row in ls)
        skipped += sk
    names.sort()
    (Path(out_dir) / f"name_{stem}.txt").write_text("".join(f"{n}\n" for n in names),
                                                  encoding="utf-8")
    write_moving_labels(moving_labels_path(out_dir, stem), labels)
    return {"counts": {"images": len(names), "ids": len({n[:4] for n in names}),
                       f"skipped_not_{split}": skipped}, "cameras": cams}


def _moving_recording(rec, out: str, config: ReidConfig, split: str, cam_of: dict,
                      rec_index: int) -> tuple[list[tuple], int]:
    """`moving_crops` of one recording (an opened ``Recording`` or its path, in a worker):
    writes its crops into ``out`` and returns their `MOVING_LABEL_FIELDS` rows and the
    count of crops skipped as the other split's. ``cam_of``: observer id → camera number."""
    from dashtraj.world import catalog

    if isinstance(rec, str):
        from dashtraj.world.recording import Recording

        rec = Recording.open(rec)
    pool = catalog.identities()
    rows = {int(v["vehicle_id"]): v for v in rec.vehicles}
    labels, skipped = [], 0
    for rf in recording_frames(rec, config.every_s, msaa=config.msaa):
        for lab, vehicle_id, iid in zip(rf.frame_data.labels, rf.vehicle_ids,
                                        rf.identity_ids, strict=True):
            b = lab.visible_box
            if (b is None or lab.visible_fraction < config.min_visible_fraction
                    or b[3] - b[1] < config.min_box_height_px):
                continue
            row = rows[vehicle_id]
            same_look = (0 <= iid < len(pool) and pool[iid].model.blueprint_id
                         == row["blueprint_id"] and pool[iid].color_name == row["color"])
            vid = iid + 1
            if not same_look or iid >= config.n_ids or split_of(vid, config) != split:
                skipped += 1
                continue
            name = veri_name(vid, cam_of[rf.observer_id], rf.frame, rec_index)
            crop_vehicle(rf.frame_data.rgb, b, config.margin, config.size).save(
                Path(out) / name, format="JPEG", quality=JPEG_QUALITY)
            labels.append((name, round(float(lab.truncation), 4),
                           round(float(lab.visible_fraction), 4),
                           round(float(b[2] - b[0]), 1), round(float(b[3] - b[1]), 1)))
    return labels, skipped


@dataclass(frozen=True)
class DriveReidConfig:
    """A VeRi-layout set from drives with truth (`drive_reid_set`).

    Attributes:
        every_s: frames sampled, seconds. size: crop long side, pixels. margin: crop
        margin, fraction of the box. min_visible_fraction, min_box_height_px: the crops
        kept (a vehicle mostly in view and big enough to tell). test_fraction: share of
        the identities held out for query and gallery. seed: the split's and the query
        cameras' seed.
    """

    every_s: float = 0.5
    size: int = 256
    margin: float = 0.1
    min_visible_fraction: float = 0.6
    min_box_height_px: float = 40.0
    test_fraction: float = 0.5
    seed: int = 0


def drive_reid_set(drives, out_dir, config: DriveReidConfig = DriveReidConfig()) -> dict:
    """A VeRi-776-layout ReID set from drives with ground truth (CARLA's own frames from
    ``carla-record``): every vehicle of every drive is an identity (ids 1… in the order
    (drive, vehicle id)), every drive's observer a camera (1…), every crop of a truth box
    kept by the config's filters an image ``<id>_c<cam>_<frame>_<drive index>.jpg``.
    ``test_fraction`` of the identities (drawn with ``seed``) go to ``image_query`` and
    ``image_test`` — of each test id seen by two cameras or more, the crops of about a
    tenth of its cameras (at least one, never all: `QUERY_FRACTION`) are queries, the rest
    gallery; one seen by one camera is gallery only — the others to ``image_train``.
    Writes the folders, ``name_*.txt`` and ``reid.json`` (config, counts, cameras,
    identities). Raises DatasetError for a drive without truth."""
    from dashtraj.datasets.frames import observer_ids

    drives = list(drives)
    for d in drives:
        if getattr(d, "truth", None) is None:
            raise DatasetError(f"{d.path} is a drive without truth.csv: no identities for a "
                               "ReID set")
    out = Path(out_dir)
    cams, cam_of = [], {}
    for di, d in enumerate(drives):
        for o in observer_ids(d):
            cam_of[(di, o)] = len(cams) + 1
            cams.append({"cam": len(cams) + 1, "drive": str(d.path), "observer_id": o})
    if len(cams) > 999:
        raise DatasetError(f"{len(cams)} observers exceed the 999 camera ids of the VeRi names")
    crops: dict[tuple[int, int], dict[int, list]] = {}  # (drive, vehicle) -> cam -> crops
    for di, d in enumerate(drives):
        for o in observer_ids(d):
            for rf in d.frames(o, config.every_s):
                for lab, vehicle_id in zip(rf.frame_data.labels, rf.vehicle_ids, strict=True):
                    b = lab.visible_box
                    if (b is None or lab.visible_fraction < config.min_visible_fraction
                            or b[3] - b[1] < config.min_box_height_px):
                        continue
                    buf = io.BytesIO()  # kept as JPEG bytes: the split needs every crop
                    crop_vehicle(rf.frame_data.rgb, b, config.margin, config.size).save(
                        buf, format="JPEG", quality=JPEG_QUALITY)
                    crops.setdefault((di, int(vehicle_id)), {}).setdefault(
                        cam_of[(di, o)], []).append((rf.frame, buf.getvalue()))
    keys = sorted(crops)
    if len(keys) > 9999:
        raise DatasetError(f"{len(keys)} identities exceed the 9999 ids of the VeRi names")
    rng = np.random.default_rng(config.seed)
    n_test = round(len(keys) * config.test_fraction)
    if config.test_fraction > 0 and len(keys) >= 2:
        n_test = min(max(n_test, 1), len(keys) - 1)
    test = set(rng.permutation(len(keys))[:n_test].tolist()) if len(keys) >= 2 else set()
    names: dict[str, list[str]] = {s: [] for s in SPLITS}
    for s in SPLITS:
        (out / f"image_{s}").mkdir(parents=True, exist_ok=True)
    identities = []
    for i, key in enumerate(keys):
        vid = i + 1
        by_cam = crops[key]
        q = query_cameras(vid, list(by_cam), config.seed) if i in test else set()
        for cam, items in by_cam.items():
            split = "train" if i not in test else ("query" if cam in q else "test")
            for frame, jpeg in items:
                name = veri_name(vid, cam, frame, key[0])
                (out / f"image_{split}" / name).write_bytes(jpeg)
                names[split].append(name)
        identities.append({"id": vid, "drive": str(drives[key[0]].path), "vehicle_id": key[1],
                           "split": "test" if i in test else "train",
                           "cameras": sorted(by_cam)})
    for s in SPLITS:
        (out / f"name_{s}.txt").write_text("".join(f"{n}\n" for n in sorted(names[s])),
                                           encoding="utf-8")
    counts = {s: {"images": len(names[s]), "ids": len({n[:4] for n in names[s]})}
              for s in SPLITS}
    info = {"format": "veri776", "source": "drives", "config": asdict(config),
            "drives": [str(d.path) for d in drives], "counts": counts, "cameras": cams,
            "identities": identities}
    (out / "reid.json").write_text(json.dumps(info, indent=1, sort_keys=True) + "\n",
                                   encoding="utf-8")
    return info
