"""Exact per-frame vehicle labels from the renderer's instance and silhouette passes.

Per vehicle and frame (boxes are (x0, y0, x1, y1) in image pixels, continuous
coordinates with the top-left image corner at (0, 0): a box of whole pixels spans
from the first pixel's left/top edge to the last pixel's right/bottom edge):

- ``visible_box``: tight bound of the vehicle's pixels in ``Frame.instance`` (None if
  no pixel is visible).
- ``silhouette_box``: tight bound of the vehicle's pixels when it is drawn alone,
  without occluders (pass 3 of the renderer), inside the image (None if it covers no
  pixel). ``projected_box``: bound of the projection of its mesh vertices (after
  clipping at the near plane), not clipped to the image.
- ``visible_fraction`` = visible pixels / silhouette pixels (0 if no silhouette).
- ``truncation``: fraction of the area of the projected silhouette (convex hull of the
  projected mesh vertices, unclipped) that lies outside the image; 0 inside, 1 fully
  outside or behind the camera.
- ``orientation``: from the angle between the vehicle's heading and the ground-plane
  ray from the camera to the vehicle: |angle| < 45° → ``back`` (we see its rear),
  > 135° → ``front``, else ``side``. ``detection_class`` = class × orientation, index
  into ``DETECTION_CLASSES`` (vans count as car, trucks as truck, buses as bus).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError

try:  # the camera model of the world layer owns the list and the orientation rule
    from dashtraj.world.camera import DETECTION_CLASSES
except ImportError:  # pragma: no cover - standalone use of the renderer
    DETECTION_CLASSES = (
        "car_front", "car_back", "car_side",
        "truck_front", "truck_back", "truck_side",
        "bus_front", "bus_back", "bus_side",
        "motorcycle_front", "motorcycle_back", "motorcycle_side",
        "bicycle_front", "bicycle_back", "bicycle_side",
    )  # fmt: skip

_CLASS_OF_BODY = {
    "sedan": "car",
    "hatchback": "car",
    "suv": "car",
    "coupe": "car",
    "van": "car",
    "pickup": "car",
    "truck": "truck",
    "bus": "bus",
    "motorcycle": "motorcycle",
    "bicycle": "bicycle",
}
_CLASSES = ("car", "truck", "bus", "motorcycle", "bicycle")


@dataclass(frozen=True)
class VehicleLabel:
    """Ground-truth label of one vehicle in one frame (see the module docstring)."""

    instance_id: int
    class_name: str  # car, truck, bus, motorcycle, bicycle
    orientation: str  # front, back, side
    detection_class: str  # e.g. "car_back"
    detection_class_id: int  # index into DETECTION_CLASSES
    relative_yaw_deg: float  # vehicle yaw − bearing of the camera→vehicle ray, (−180, 180]
    distance_m: float  # ground-plane distance camera → vehicle origin
    visible_box: tuple[int, int, int, int] | None
    silhouette_box: tuple[int, int, int, int] | None
    projected_box: tuple[float, float, float, float] | None
    visible_pixels: int
    silhouette_pixels: int
    visible_fraction: float
    truncation: float

    @property
    def in_view(self) -> bool:
        """True when at least one pixel of the vehicle is visible."""
        return self.visible_pixels > 0


def class_name(model) -> str:
    """Detection class of a catalog model: car, truck, bus, motorcycle or bicycle."""
    vc = str(getattr(model, "vehicle_class", "")).lower()
    if vc in _CLASSES:
        return vc
    if vc == "van":
        return "car"
    body = str(getattr(model, "body_type", "")).lower()
    if body in _CLASS_OF_BODY:
        return _CLASS_OF_BODY[body]
    raise ValueError(
        f"vehicle model {getattr(model, 'blueprint_id', model)!r} has unknown "
        f"class {vc!r} / body type {body!r}; expected one of {_CLASSES}"
    )


def orientation(relative_yaw_deg: float) -> str:
    """back if |angle| < 45°, front if > 135°, else side (angle in degrees).

    The same rule as ``dashtraj.world.camera.orientation_of`` (strict at 45°/135°).
    """
    a = abs((relative_yaw_deg + 180.0) % 360.0 - 180.0)
    return "back" if a < 45.0 else ("front" if a > 135.0 else "side")


def relative_yaw(camera_xy, vehicle_xy, vehicle_yaw_deg: float) -> float:
    """Vehicle heading minus the bearing of the ray camera → vehicle, degrees in (−180, 180]."""
    bearing = math.degrees(math.atan2(vehicle_xy[1] - camera_xy[1], vehicle_xy[0] - camera_xy[0]))
    d = (vehicle_yaw_deg - bearing) % 360.0
    return d - 360.0 if d > 180.0 else d


def clipped_projection(
    world_pts: np.ndarray, owner: np.ndarray, n: int, m: np.ndarray, k: np.ndarray, near: float
) -> tuple[np.ndarray, np.ndarray]:
    """Project the triangles of ``n`` meshes after clipping them at z_cam = ``near``.

    Args:
        world_pts: (3T, 3) triangle-list vertices of all meshes, CARLA world, metres.
        owner: (3T,) int mesh index of each vertex (triangles never straddle meshes).
        n: number of meshes.
        m: (4, 4) world → OpenCV camera matrix; k: (3, 3) intrinsics.
        near: clipping plane distance, metres.

    Returns:
        (P, 2) projected (u, v) pixels of the vertices in front of the plane plus the
        points where triangle edges cross it, sorted by mesh, and (n + 1,) offsets:
        mesh i owns rows offsets[i]:offsets[i + 1].
    """
    c = world_pts @ m[:3, :3].T + m[:3, 3]
    z = c[:, 2]
    keep = z >= near
    if keep.all():  # nothing to clip (the usual case): project every vertex
        pts, own = c, owner
    else:
        pts, own = c[keep], owner[keep]
        zb = z.reshape(-1, 3)[:, [1, 2, 0]].ravel()
        cross = np.flatnonzero((z - near) * (zb - near) < 0)
        if len(cross):
            a = c[cross]
            b = c.reshape(-1, 3, 3)[:, [1, 2, 0]].reshape(-1, 3)[cross]
            t = (near - a[:, 2]) / (b[:, 2] - a[:, 2])
            pts = np.concatenate([pts, a + t[:, None] * (b - a)])
            own = np.concatenate([own, owner[cross]])
            order = np.argsort(own, kind="stable")
            pts, own = pts[order], own[order]
    return _project(pts, k), np.searchsorted(own, np.arange(n + 1))


def _project(pts: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(P, 2) pixels of (P, 3) OpenCV camera points in front of the camera."""
    uv = np.empty((len(pts), 2))
    for j in (0, 1):  # (f * x) / z + c, in this order
        np.multiply(pts[:, j], k[j, j], out=uv[:, j])
        uv[:, j] /= pts[:, 2]
        uv[:, j] += k[j, 2]
    return uv


def hull_rows(positions: np.ndarray) -> np.ndarray:
    """Sorted rows of a mesh's (3T, 3) vertex list that are the vertices of its 3-D
    convex hull (one row per hull vertex); every row when the hull is degenerate.

    The projection of a mesh lying in front of the camera has the same convex hull and
    the same pixel bounds as the projection of these rows (a central projection maps
    the hull onto the hull, and its u and v are extreme at hull vertices)."""
    pts = np.asarray(positions, np.float64)
    uniq, first = np.unique(pts, axis=0, return_index=True)
    try:
        vertices = ConvexHull(uniq).vertices
    except (QhullError, ValueError):  # flat or too few points
        return np.arange(len(pts))
    return np.sort(first[vertices])


def _poly_area(p) -> float:
    """Area of a simple polygon ((P, 2) array or list of (x, y)), shoelace formula."""
    if len(p) < 3:
        return 0.0
    pts = p.tolist() if isinstance(p, np.ndarray) else p
    twice = 0.0
    x0, y0 = pts[-1]
    for x1, y1 in pts:
        twice += x0 * y1 - y0 * x1
        x0, y0 = x1, y1
    return 0.5 * abs(twice)


def _clip_polygon(poly, w: float, h: float) -> list:
    """Sutherland–Hodgman clip of a convex polygon ((P, 2) array or list of (x, y)) to
    [0, w] × [0, h]: the clipped polygon's vertices, a list of (x, y)."""
    pts = poly.tolist() if isinstance(poly, np.ndarray) else list(poly)
    for axis, bound, keep_less in ((0, 0.0, False), (0, w, True), (1, 0.0, False), (1, h, True)):
        if not pts:
            break
        out = []
        for k, p in enumerate(pts):
            q = pts[(k + 1) % len(pts)]
            ia = p[axis] <= bound if keep_less else p[axis] >= bound
            ib = q[axis] <= bound if keep_less else q[axis] >= bound
            if ia:
                out.append(p)
            if ia != ib:
                t = (bound - p[axis]) / (q[axis] - p[axis])
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
        pts = out
    return pts


def truncation(uv: np.ndarray, width: int, height: int, lo=None, hi=None) -> float:
    """Fraction of the convex hull of projected points (P, 2) outside the image
    (``lo``/``hi``: the points' precomputed min/max, optional)."""
    if len(uv) == 0:
        return 1.0
    if lo is None or hi is None:
        lo, hi = uv.min(axis=0), uv.max(axis=0)
    lo, hi = (float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1]))
    if lo[0] >= 0 and lo[1] >= 0 and hi[0] <= width and hi[1] <= height:
        return 0.0
    if hi[0] <= 0 or hi[1] <= 0 or lo[0] >= width or lo[1] >= height:
        return 1.0
    try:  # qhull, then plain Python on the hull's few vertices (numpy's overhead dominates)
        hull = np.asarray(uv, np.float64)[ConvexHull(uv).vertices].tolist()
    except (QhullError, ValueError):  # degenerate (a line or a point)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= width) & (uv[:, 1] >= 0) & (uv[:, 1] <= height)
        return float(1.0 - inside.mean())
    area = _poly_area(hull)
    if area <= 0.0:
        return 1.0
    return float(min(1.0, max(0.0, 1.0 - _poly_area(_clip_polygon(hull, width, height)) / area)))


@dataclass
class VehicleProjection:
    """Projected vertices and pixel boxes of a frame's vehicles (see ``vehicle_boxes``)."""

    uv: np.ndarray  # (P, 2) projected vertices (after near clipping), sorted by vehicle
    offsets: np.ndarray  # (N + 1,) vehicle i owns uv[offsets[i]:offsets[i + 1]]
    lo: np.ndarray  # (N, 2) min (u, v), NaN when nothing is in front of the camera
    hi: np.ndarray  # (N, 2) max (u, v)
    has: np.ndarray  # (N,) bool: some vertex in front of the near plane
    boxes: np.ndarray  # (N, 4) int (c0, r0, c1, r1): 1 px beyond lo/hi, clipped to the image

    def boxes_nonempty(self) -> np.ndarray:
        """(N,) bool: the vehicle can cover a pixel (its box is not empty)."""
        b = self.boxes
        return (b[:, 2] > b[:, 0]) & (b[:, 3] > b[:, 1])


def vehicle_boxes(
    renderer, camera_pose, world: np.ndarray, starts: np.ndarray, hull: np.ndarray | None = None,
    tri: np.ndarray | None = None,
) -> VehicleProjection:
    """Project every vehicle's vertices (``world`` (V, 3), vehicle i owning rows
    starts[i]:starts[i + 1]) and bound its pixels: every pixel a vehicle can cover
    lies in its box (the rasterizer only covers pixel centres inside its triangles).

    ``tri`` ((3T,) rows of ``world``, vehicle by vehicle): the triangle list, where
    ``world`` holds each vertex once; without it ``world`` is the triangle list.
    ``hull`` (sorted rows of ``world``, ``hull_rows`` of each vehicle's mesh): a
    vehicle wholly in front of the near plane is projected by its hull vertices only
    (the same hull and bounds, a tenth of the points); one that crosses the plane is
    clipped and projected whole, as without ``hull``."""
    from dashtraj.render.scene import NEAR_M, world_to_opencv

    n = len(starts) - 1
    w, h = renderer.width, renderer.height
    m = world_to_opencv(camera_pose)
    owner = np.repeat(np.arange(n), np.diff(starts))
    if tri is None:
        tri = np.arange(len(world))
    if hull is None:
        uv, off = clipped_projection(world[tri], owner[tri], n, m, renderer.k, NEAR_M)
    else:
        uv, off = _hull_projection(world, owner, hull, n, m, renderer.k, NEAR_M, tri)
    has = off[1:] > off[:-1]
    lo = np.full((n, 2), np.nan)
    hi = np.full((n, 2), np.nan)
    if len(uv):
        first = np.minimum(off[:-1], len(uv) - 1)
        lo[has] = np.minimum.reduceat(uv, first, axis=0)[has]
        hi[has] = np.maximum.reduceat(uv, first, axis=0)[has]
    boxes = np.zeros((n, 4), np.int64)
    boxes[has] = np.column_stack(
        [
            np.clip(np.floor(lo[has, 0]) - 1, 0, w),
            np.clip(np.floor(lo[has, 1]) - 1, 0, h),
            np.clip(np.ceil(hi[has, 0]) + 1, 0, w),
            np.clip(np.ceil(hi[has, 1]) + 1, 0, h),
        ]
    )
    return VehicleProjection(uv, off, lo, hi, has, boxes)


def _hull_projection(world, owner, hull, n, m, k, near, tri):
    """``clipped_projection``'s (uv, offsets) with the hull vertices alone standing for
    each vehicle that lies wholly in front of the near plane (``vehicle_boxes``; ``tri``:
    the triangle list as rows of ``world``)."""
    own_h = owner[hull]
    c = world[hull] @ m[:3, :3].T + m[:3, 3]
    crossing = np.zeros(n, bool)
    crossing[own_h[c[:, 2] < near]] = True  # its nearest vertex is a hull vertex
    if not crossing.any():  # the usual case
        return _project(c, k), np.searchsorted(own_h, np.arange(n + 1))
    front = ~crossing[own_h]
    rows = tri[crossing[owner[tri]]]
    uv_c, off_c = clipped_projection(world[rows], owner[rows], n, m, k, near)
    own = np.concatenate([own_h[front], np.repeat(np.arange(n), np.diff(off_c))])
    order = np.argsort(own, kind="stable")
    uv = np.concatenate([_project(c[front], k), uv_c])[order]
    return uv, np.searchsorted(own[order], np.arange(n + 1))


def visible_in_boxes(instance: np.ndarray, ids, boxes):
    """Visible pixel counts (N,) and tight boxes (a list, None where no pixel shows) of the
    instance ids ``ids`` (N,) in an instance image, scanning only each id's box ``boxes[i]``
    (x0, y0, x1, y1; ints, an empty box for none), which must hold all its pixels."""
    n = len(ids)
    counts = np.zeros(n, np.int64)
    vboxes: list = [None] * n
    for i, iid in enumerate(ids):
        c0, r0, c1, r1 = (int(c) for c in boxes[i])
        if c1 <= c0 or r1 <= r0:
            continue
        m = instance[r0:r1, c0:c1] == iid
        rows = np.flatnonzero(m.any(axis=1))
        if len(rows) == 0:
            continue
        cols = np.flatnonzero(m.any(axis=0))
        counts[i] = int(np.count_nonzero(m))
        vboxes[i] = (
            c0 + int(cols[0]),
            r0 + int(rows[0]),
            c0 + int(cols[-1]) + 1,
            r0 + int(rows[-1]) + 1,
        )
    if int(counts.sum()) != int(np.count_nonzero(instance)):  # pragma: no cover
        # a pixel outside its vehicle's box would break the containment argument: then
        # scan the whole image (never seen; this keeps the labels exact regardless)
        ids = np.asarray(ids, np.int64)
        order = np.argsort(ids)
        pos = np.minimum(np.searchsorted(ids[order], instance), n - 1)
        compact = np.where(ids[order][pos] == instance, order[pos] + 1, 0).astype(np.int32)
        counts = np.bincount(compact.ravel(), minlength=n + 1)[1 : n + 1]
        slices = ndimage.find_objects(compact, max_label=n)
        vboxes = [
            None if sl is None else (sl[1].start, sl[0].start, sl[1].stop, sl[0].stop)
            for sl in slices
        ]
    return counts, vboxes


def compute_labels(
    renderer, frame, vehicles, proj: VehicleProjection, ranges, mvp: bytes
) -> list[VehicleLabel]:
    """Labels of every vehicle of a frame (called by ``Renderer.render``).

    Args:
        renderer: the ``Renderer`` that drew the frame (runs the silhouette pass).
        frame: the ``Frame`` with rgb/instance/depth.
        vehicles: the ``VehicleInstance`` list, in draw order.
        proj: the vehicles' projection (``vehicle_boxes``).
        ranges: (first vertex, count) of each vehicle in the vehicle buffer.
        mvp: the frame's world → clip matrix bytes.
    """
    n = len(vehicles)
    if n == 0:
        return []
    w, h = renderer.width, renderer.height
    uv, off, lo, hi, has = proj.uv, proj.offsets, proj.lo, proj.hi, proj.has
    sil_counts, sil_boxes = renderer.silhouette_counts(proj.boxes, ranges, mvp)
    # a vehicle's visible pixels lie in its silhouette: scan only the silhouette box
    vis_counts, vis_boxes = visible_in_boxes(frame.instance, [v.instance_id for v in vehicles],
                                             np.maximum(sil_boxes, 0))
    pboxes = [
        (float(lo[i, 0]), float(lo[i, 1]), float(hi[i, 0]), float(hi[i, 1])) if has[i] else None
        for i in range(n)
    ]
    cam_xy = frame.camera_pose[:2]
    out = []
    for i, v in enumerate(vehicles):
        cls = class_name(v.model)
        rel = relative_yaw(cam_xy, (v.x, v.y), v.yaw_deg)
        ori = orientation(rel)
        det = f"{cls}_{ori}"
        vbox = vis_boxes[i]
        sbox = None if sil_boxes[i, 0] < 0 else tuple(int(c) for c in sil_boxes[i])
        nv, ns = int(vis_counts[i]), int(sil_counts[i])
        out.append(
            VehicleLabel(
                instance_id=v.instance_id,
                class_name=cls,
                orientation=ori,
                detection_class=det,
                detection_class_id=DETECTION_CLASSES.index(det),
                relative_yaw_deg=rel,
                distance_m=math.hypot(v.x - cam_xy[0], v.y - cam_xy[1]),
                visible_box=vbox,
                silhouette_box=sbox,
                projected_box=pboxes[i],
                visible_pixels=nv,
                silhouette_pixels=ns,
                visible_fraction=(nv / ns) if ns else 0.0,
                truncation=truncation(uv[off[i] : off[i + 1]], w, h, lo[i], hi[i]),
            )
        )
    return out
