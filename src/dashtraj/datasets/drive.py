"""A recorded drive: the frames and camera poses of dashcams that really drove (a CARLA
client's sensors, a research vehicle, a fleet), for ``dashtraj perceive``.

A drive is a folder::

    drive.json              {"format": "dashtraj-drive", "format_version": 1,
                             "map": "map.xodr",          # a file in the folder, a path,
                                                         # or a built-in town name
                             "camera": {"width_px": 1280, "height_px": 720, "fov_deg": 90,
                                        "x_m": 1.0, "y_m": 0.0, "z_m": 1.6,
                                        "pitch_deg": 0.0},
                             "observer_roles": {"3": "oncoming"}}   # optional
    poses.csv               observer_id,frame,t,cam_x,cam_y,cam_z,cam_yaw,cam_pitch
    <observer_id>/<frame:06d>.jpg   (or .png): one image per row of poses.csv
    truth.csv                       optional: every vehicle's 3-D box over time
    <observer_id>/<frame:06d>.depth.png   optional, with truth.csv: the frame's depth

``camera`` is the dashcam (`dashtraj.world.camera.CameraSpec`): the image size and
horizontal FOV give the intrinsics (CARLA's ideal camera: f = W / (2 tan(FOV/2)),
principal point at the centre; undistort real images first), ``z_m`` is its height
above the road (the road elevation under the observer is cam_z − z_m) and ``x_m``,
``y_m`` where it sits on the vehicle (forward, right of the vehicle's ground point),
which `perceive` uses for the observer's own position. ``poses.csv`` gives the camera
of every frame in CARLA world coordinates (metres; yaw and pitch in degrees, yaw
positive turning +x toward +y, pitch positive looking up): what ``sensor.get_transform()``
returns in CARLA, or GPS/IMU and the mount on a real vehicle, in the map's frame. t is
seconds; frame is any integer that orders an observer's frames and names its image.

This is the layout ``dashtraj render RUN -o DIR`` writes beside its labels (the
images are ``DIR/<observer>/<frame>.jpg``), so a simulated recording can be perceived
from its images like a real drive. A drive without ground truth gives a database whose
truth columns are empty, and the ``oracle`` detector cannot run on it. An optional
``truth.csv`` (`dashtraj.datasets.drive_truth`: every vehicle's 3-D box over time, which
``render`` and ``carla-record`` write) gives its frames truth boxes, so the truth
columns are filled and ``--detector oracle`` runs; a frame's depth image (CARLA's depth
camera encoding; ``render --depth``, ``carla-record``) makes them hug the vehicles'
pixels and lets scenery hide a vehicle.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dashtraj.datasets.frames import DatasetError, RecordingFrame

DRIVE_FORMAT = "dashtraj-drive"
DRIVE_VERSION = 1
POSE_COLUMNS = ("observer_id", "frame", "t", "cam_x", "cam_y", "cam_z", "cam_yaw", "cam_pitch")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")


class DriveError(DatasetError):
    """A drive folder is missing, malformed or inconsistent (the message names the file,
    line or element)."""


def is_drive(path) -> bool:
    """Whether a folder is a drive (has ``drive.json``)."""
    return (Path(path) / "drive.json").is_file()


def open_with_truth(path, why: str, error: type[Exception] = DriveError):
    """A simulated recording (`Recording.open`), or a drive with a ``truth.csv``
    (`Drive.open`); ``error(f"{path} is a drive without truth.csv: {why}")`` for a drive
    without one: what evaluations and training sets read."""
    from dashtraj.world.recording import Recording

    if is_drive(path) and not (Path(path) / "meta.json").is_file():
        drive = Drive.open(path)
        if drive.truth is None:
            raise error(f"{path} is a drive without truth.csv: {why} (see "
                        "dashtraj.datasets.drive_truth)")
        return drive
    return Recording.open(path)


@dataclass(frozen=True)
class DrivePose:
    """One frame of one observer: its camera in CARLA world coordinates."""

    observer_id: int
    frame: int
    t: float
    cam_x: float
    cam_y: float
    cam_z: float
    cam_yaw: float
    cam_pitch: float


@dataclass(frozen=True)
class _DriveConfig:
    camera: object


@dataclass(frozen=True)
class DriveImage:
    """The parts of a rendered ``Frame`` a drive has: the image and its camera pose
    (x, y, z, yaw, pitch, roll); the instance image and labels of its truth boxes when
    the drive has a ``truth.csv`` (`dashtraj.datasets.drive_truth.truth_frame`), else
    None and none; never a depth image."""

    rgb: np.ndarray
    camera_pose: tuple
    instance: np.ndarray | None = None
    depth: None = None
    labels: tuple = ()


class Drive:
    """A drive folder, checked when opened (`Drive.open`). Duck-types the parts of a
    `dashtraj.world.recording.Recording` that ``perceive`` reads: ``path``, ``meta``
    (map source and sha256, observer roles), ``config.camera``, ``map_path`` and
    ``vehicles`` (the observers)."""

    def __init__(self, path: Path, meta: dict, camera, map_path: Path,
                 poses: dict[int, list[DrivePose]], truth=None):
        self.path = path
        self.meta = meta
        self.config = _DriveConfig(camera)
        self.map_path = map_path
        self.poses = poses
        self.truth = truth  # a `DriveTruth`, or None

    @property
    def vehicles(self) -> list[dict]:
        return [{"vehicle_id": o, "role": "observer"} for o in sorted(self.poses)]

    @property
    def observer_ids(self) -> list[int]:
        return sorted(self.poses)

    @classmethod
    def open(cls, path: str | Path) -> Drive:
        """Read and check ``drive.json``, ``poses.csv``, ``truth.csv`` when there is one,
        and that every image exists.

        Raises DriveError naming the file, line or field."""
        from dashtraj.errors import read_utf8
        from dashtraj.world.camera import CameraSpec
        from dashtraj.world.recording import check_camera, resolve_map

        root = Path(path)
        mf = root / "drive.json"
        if not mf.is_file():
            raise DriveError(f"{root} is not a drive: no drive.json (see dashtraj.datasets."
                             "drive for the layout)")
        try:
            meta = json.loads(read_utf8(mf, DriveError))
        except json.JSONDecodeError as exc:
            raise DriveError(f"{mf}: not JSON ({exc.msg}, line {exc.lineno})") from None
        if not isinstance(meta, dict) or meta.get("format") != DRIVE_FORMAT:
            raise DriveError(f"{mf}: not a dashtraj drive (format must be {DRIVE_FORMAT!r})")
        version = meta.get("format_version")
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise DriveError(f"{mf}: format_version must be an integer >= 1, got {version!r}")
        if version > DRIVE_VERSION:
            raise DriveError(f"{mf}: format_version {version} is newer than this dashtraj "
                             f"reads ({DRIVE_VERSION}); upgrade dashtraj")
        cam = meta.get("camera")
        fields = set(CameraSpec.__dataclass_fields__)
        if not isinstance(cam, dict) or not set(cam) <= fields:
            bad = sorted(set(cam) - fields) if isinstance(cam, dict) else cam
            raise DriveError(f"{mf}: camera must be an object with fields among "
                             f"{', '.join(sorted(fields))} (got {bad!r})")
        camera = CameraSpec.from_dict(cam)
        check_camera(camera, str(mf), DriveError)
        source = meta.get("map")
        if not isinstance(source, str) or not source:
            raise DriveError(f"{mf}: map must name an .xodr file or a built-in town")
        local = root / source
        try:
            map_path = local if local.is_file() else resolve_map(source)
        except Exception as exc:
            raise DriveError(f"{mf}: map {source!r}: {exc}") from None
        roles = meta.get("observer_roles", {})
        if not isinstance(roles, dict):
            raise DriveError(f"{mf}: observer_roles must be an object")
        poses = _read_poses(root / "poses.csv")
        for o, rows in poses.items():
            for r in rows:
                _check_image(root, o, r.frame, camera)
        import hashlib

        truth = None
        if (root / "truth.csv").is_file():
            from dashtraj.datasets.drive_truth import read_truth

            truth = read_truth(root / "truth.csv")
        meta = {**meta, "map": {"source": str(source),
                                "sha256": hashlib.sha256(map_path.read_bytes()).hexdigest()},
                "observer_roles": {str(k): v for k, v in roles.items()}}
        return cls(root, meta, camera, map_path, poses, truth)

    def frame_poses(self, observer_id: int, every_s: float | None = None) -> list[DrivePose]:
        """The observer's frames in time order; with ``every_s``, the first frame of each
        ``every_s`` interval (floor(t / every_s)): every frame of a drive recorded at that
        period or slower, one per period of a faster one, whatever its timestamps."""
        rows = self.poses[observer_id]
        if every_s is None:
            return list(rows)
        out, last = [], None
        for r in rows:
            b = math.floor(r.t / every_s + 1e-6)
            if b != last:
                out.append(r)
                last = b
        return out

    def frame_count(self, every_s: float | None = None, observers=None) -> int:
        """How many frames `frames` gives for ``observers`` (None: all; ids the drive
        lacks count none)."""
        obs = self.observer_ids if observers is None else observers
        return sum(len(self.frame_poses(o, every_s)) for o in obs if o in self.poses)

    def frames(self, observer_id: int, every_s: float | None = None):
        """`RecordingFrame`s of the observer's images (read from disk, RGB uint8), in
        time order, with the truth's labels when the drive has them. Raises DriveError
        for an image that does not decode or has another size than the camera's."""
        for r in self.frame_poses(observer_id, every_s):
            rgb = _open_image(_image(self.path, observer_id, r.frame), self.config.camera,
                              decode=True)
            pose = (r.cam_x, r.cam_y, r.cam_z, r.cam_yaw, r.cam_pitch, 0.0)
            if self.truth is None:
                yield RecordingFrame(observer_id, r.t, r.frame, DriveImage(rgb, pose), (), ())
                continue
            from dashtraj.datasets.drive_truth import truth_frame

            dp = self.path / str(observer_id) / f"{r.frame:06d}.depth.png"
            depth = None
            if dp.is_file():
                from dashtraj.datasets.drive_truth import decode_depth

                depth = decode_depth(_open_image(dp, self.config.camera, decode=True))
            inst, labels, vids = truth_frame(self.config.camera, pose, self.truth.at(r.t),
                                             exclude=observer_id, depth=depth)
            yield RecordingFrame(observer_id, r.t, r.frame,
                                 DriveImage(rgb, pose, inst, None, tuple(labels)), vids,
                                 (-1,) * len(vids))


def _check_image(root: Path, observer_id: int, frame: int, spec) -> None:
    """The frame's image exists, opens and has the camera's size (its header only)."""
    p = _image(root, observer_id, frame)
    if p is None:
        raise DriveError(f"{root / 'poses.csv'}: observer {observer_id} frame {frame} has no "
                         f"image {observer_id}/{frame:06d}.jpg (or .png)")
    _open_image(p, spec, decode=False)


def _open_image(p: Path, spec, decode: bool) -> np.ndarray | None:
    """Open an image, check it has the camera's size, and with ``decode`` return its
    (H, W, 3) uint8 RGB pixels (else read the header only). Raises DriveError."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(p) as im:
            size = im.size
            rgb = np.asarray(im.convert("RGB")) if decode else None
    except (OSError, UnidentifiedImageError) as exc:
        raise DriveError(f"{p}: not an image ({exc})") from None
    if size != (spec.width_px, spec.height_px):
        raise DriveError(f"{p}: {size[0]}x{size[1]} pixels, the camera in drive.json is "
                         f"{spec.width_px}x{spec.height_px}")
    return rgb


def _image(root: Path, observer_id: int, frame: int) -> Path | None:
    for suffix in IMAGE_SUFFIXES:
        p = root / str(observer_id) / f"{frame:06d}{suffix}"
        if p.is_file():
            return p
    return None


def _read_poses(path: Path) -> dict[int, list[DrivePose]]:
    from dashtraj.errors import read_utf8

    if not path.is_file():
        raise DriveError(f"{path} does not exist (a drive needs its camera poses)")
    lines = read_utf8(path, DriveError).splitlines()
    reader = csv.DictReader(lines)
    missing = [c for c in POSE_COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise DriveError(f"{path}: missing column {missing[0]!r} (columns: "
                         f"{', '.join(POSE_COLUMNS)})")
    out: dict[int, list[DrivePose]] = {}
    seen: set[tuple[int, int]] = set()
    for n, row in enumerate(reader, start=2):
        try:
            o, f = int(row["observer_id"]), int(row["frame"])
            vals = [float(row[c]) for c in POSE_COLUMNS[2:]]
        except (TypeError, ValueError):
            raise DriveError(f"{path}, line {n}: observer_id and frame must be integers and "
                             "t, cam_* numbers") from None
        if o < 0 or f < 0 or not all(math.isfinite(v) for v in vals):
            raise DriveError(f"{path}, line {n}: ids must be >= 0 and numbers finite")
        if not -89.0 <= vals[5] <= 89.0:
            raise DriveError(f"{path}, line {n}: cam_pitch {vals[5]:g} is not within ±89°")
        if (o, f) in seen:
            raise DriveError(f"{path}, line {n}: observer {o} frame {f} appears twice")
        seen.add((o, f))
        out.setdefault(o, []).append(DrivePose(o, f, *vals))
    if not out:
        raise DriveError(f"{path}: no poses")
    for o, rows in out.items():
        rows.sort(key=lambda r: r.t)
        ts = [r.t for r in rows]
        if any(b <= a for a, b in itertools.pairwise(ts)):
            raise DriveError(f"{path}: observer {o} has two frames at the same t")
    return out


def write_drive(out: Path, map_path: Path, camera, poses: list[DrivePose],
                roles: dict | None = None) -> None:
    """Write ``drive.json`` (with a copy of the map as ``map.xodr``) and ``poses.csv``
    into a folder that holds (or will hold) the images."""
    import shutil

    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(map_path, out / "map.xodr")
    meta = {"format": DRIVE_FORMAT, "format_version": DRIVE_VERSION, "map": "map.xodr",
            "camera": camera.to_dict(), "observer_roles": roles or {}}
    (out / "drive.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n",
                                    encoding="utf-8")
    with open(out / "poses.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(POSE_COLUMNS)
        for r in sorted(poses, key=lambda r: (r.observer_id, r.t)):
            w.writerow([r.observer_id, r.frame, repr(float(r.t)), *(repr(float(v)) for v in (
                r.cam_x, r.cam_y, r.cam_z, r.cam_yaw, r.cam_pitch))])
