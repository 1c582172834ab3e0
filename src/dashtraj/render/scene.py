"""`Renderer`: dashcam frames of a town with exact per-pixel instance ids and depth.

Camera model (``shared/CARLA_FACTS.md``, RGB camera): pinhole, horizontal FOV,
K = [[f, 0, W/2], [0, f, H/2], [0, 0, 1]] with f = W / (2 tan(FOV/2)); camera axes
(x forward, y right, z up) map to OpenCV's (x right, y down, z forward) as (y, −z, x).
Image coordinates (u, v) are continuous with the image's top-left corner at (0, 0);
pixel (row i, column j) covers u ∈ [j, j+1), v ∈ [i, i+1), so its centre is
(j + 0.5, i + 0.5) and the principal point W/2, H/2 lies on a pixel corner (as in
CARLA/Unreal).

Passes per frame (moderngl on Mesa llvmpipe, headless EGL; see ``dashtraj.render.gl``):

1. colour, ``msaa`` samples, resolved to ``rgb``;
2. ids and depth without multisampling (one sample per pixel centre: exact ids);
3. silhouettes: every vehicle drawn alone (no occluders) into an id buffer; vehicles
   whose projected boxes do not overlap share a pass. Pass 3 rasterizes each
   vehicle with the same viewport and matrix as pass 2, so the visible pixels of a
   vehicle are always a subset of its silhouette pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dashtraj.render.gl import create_context
from dashtraj.render.meshes import Mesh, scene_meshes, vehicle_mesh

NEAR_M = 0.1
FAR_M = 2000.0
SKY_RGB = (0.62, 0.74, 0.88)
SUN_DIR = (0.35, -0.45, 0.82)  # CARLA world, towards the sun (unit after normalising)
AMBIENT, DIFFUSE = 0.45, 0.6
FRONT_FACE = "cw"  # meshes wind CCW seen from outside; the y-down image flip turns that to CW

_VS = """
#version 330
uniform mat4 mvp;
uniform vec3 sun;
in vec3 in_pos;
in vec3 in_normal;
in vec4 in_color;
in float in_id;
out vec3 v_color;
out float v_depth;
flat out int v_id;
void main() {
    gl_Position = mvp * vec4(in_pos, 1.0);
    float lam = max(dot(normalize(in_normal), sun), 0.0);
    vec3 lit = in_color.rgb * (%(ambient)f + %(diffuse)f * lam);
    v_color = mix(lit, in_color.rgb, in_color.a);
    v_depth = gl_Position.w;
    v_id = int(in_id + 0.5);
}
"""
_FS_COLOR = """
#version 330
in vec3 v_color;
in float v_depth;
flat in int v_id;
out vec4 f_color;
void main() { f_color = vec4(v_color, 1.0); }
"""
_FS_ID = """
#version 330
in vec3 v_color;
in float v_depth;
flat in int v_id;
layout(location = 0) out int f_id;
layout(location = 1) out float f_depth;
void main() { f_id = v_id; f_depth = v_depth; }
"""


def intrinsics(width: int, height: int, fov_deg: float) -> np.ndarray:
    """CARLA's ideal pinhole K (3, 3), pixels: f = W / (2 tan(FOV/2)), centre (W/2, H/2)."""
    f = width / (2.0 * math.tan(math.radians(fov_deg) / 2.0))
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def rotation_matrix(yaw_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """CARLA rotation (3, 3): columns are the body's forward, right, up axes in the world.

    Matches UE4/CARLA ``Transform.get_matrix()`` (yaw turns +x toward +y, pitch raises
    the nose, roll about forward).
    """
    cy, sy = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    cp, sp = math.cos(math.radians(pitch_deg)), math.sin(math.radians(pitch_deg))
    cr, sr = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    return np.array(
        [
            [cp * cy, cy * sp * sr - sy * cr, -cy * sp * cr - sy * sr],
            [cp * sy, sy * sp * sr + cy * cr, -sy * sp * cr + cy * sr],
            [sp, -cp * sr, cp * cr],
        ]
    )


def world_to_opencv(camera_pose) -> np.ndarray:
    """(4, 4) matrix from CARLA world (metres) to the OpenCV camera frame (x right,
    y down, z forward, metres) for ``camera_pose`` = (x, y, z, yaw, pitch, roll)."""
    x, y, z, yaw, pitch, roll = (float(v) for v in camera_pose)
    r = rotation_matrix(yaw, pitch, roll)  # body axes (fwd, right, up) in world
    world_to_cam = np.eye(4)
    world_to_cam[:3, :3] = r.T
    world_to_cam[:3, 3] = -r.T @ np.array([x, y, z])
    to_cv = np.array([[0, 1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], float)
    return to_cv @ world_to_cam


def project_points(points: np.ndarray, camera_pose, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project (N, 3) CARLA-world points: returns (N, 2) (u, v) pixels and (N,) depth
    z_cam (metres along the optical axis; ≤ 0 means behind the camera)."""
    p = np.asarray(points, float).reshape(-1, 3)
    m = world_to_opencv(camera_pose)
    c = p @ m[:3, :3].T + m[:3, 3]
    z = c[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.column_stack([k[0, 0] * c[:, 0] / z + k[0, 2], k[1, 1] * c[:, 1] / z + k[1, 2]])
    return uv, z


def _gl_projection(k: np.ndarray, width: int, height: int) -> np.ndarray:
    """OpenCV camera frame → GL clip space; clip w = z_cam, NDC y up = image top."""
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    a = (FAR_M + NEAR_M) / (FAR_M - NEAR_M)
    b = -2.0 * FAR_M * NEAR_M / (FAR_M - NEAR_M)
    return np.array(
        [
            [2 * fx / width, 0.0, 2 * cx / width - 1.0, 0.0],
            [0.0, -2 * fy / height, 1.0 - 2 * cy / height, 0.0],
            [0.0, 0.0, a, b],
            [0.0, 0.0, 1.0, 0.0],
        ]
    )


@dataclass(frozen=True)
class VehicleInstance:
    """One vehicle to draw.

    Attributes:
        instance_id: ≥ 1, written into ``Frame.instance``.
        identity: a catalog ``VehicleIdentity`` (``.model``, ``.rgb``) or a
            ``VehicleModel`` (then ``rgb`` is its ``default_color`` or grey).
        x, y, z: location of the vehicle's footprint centre on the ground, CARLA world, m.
        yaw_deg: heading, CARLA degrees.
    """

    instance_id: int
    identity: Any
    x: float
    y: float
    z: float
    yaw_deg: float

    @property
    def model(self):
        return getattr(self.identity, "model", self.identity)

    @property
    def rgb(self) -> tuple[int, int, int]:
        c = getattr(self.identity, "rgb", None)
        if c is None:
            c = getattr(self.model, "default_color", None)
            c = getattr(c, "rgb", c)
        return tuple(int(v) for v in c) if c is not None else (128, 128, 128)


@dataclass
class Frame:
    """One rendered frame.

    Attributes:
        rgb: (H, W, 3) uint8, antialiased.
        instance: (H, W) int32 instance ids (0 = no vehicle), one sample per pixel centre.
        depth: (H, W) float32 metres along the optical axis (inf = sky).
        k: (3, 3) camera intrinsics, pixels.
        camera_pose: (x, y, z, yaw, pitch, roll), CARLA world.
        labels: per-vehicle labels (``dashtraj.render.labels.VehicleLabel``), in the
            order the vehicles were given.
    """

    rgb: np.ndarray
    instance: np.ndarray
    depth: np.ndarray
    k: np.ndarray
    camera_pose: tuple
    labels: list = field(default_factory=list)


def as_instances(vehicles) -> list[VehicleInstance]:
    """Accept ``VehicleInstance`` objects or tuples (instance_id, identity, x, y, z, yaw)."""
    out = []
    for v in vehicles:
        if not isinstance(v, VehicleInstance):
            v = VehicleInstance(int(v[0]), v[1], float(v[2]), float(v[3]), float(v[4]), float(v[5]))
        if v.instance_id < 1:
            raise ValueError(f"vehicle instance_id must be ≥ 1, got {v.instance_id}")
        out.append(v)
    ids = [v.instance_id for v in out]
    if len(set(ids)) != len(ids):
        raise ValueError(f"duplicate vehicle instance ids in {ids}")
    return out


def vehicle_world_positions(v: VehicleInstance, mesh: Mesh) -> np.ndarray:
    """(N, 3) mesh vertices of vehicle ``v`` in the CARLA world frame, metres."""
    c, s = math.cos(math.radians(v.yaw_deg)), math.sin(math.radians(v.yaw_deg))
    p = mesh.positions.astype(np.float64)
    return np.column_stack(
        [v.x + c * p[:, 0] - s * p[:, 1], v.y + s * p[:, 0] + c * p[:, 1], v.z + p[:, 2]]
    )


class Renderer:
    """Headless CPU renderer of one map.

    Args:
        road_map: a ``dashtraj.roads.RoadMap``; its static meshes are built once.
        width, height: image size, pixels.
        fov_deg: horizontal field of view, degrees.
        msaa: samples of the colour pass (0 or 1 = none).
        seed: building placement seed.
        ctx: an existing moderngl context to share; None creates a headless EGL one.
        threads: llvmpipe threads for a new context (see ``dashtraj.render.gl``).

    Example:
        >>> r = Renderer(m, 640, 360)  # doctest: +SKIP
        >>> f = r.render((0, 0, 1.5, 0, 0, 0), [(1, ident, 15, 0, 0, 0)])  # doctest: +SKIP
        >>> f.labels[0].detection_class  # doctest: +SKIP
        'car_back'
    """

    def __init__(
        self,
        road_map,
        width: int = 1280,
        height: int = 720,
        fov_deg: float = 90.0,
        msaa: int = 4,
        seed: int = 0,
        ctx=None,
        threads: int | None = None,
    ):
        import moderngl

        self.road_map = road_map
        self.width, self.height = int(width), int(height)
        self.fov_deg = float(fov_deg)
        self.msaa = int(msaa) if msaa and msaa > 1 else 0
        self.k = intrinsics(self.width, self.height, self.fov_deg)
        self._proj = _gl_projection(self.k, self.width, self.height)
        self._owns_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_context(threads)
        ctx = self.ctx
        sun = np.asarray(SUN_DIR, float)
        sun = sun / np.linalg.norm(sun)
        vs = _VS % {"ambient": AMBIENT, "diffuse": DIFFUSE}
        self._prog_color = ctx.program(vertex_shader=vs, fragment_shader=_FS_COLOR)
        self._prog_id = ctx.program(vertex_shader=vs, fragment_shader=_FS_ID)
        for p in (self._prog_color, self._prog_id):
            if "sun" in p:
                p["sun"].value = tuple(sun)
        size = (self.width, self.height)
        self._fbo_ms = ctx.framebuffer(
            color_attachments=[ctx.renderbuffer(size, 4, samples=self.msaa)],
            depth_attachment=ctx.depth_renderbuffer(size, samples=self.msaa),
        )
        self._fbo_rgb = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 4)])
        self._fbo_id = ctx.framebuffer(
            color_attachments=[
                ctx.renderbuffer(size, 1, dtype="i4"),
                ctx.renderbuffer(size, 1, dtype="f4"),
            ],
            depth_attachment=ctx.depth_renderbuffer(size),
        )
        self._fbo_sil = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 1, dtype="i4")])
        scene = scene_meshes(road_map, seed)
        self._static = []
        # drawn after the vehicles, near to far, so hidden fragments fail the depth test early
        for mesh, offset in ((scene.buildings, False), (scene.ground, False), (scene.marks, True)):
            if mesh.n_vertices:
                data, tiles = _tiled(mesh.interleaved(0.0))
                buf = ctx.buffer(data.tobytes())
                self._static.append((self._vaos(buf), offset, tiles))
        self._vbuf = None
        self._vbuf_bytes = 0
        self._moderngl = moderngl

    # ------------------------------------------------------------------ GL plumbing
    def _vaos(self, buf):
        # attributes a program does not use are optimised away: skip their bytes
        color = (buf, "3f 3f 4f 4x", "in_pos", "in_normal", "in_color")
        ids = (buf, "3f 28x 1f", "in_pos", "in_id")
        return (
            self.ctx.vertex_array(self._prog_color, [color]),
            self.ctx.vertex_array(self._prog_id, [ids]),
        )

    def _upload_vehicles(self, data: np.ndarray):
        nbytes = data.nbytes
        if self._vbuf is None or nbytes > self._vbuf_bytes:
            cap = max(nbytes, 1 << 16)
            cap = 1 << (cap - 1).bit_length()
            if self._vbuf is not None:
                self._vbuf.release()
            self._vbuf = self.ctx.buffer(reserve=cap, dynamic=True)
            self._vbuf_bytes = cap
            self._vveh = self._vaos(self._vbuf)
        if nbytes:
            self._vbuf.write(data.tobytes())

    def _draw_scene(self, which: int, mvp: bytes, n_vehicle_vertices: int):
        mgl = self._moderngl
        prog = self._prog_color if which == 0 else self._prog_id
        prog["mvp"].write(mvp)
        if n_vehicle_vertices:
            self._vveh[which].render(mgl.TRIANGLES, vertices=n_vehicle_vertices)
        for (vaos, offset, _tiles), runs in zip(self._static, self._runs, strict=True):
            if offset:
                self.ctx.polygon_offset = (0.0, -2.0)  # units only: no slope term
            for first, count in runs:
                vaos[which].render(mgl.TRIANGLES, first=first, vertices=count)
            if offset:
                self.ctx.polygon_offset = (0.0, 0.0)

    # ------------------------------------------------------------------ frame
    def mvp(self, camera_pose) -> np.ndarray:
        """(4, 4) world → clip matrix (float64) for a camera pose."""
        return self._proj @ world_to_opencv(camera_pose)

    def render(self, camera_pose, vehicles=(), labels: bool = True) -> Frame:
        """Render one frame.

        Args:
            camera_pose: (x, y, z, yaw_deg, pitch_deg, roll_deg) of the camera, CARLA
                world (metres, degrees).
            vehicles: ``VehicleInstance`` objects or tuples (instance_id ≥ 1, identity
                or model, x, y, z, yaw_deg), CARLA world.
            labels: compute per-vehicle labels (``Frame.labels``).

        Returns:
            a :class:`Frame`.
        """
        from dashtraj.render.labels import compute_labels

        mgl = self._moderngl
        ctx = self.ctx
        vs = as_instances(vehicles)
        meshes = [vehicle_mesh(v.model, v.rgb) for v in vs]
        world = [vehicle_world_positions(v, mesh) for v, mesh in zip(vs, meshes, strict=True)]
        ranges, first = [], 0
        rows = []
        for i, (mesh, pos) in enumerate(zip(meshes, world, strict=True)):
            d = mesh.interleaved(float(i + 1))
            d[:, :3] = pos
            c, s = math.cos(math.radians(vs[i].yaw_deg)), math.sin(math.radians(vs[i].yaw_deg))
            n = mesh.normals
            d[:, 3] = c * n[:, 0] - s * n[:, 1]
            d[:, 4] = s * n[:, 0] + c * n[:, 1]
            rows.append(d)
            ranges.append((first, mesh.n_vertices))
            first += mesh.n_vertices
        data = np.concatenate(rows) if rows else np.zeros((0, 11), np.float32)
        self._upload_vehicles(data)
        mvp64 = self.mvp(camera_pose)
        self._runs = [_visible_runs(tiles, mvp64) for _, _, tiles in self._static]
        mvp = mvp64.T.astype("f4").tobytes()  # column-major for GLSL

        ctx.enable(mgl.DEPTH_TEST)
        ctx.disable(mgl.BLEND)
        ctx.enable(mgl.CULL_FACE)
        ctx.front_face = FRONT_FACE
        # pass 1: colour (MSAA) -> resolve
        self._fbo_ms.use()
        self._fbo_ms.clear(*SKY_RGB, 1.0, depth=1.0)
        self._draw_scene(0, mvp, first)
        ctx.copy_framebuffer(self._fbo_rgb, self._fbo_ms)
        rgb = np.frombuffer(self._fbo_rgb.read(components=4, alignment=1), np.uint8)
        rgb = rgb.reshape(self.height, self.width, 4)[::-1, :, :3].copy()
        # pass 2: instance ids + depth, one sample per pixel
        self._fbo_id.use()
        self._fbo_id.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self._draw_scene(1, mvp, first)
        idx = np.frombuffer(
            self._fbo_id.read(components=1, attachment=0, dtype="i4", alignment=1), np.int32
        ).reshape(self.height, self.width)[::-1]
        depth = (
            np.frombuffer(
                self._fbo_id.read(components=1, attachment=1, dtype="f4", alignment=1), np.float32
            )
            .reshape(self.height, self.width)[::-1]
            .copy()
        )
        depth[depth <= 0.0] = np.inf
        lut = np.array([0] + [v.instance_id for v in vs], np.int32)
        instance = lut[idx]
        frame = Frame(rgb, instance, depth, self.k.copy(), tuple(float(c) for c in camera_pose))
        if labels:
            frame.labels = compute_labels(self, frame, vs, world, idx, ranges, mvp)
        return frame

    def silhouette_counts(self, boxes: np.ndarray, ranges, mvp: bytes) -> np.ndarray:
        """Silhouette pixel counts of vehicles drawn alone (pass 3).

        Args:
            boxes: (N, 4) int pixel boxes (c0, r0, c1, r1), exclusive ends, that contain
                each vehicle's pixels (rows from the image top); empty boxes are skipped.
            ranges: (first vertex, vertex count) of each vehicle in the vehicle buffer.
            mvp: the frame's matrix bytes.

        Returns:
            (N,) int64 pixel counts and (N, 4) int tight silhouette boxes (−1 if none).
        """
        mgl = self._moderngl
        n = len(ranges)
        counts = np.zeros(n, np.int64)
        tight = np.full((n, 4), -1, np.int64)
        todo = [i for i in range(n) if boxes[i, 2] > boxes[i, 0] and boxes[i, 3] > boxes[i, 1]]
        # greedy layering: vehicles whose boxes overlap go to different passes
        layers: list[list[int]] = []
        for i in sorted(todo, key=lambda j: (boxes[j, 0], boxes[j, 1], j)):
            for layer in layers:
                if not any(_overlap(boxes[i], boxes[j]) for j in layer):
                    layer.append(i)
                    break
            else:
                layers.append([i])
        self.ctx.disable(mgl.DEPTH_TEST)
        self._prog_id["mvp"].write(mvp)
        self._fbo_sil.use()
        for layer in layers:
            c0, r0 = min(boxes[j, 0] for j in layer), min(boxes[j, 1] for j in layer)
            c1, r1 = max(boxes[j, 2] for j in layer), max(boxes[j, 3] for j in layer)
            vp = (int(c0), int(self.height - r1), int(c1 - c0), int(r1 - r0))
            self._fbo_sil.clear(0.0, 0.0, 0.0, 0.0, viewport=vp)
            for j in layer:
                first, count = ranges[j]
                self._vveh[1].render(mgl.TRIANGLES, first=first, vertices=count)
            buf = self._fbo_sil.read(viewport=vp, components=1, dtype="i4", alignment=1)
            ids = np.frombuffer(buf, np.int32).reshape(r1 - r0, c1 - c0)[::-1]
            counts += np.bincount(ids.ravel(), minlength=n + 1)[1 : n + 1]
            for j in layer:
                rr, cc = np.nonzero(
                    ids[boxes[j, 1] - r0 : boxes[j, 3] - r0, boxes[j, 0] - c0 : boxes[j, 2] - c0]
                    == j + 1
                )
                if len(rr):
                    tight[j] = (
                        boxes[j, 0] + cc.min(),
                        boxes[j, 1] + rr.min(),
                        boxes[j, 0] + cc.max() + 1,
                        boxes[j, 1] + rr.max() + 1,
                    )
        self.ctx.enable(mgl.DEPTH_TEST)
        return counts, tight

    def release(self) -> None:
        """Free this renderer's GL objects, and the context if the renderer created it."""
        if self._owns_ctx:
            self.ctx.release()
            return
        for fbo in (self._fbo_ms, self._fbo_rgb, self._fbo_id, self._fbo_sil):
            for att in (*fbo.color_attachments, fbo.depth_attachment):
                if att is not None:
                    att.release()
            fbo.release()
        for vaos, _, _ in self._static:
            for vao in vaos:
                vao.release()
        if self._vbuf is not None:
            for vao in self._vveh:
                vao.release()
            self._vbuf.release()
        self._prog_color.release()
        self._prog_id.release()


TILE_M = 40.0


def _tiled(data: np.ndarray, tile_m: float = TILE_M):
    """Sort a triangle list (3T, 11) by ground tile of its triangles' centroids.

    Returns the sorted rows and a tile table: (first vertex, vertex count, lo (3,),
    hi (3,)) arrays, one row per non-empty tile, lo/hi the tile's bounding box in the
    CARLA world frame. Triangles larger than a tile (the grass plane) get their own
    always-tested tile; culling whole tiles never changes which pixels are drawn.
    """
    tri = data[:, :3].reshape(-1, 3, 3).astype(np.float64)
    c = tri.mean(axis=1)
    key = np.floor(c[:, :2] / tile_m).astype(np.int64)
    big = (np.ptp(tri[:, :, :2], axis=1) > tile_m).any(axis=1)
    key[big] = np.iinfo(np.int64).min // 4 + np.arange(big.sum())[:, None]
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    tri_sorted = inv[order]
    rows = (order[:, None] * 3 + np.arange(3)).ravel()
    data = np.ascontiguousarray(data[rows])
    starts = np.flatnonzero(np.r_[True, tri_sorted[1:] != tri_sorted[:-1]])
    counts = np.diff(np.r_[starts, len(tri_sorted)])
    pts = tri[order]
    lo = np.minimum.reduceat(pts.min(axis=1), starts)
    hi = np.maximum.reduceat(pts.max(axis=1), starts)
    return data, (starts * 3, counts * 3, lo, hi)


def _visible_runs(tiles, mvp: np.ndarray) -> list[tuple[int, int]]:
    """(first, count) vertex runs of the tiles whose boxes touch the view frustum."""
    first, count, lo, hi = tiles
    corners = np.stack(
        [np.where(np.array(b)[None, :], hi, lo) for b in np.ndindex(2, 2, 2)], axis=1
    )  # (T, 8, 3)
    clip = corners @ mvp[:, :3].T + mvp[:, 3]  # (T, 8, 4)
    w = clip[..., 3]
    out = (
        (clip[..., 0] < -w).all(1)
        | (clip[..., 0] > w).all(1)
        | (clip[..., 1] < -w).all(1)
        | (clip[..., 1] > w).all(1)
        | (w < NEAR_M).all(1)
        | (clip[..., 2] > w).all(1)
    )
    runs: list[tuple[int, int]] = []
    for f, n in zip(first[~out].tolist(), count[~out].tolist(), strict=True):
        if runs and runs[-1][0] + runs[-1][1] == f:
            runs[-1] = (runs[-1][0], runs[-1][1] + n)
        else:
            runs.append((f, n))
    return runs


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]
