"""A drive's ground truth (``truth.csv``, optional): where every vehicle was, for evaluation.

A drive (`dashtraj.datasets.drive`) is images and camera poses; what the cameras saw is
what perceive must find. When the truth is known — a CARLA server knows every actor's
box (``dashtraj carla-record`` writes it), ``dashtraj render`` knows its recording's
states, a test track may have RTK-GPS on every car — ``truth.csv`` beside ``poses.csv``
gives it, one row per vehicle and moment::

    t,vehicle_id,role,type_id,vehicle_class,x,y,z,yaw,half_length,half_width,half_height

t in seconds on the clock of ``poses.csv``; vehicle_id an integer (the vehicle that
carries a camera is never a truth box of it: the observer's id, or any vehicle whose
footprint holds the camera, `CARRIER_MARGIN_M`); role
free text (``target``, ``observer``, ``agent``); type_id free text (a CARLA blueprint
id); vehicle_class one of car, truck, bus, motorcycle, bicycle (CARLA's ``van`` counts
as car); x, y, z the centre of the vehicle's footprint on the road (the bottom face of
its 3-D box), CARLA world metres; yaw degrees; half extents of the 3-D box, metres.

At a frame's time t a vehicle stands where its rows say: at a row of that time (within
1 µs), or interpolated between the rows just before and after it (linear, the yaw along
the shorter way round) when they are at most `MAX_GAP_S` apart; otherwise it is absent.

**Truth boxes from 3-D boxes.** Each vehicle's box is projected into the frame's camera
(clipped at the near plane) and the convex hull of its corners is drawn, far vehicles
first, into an instance image.

- *With the frame's depth* (``<observer>/<frame>.depth.png`` beside the image, CARLA's
  depth camera encoding: ``carla-record`` and ``render --depth`` write it), a hull pixel
  is the vehicle's when the point its depth puts on the pixel's ray lies inside the
  vehicle's box (`DEPTH_TOL_M`) and above the road (`GROUND_EPS_M`): the pixels the
  vehicle really covers, hidden by whatever is nearer (a building, a tree, a car), as a
  renderer's instance image gives them. Its silhouette (for the visible fraction) is
  those pixels plus the hull pixels something nearer hides.
- *Without depth*, a vehicle's visible box is what nearer vehicles' hulls leave of its
  own hull, its visible fraction that part of its hull inside the image: a 3-D box's
  outline, not a silhouette (a car's hull takes in the air above its bonnet), and
  nothing but other vehicles hides a vehicle (CARLA's bounding boxes know no buildings).

So the frames of a drive with truth carry ``labels`` and an ``instance`` image like a
rendered frame's, and everything that reads those works on them: the database's truth
columns (a detection's vehicle by IoU ≥ 0.5), the ``oracle`` detector (these boxes as
detections), the depicted vehicle of a box, ``tracker eval`` and ``localization eval``.
How close each comes to the renderer's exact labels is measured on rendered drives
(``tests/perception/test_drive.py``; README, "Your own drives"). The box ignores the
road's grade (its yaw only): on a steep street the road right behind a vehicle going
downhill can count as the vehicle's for a few pixels.
"""

from __future__ import annotations

import csv
import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dashtraj.datasets.drive import DriveError

TRUTH_COLUMNS = ("t", "vehicle_id", "role", "type_id", "vehicle_class", "x", "y", "z", "yaw",
                 "half_length", "half_width", "half_height")
TRUTH_CLASSES = ("car", "truck", "bus", "motorcycle", "bicycle")
_CLASS_ALIASES = {"van": "car"}
MAX_GAP_S = 1.0
"""Longest time between two rows of a vehicle that a frame between them interpolates."""
EXACT_S = 1e-6
DEPTH_TOL_M = 0.3
"""How far outside its 3-D box a pixel's depth point may lie and be the vehicle's (mesh
and box differ by mirrors, rounding; the depth image by its resolution)."""
GROUND_EPS_M = 0.05
"""Depth points less than this above the box's bottom are the road, not the vehicle."""
DEPTH_SCALE_M = 1000.0
"""CARLA's depth encoding: (R + 256 G + 65536 B) / (256³ − 1) × 1000 m."""
CARRIER_MARGIN_M = 0.5
"""A vehicle whose footprint, grown by this much, holds the camera carries it (never a
box of its own camera, whatever its id in truth.csv)."""
MAX_RANGE_M = 1000.0
"""Vehicles farther from the camera than this (ground plane) are left out of a frame."""
NEAR_M = 0.1
"""The near plane: a box's parts closer than this along the optical axis are clipped."""
_NUM = ("t", "x", "y", "z", "yaw", "half_length", "half_width", "half_height")
# the 12 edges of `box_corners`' 8 corners (bottom 0-3, top 4-7)
_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4),
          (0, 4), (1, 5), (2, 6), (3, 7))


class TruthError(DriveError):
    """A truth.csv that cannot be read (the message names the file and line)."""


@dataclass(frozen=True)
class TruthMoment:
    """Every vehicle present at one moment: (N,) arrays and per-vehicle strings."""

    vehicle_ids: np.ndarray  # int64
    classes: tuple[str, ...]
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    yaw: np.ndarray
    half_length: np.ndarray
    half_width: np.ndarray
    half_height: np.ndarray

    def __len__(self) -> int:
        return len(self.vehicle_ids)


@dataclass(frozen=True)
class _Track:
    t: np.ndarray  # (n,) ascending
    values: np.ndarray  # (n, 7): x, y, z, yaw, half_length, half_width, half_height
    vehicle_class: str
    role: str
    type_id: str


class DriveTruth:
    """The rows of a ``truth.csv``, by vehicle (`read_truth`)."""

    def __init__(self, path: Path, tracks: dict[int, _Track]):
        self.path = path
        self._tracks = dict(sorted(tracks.items()))

    @property
    def vehicle_ids(self) -> list[int]:
        return list(self._tracks)

    def role(self, vehicle_id: int) -> str:
        return self._tracks[vehicle_id].role

    def vehicle_class(self, vehicle_id: int) -> str:
        return self._tracks[vehicle_id].vehicle_class

    def at(self, t: float) -> TruthMoment:
        """Every vehicle present at time ``t`` (module docstring), by vehicle id."""
        ids, classes, rows = [], [], []
        for vid, tr in self._tracks.items():
            v = _value_at(tr, t)
            if v is not None:
                ids.append(vid)
                classes.append(tr.vehicle_class)
                rows.append(v)
        a = np.asarray(rows, np.float64).reshape(-1, 7)
        return TruthMoment(np.asarray(ids, np.int64), tuple(classes), *(a[:, k] for k in range(7)))


def _value_at(tr: _Track, t: float) -> np.ndarray | None:
    i = int(np.searchsorted(tr.t, t))
    if i < len(tr.t) and abs(tr.t[i] - t) <= EXACT_S:
        return tr.values[i]
    if i > 0 and abs(tr.t[i - 1] - t) <= EXACT_S:
        return tr.values[i - 1]
    if i == 0 or i == len(tr.t) or tr.t[i] - tr.t[i - 1] > MAX_GAP_S:
        return None
    a, b = tr.values[i - 1], tr.values[i]
    w = (t - tr.t[i - 1]) / (tr.t[i] - tr.t[i - 1])
    out = a + w * (b - a)
    dyaw = (b[3] - a[3] + 180.0) % 360.0 - 180.0
    out[3] = a[3] + w * dyaw
    return out


def read_truth(path: str | Path) -> DriveTruth:
    """Read and check a ``truth.csv``. Raises TruthError naming the file and line."""
    from dashtraj.errors import read_utf8

    path = Path(path)
    reader = csv.DictReader(read_utf8(path, TruthError).splitlines())
    missing = [c for c in TRUTH_COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise TruthError(f"{path}: missing column {missing[0]!r} (columns: "
                         f"{', '.join(TRUTH_COLUMNS)})")
    rows: dict[int, list] = {}
    info: dict[int, tuple[str, str, str, int]] = {}
    for n, row in enumerate(reader, start=2):
        try:
            vid = int(row["vehicle_id"])
            vals = [float(row[c]) for c in _NUM]
        except (TypeError, ValueError):
            raise TruthError(f"{path}, line {n}: vehicle_id must be an integer and "
                             f"{', '.join(_NUM)} numbers") from None
        if not all(math.isfinite(v) for v in vals):
            raise TruthError(f"{path}, line {n}: numbers must be finite")
        if min(vals[5:]) <= 0.0:
            raise TruthError(f"{path}, line {n}: half extents must be > 0 m")
        cls = (row["vehicle_class"] or "").strip().lower()
        cls = _CLASS_ALIASES.get(cls, cls)
        if cls not in TRUTH_CLASSES:
            raise TruthError(f"{path}, line {n}: vehicle_class {row['vehicle_class']!r} is not "
                             f"one of {', '.join(TRUTH_CLASSES)} (or van)")
        first = info.setdefault(vid, (cls, row["role"] or "", row["type_id"] or "", n))
        if first[0] != cls:
            raise TruthError(f"{path}, line {n}: vehicle {vid} is a {cls} here and a "
                             f"{first[0]} on line {first[3]}")
        rows.setdefault(vid, []).append((vals[0], n, vals[1:]))
    if not rows:
        raise TruthError(f"{path}: no rows")
    tracks = {}
    for vid, rs in rows.items():
        rs.sort(key=lambda r: r[0])
        for (ta, _, _), (tb, nb, _) in itertools.pairwise(rs):
            if tb - ta <= EXACT_S:
                raise TruthError(f"{path}, line {nb}: vehicle {vid} has two rows at t {tb:g}")
        cls, role, type_id, _ = info[vid]
        tracks[vid] = _Track(np.array([r[0] for r in rs]), np.array([r[2] for r in rs]),
                             cls, role, type_id)
    return DriveTruth(path, tracks)


def write_truth(path: str | Path, rows) -> None:
    """Write ``truth.csv``: ``rows`` of (t, vehicle_id, role, type_id, vehicle_class, x, y,
    z, yaw, half_length, half_width, half_height), sorted by (t, vehicle_id)."""
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(TRUTH_COLUMNS)
        for r in sorted(rows, key=lambda r: (r[0], r[1])):
            w.writerow([repr(float(r[0])), int(r[1]), r[2], r[3], r[4],
                        *(repr(float(v)) for v in r[5:])])


def encode_depth(depth_m: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a depth image in metres, in CARLA's depth camera encoding
    (what ``sensor.camera.depth`` saves raw): 24 bits over 0..1000 m, farther (and
    infinity, the sky) clipped to 1000 m."""
    d = np.nan_to_num(np.asarray(depth_m, np.float64), nan=DEPTH_SCALE_M, posinf=DEPTH_SCALE_M)
    n = np.rint(np.clip(d / DEPTH_SCALE_M, 0.0, 1.0) * (256 ** 3 - 1)).astype(np.int64)
    return np.stack([n & 255, (n >> 8) & 255, n >> 16], axis=-1).astype(np.uint8)


def decode_depth(rgb: np.ndarray) -> np.ndarray:
    """(H, W) float32 metres of CARLA's depth encoding (`encode_depth`)."""
    a = np.asarray(rgb).astype(np.int64)
    n = a[..., 0] + a[..., 1] * 256 + a[..., 2] * 65536
    return (n / (256 ** 3 - 1) * DEPTH_SCALE_M).astype(np.float32)


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (K, 2) of 2-D points, counter-clockwise (Andrew's monotone chain)."""
    pts = sorted(set(map(tuple, np.round(points, 6).tolist())))
    if len(pts) <= 2:
        return np.asarray(pts, np.float64).reshape(-1, 2)

    def half(seq):
        out: list = []
        for p in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (p[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (p[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(reversed(pts))
    return np.asarray(lower[:-1] + upper[:-1], np.float64)


def _clip_near(p_cam: np.ndarray) -> np.ndarray:
    """The corners (8, 3) of a box in camera axes, clipped at the near plane: the corners
    in front of it and the points where the box's edges cross it."""
    d = p_cam[:, 0]
    out = [p_cam[i] for i in range(8) if d[i] > NEAR_M]
    for a, b in _EDGES:
        if (d[a] > NEAR_M) != (d[b] > NEAR_M):
            w = (NEAR_M - d[a]) / (d[b] - d[a])
            out.append(p_cam[a] + w * (p_cam[b] - p_cam[a]))
    return np.asarray(out, np.float64).reshape(-1, 3)


def _depth_masks(spec, camera_pose, moment: TruthMoment, i: int, lo, hi, hull: np.ndarray,
                 depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(own, silhouette) masks of vehicle ``i`` in the window ``lo``..``hi`` from the
    frame's depth image: a hull pixel is the vehicle's own when the point the depth puts
    on its ray lies inside the vehicle's box (grown by `DEPTH_TOL_M`) at least
    `GROUND_EPS_M` above its bottom (the road under and beside it is not the vehicle);
    its silhouette adds the hull pixels where something nearer than the box hides it."""
    cx, cy, cz, cyaw, cpitch = (float(v) for v in camera_pose[:5])
    f = spec.focal_px
    u = np.arange(lo[0], hi[0], dtype=np.float64) + 0.5 - spec.width_px / 2.0
    v = np.arange(lo[1], hi[1], dtype=np.float64) + 0.5 - spec.height_px / 2.0
    d = np.where(np.isfinite(depth), depth, 1e9).astype(np.float64)
    right = d * (u[None, :] / f)
    upc = -d * (v[:, None] / f)
    p, hd = math.radians(cpitch), math.radians(cyaw)
    fwd_h = d * math.cos(p) - upc * math.sin(p)
    up = d * math.sin(p) + upc * math.cos(p)
    dx = fwd_h * math.cos(hd) - right * math.sin(hd) + cx - float(moment.x[i])
    dy = fwd_h * math.sin(hd) + right * math.cos(hd) + cy - float(moment.y[i])
    yaw = math.radians(float(moment.yaw[i]))
    lx = dx * math.cos(yaw) + dy * math.sin(yaw)
    ly = -dx * math.sin(yaw) + dy * math.cos(yaw)
    lz = up + cz - float(moment.z[i])
    tol = DEPTH_TOL_M
    own = hull & (np.abs(lx) <= moment.half_length[i] + tol) & \
        (np.abs(ly) <= moment.half_width[i] + tol) & (lz >= GROUND_EPS_M) & \
        (lz <= 2.0 * moment.half_height[i] + tol)
    # nearer than every point of the box along the ray: something hides the vehicle there
    near = math.hypot(float(moment.x[i]) - cx, float(moment.y[i]) - cy) - math.hypot(
        float(moment.half_length[i]), float(moment.half_width[i])) - tol
    hidden = hull & (np.hypot(fwd_h, right) < near)
    return own, own | hidden


def truth_frame(spec, camera_pose, moment: TruthMoment, exclude: int | None = None,
                depth: np.ndarray | None = None):
    """Labels of one frame from the truth (module docstring).

    Args:
        spec: the image's `CameraSpec` (size, FOV). camera_pose: (x, y, z, yaw, pitch,
            ...) of the camera, CARLA world. moment: `DriveTruth.at` the frame's time.
        exclude: the observer's own vehicle id (never a box of its own camera).
        depth: (H, W) metres along the optical axis (`decode_depth` of CARLA's depth
            camera), or None: with it a vehicle's pixels are those whose depth puts them
            inside its box (`_depth_masks`), so anything nearer hides it, not only other
            vehicles, and the box hugs the vehicle rather than its 3-D box's outline.

    Returns:
        (instance, labels, vehicle_ids): (H, W) int32 image of instance ids (0: none),
        `dashtraj.render.labels.VehicleLabel` per vehicle in front of the camera within
        `MAX_RANGE_M`, and each label's vehicle id.
    """
    from PIL import Image, ImageDraw

    from dashtraj.render.labels import (
        VehicleLabel,
        orientation,
        relative_yaw,
        truncation,
        visible_in_boxes,
    )
    from dashtraj.world.camera import DETECTION_CLASSES, box_corners, project, world_to_camera

    w, h = int(spec.width_px), int(spec.height_px)
    cx, cy, cz, cyaw, cpitch = (float(v) for v in camera_pose[:5])
    instance = np.zeros((h, w), np.int32)
    keep = np.ones(len(moment), bool)
    if exclude is not None:
        keep &= moment.vehicle_ids != int(exclude)
    # the vehicle that carries the camera, whatever id the truth gives it: its footprint
    # (grown by CARRIER_MARGIN_M) holds the camera
    rad = np.radians(moment.yaw)
    lx = (cx - moment.x) * np.cos(rad) + (cy - moment.y) * np.sin(rad)
    ly = -(cx - moment.x) * np.sin(rad) + (cy - moment.y) * np.cos(rad)
    keep &= ~((np.abs(lx) <= moment.half_length + CARRIER_MARGIN_M)
              & (np.abs(ly) <= moment.half_width + CARRIER_MARGIN_M))
    dist = np.hypot(moment.x - cx, moment.y - cy)
    keep &= dist <= MAX_RANGE_M
    idx = np.flatnonzero(keep)
    if not len(idx):
        return instance, [], ()
    corners = box_corners(moment.x[idx], moment.y[idx], moment.z[idx], moment.yaw[idx],
                          2 * moment.half_length[idx], 2 * moment.half_width[idx],
                          2 * moment.half_height[idx])
    cam = world_to_camera(corners, (cx, cy, cz), cyaw, cpitch)
    seen = []  # (index into moment, hull uv, projected uv)
    for j, i in enumerate(idx):
        pts = _clip_near(cam[j])
        if len(pts) < 3:
            continue
        uv = project(spec, pts)
        lo, hi = uv.min(0), uv.max(0)
        if hi[0] <= 0 or hi[1] <= 0 or lo[0] >= w or lo[1] >= h:
            continue
        seen.append((int(i), _hull(uv), uv))
    # far first: nearer hulls overwrite
    seen.sort(key=lambda s: -dist[s[0]])
    sil: dict[int, tuple] = {}
    for k, (i, hull, _) in enumerate(seen):
        lo = np.floor(np.clip(hull.min(0), 0, [w, h])).astype(int)
        hi = np.ceil(np.clip(hull.max(0), 0, [w, h])).astype(int)
        if hi[0] <= lo[0] or hi[1] <= lo[1]:
            sil[i] = (0, None)
            continue
        img = Image.new("1", (int(hi[0] - lo[0]), int(hi[1] - lo[1])), 0)
        ImageDraw.Draw(img).polygon([(float(u - lo[0]), float(v - lo[1])) for u, v in hull],
                                    fill=1)
        m = np.asarray(img, bool)
        own = m
        if depth is not None and m.any():
            own, m = _depth_masks(spec, camera_pose, moment, i, lo, hi, m,
                                  depth[lo[1]:hi[1], lo[0]:hi[0]])
        if not m.any():
            sil[i] = (0, None)
            continue
        instance[lo[1]:hi[1], lo[0]:hi[0]][own] = k + 1
        rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))
        sil[i] = (int(m.sum()), (int(lo[0] + cols[0]), int(lo[1] + rows[0]),
                                 int(lo[0] + cols[-1] + 1), int(lo[1] + rows[-1] + 1)))
    # a vehicle's own pixels lie in its silhouette's box
    counts, vboxes = visible_in_boxes(
        instance, range(1, len(seen) + 1),
        [sil[i][1] or (0, 0, 0, 0) for i, _, _ in seen])
    labels, vids = [], []
    for k, (i, _, uv) in enumerate(seen):
        ns, sbox = sil[i]
        vbox, nv = vboxes[k], int(counts[k])
        x, y, yaw = float(moment.x[i]), float(moment.y[i]), float(moment.yaw[i])
        rel = relative_yaw((cx, cy), (x, y), yaw)
        ori = orientation(rel)
        cls = moment.classes[i]
        lo, hi = uv.min(0), uv.max(0)
        labels.append(VehicleLabel(
            instance_id=k + 1, class_name=cls, orientation=ori,
            detection_class=f"{cls}_{ori}",
            detection_class_id=DETECTION_CLASSES.index(f"{cls}_{ori}"),
            relative_yaw_deg=rel, distance_m=float(dist[i]), visible_box=vbox,
            silhouette_box=sbox,
            projected_box=(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])),
            visible_pixels=nv, silhouette_pixels=ns,
            visible_fraction=(nv / ns) if ns else 0.0,
            truncation=truncation(uv, w, h, lo, hi)))
        vids.append(int(moment.vehicle_ids[i]))
    return instance, labels, tuple(vids)
