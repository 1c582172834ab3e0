"""`Renderer`: dashcam frames of a town with exact per-pixel instance ids and depth.

Camera model (``shared/CARLA_FACTS.md``, RGB camera): pinhole, horizontal FOV,
K = [[f, 0, W/2], [0, f, H/2], [0, 0, 1]] with f = W / (2 tan(FOV/2)); camera axes
(x forward, y right, z up) map to OpenCV's (x right, y down, z forward) as (y, −z, x).
Image coordinates (u, v) are continuous with the image's top-left corner at (0, 0);
pixel (row i, column j) covers u ∈ [j, j+1), v ∈ [i, i+1), so its centre is
(j + 0.5, i + 0.5) and the principal point W/2, H/2 lies on a pixel corner (as in
CARLA/Unreal).

Passes per frame (moderngl on Mesa llvmpipe, headless EGL; see ``dashtraj.render.gl``):

0. shadow map (when the look has sun shadows): depth of the vehicles (their shadow
   casters: ``meshes.shadow_caster_mesh``, without the details that lie on the body),
   buildings and props seen from the sun, orthographic, ``SHADOW_MAP_PX`` square,
   fitted to the view frustum up to ``SHADOW_RANGE_M``.
1. with ``msaa=0``: ONE pass writes colour, instance ids and depth (three
   attachments). With MSAA: colour with ``msaa`` samples, resolved to ``rgb``, then
   ids and depth without multisampling (one sample per pixel centre: exact ids; all
   attachments of a framebuffer share one sample count, and MSAA samples do not sit
   at pixel centres, so ids cannot come from the MSAA pass). Both give the same ids
   and depth, byte for byte.
2. silhouettes (labels only): every vehicle drawn alone (no occluders, no depth test)
   in ONE pass: vehicles whose projected boxes overlap go to different layers, layer
   ``l`` ORs bit ``l`` into a uint32 image (GL logic op), 32 layers per pass, one
   readback. It rasterizes each vehicle with the same viewport and matrix as pass 1,
   so the visible pixels of a vehicle are always a subset of its silhouette pixels.

The colour of pass 1 is shaded by ``dashtraj.render.shaders`` under the renderer's
``LookConfig`` (sun, sky, materials, fog, camera response; one compiled shader variant
per material group and look flags), the sky fills what no geometry covered, and
``dashtraj.render.post`` applies rain, blur and JPEG after readback. The look never
touches ids, depth or labels.

Framebuffer rows are image rows (the projection puts the image top at GL's row 0), so
nothing is flipped on readback. Static tiles and vehicles outside the view frustum
are not drawn; road, kerb and mark polylines are simplified when the meshes are built.
"""

from __future__ import annotations

import functools
import math
import time
import zlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dashtraj.render import shaders
from dashtraj.render.gl import check_samples, create_context, gl_function
from dashtraj.render.look import LookConfig, lighting
from dashtraj.render.meshes import (
    MAT_ASPHALT,
    MAT_CURB,
    MAT_SIDEWALK,
    Mesh,
    scene_meshes,
    vehicle_mesh,
)

NEAR_M = 0.1
FAR_M = 2000.0
SKY_RGB = (0.62, 0.74, 0.88)  # the legacy look's flat sky
FRONT_FACE = "ccw"  # meshes wind CCW seen from outside (image rows run along GL's +y)
NOISE_PX = 1024  # side of the tileable noise texture of the procedural materials
SKY_MARGIN = 0.03  # sky pass: share of the rows drawn below the horizon (map edge, rounding)
SHADOW_MAP_PX = 512  # side of the sun's shadow map, texels
SHADOW_RANGE_M = 45.0  # shadows are drawn this far along the optical axis
SHADOW_CASTER_REACH_M = 60.0  # casters up to this far toward the sun from the shadowed area
SHADOW_SNAP_M = 4.0  # the shadow map's box snaps outward to this grid (in the sun's frame)


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
    """OpenCV camera frame → GL clip space; clip w = z_cam, NDC y = −1 at the image top.

    GL's window row 0 is then the image's top row: framebuffers read back in image
    order, with no flip."""
    fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    a = (FAR_M + NEAR_M) / (FAR_M - NEAR_M)
    b = -2.0 * FAR_M * NEAR_M / (FAR_M - NEAR_M)
    return np.array(
        [
            [2 * fx / width, 0.0, 2 * cx / width - 1.0, 0.0],
            [0.0, 2 * fy / height, 2 * cy / height - 1.0, 0.0],
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
        depth: (H, W) float32 metres along the optical axis (inf = sky); None when
            rendered with ``depth=False``.
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


def place(x, y, z, c, s, p: np.ndarray) -> tuple:
    """World coordinates of vehicle-frame points: ``x + c·px − s·py``, ``y + s·px + c·py``,
    ``z + pz`` for points ``p`` (..., 3) of a vehicle at (x, y, z) whose yaw has cosine ``c``
    and sine ``s`` (scalars, or arrays broadcast against ``p[..., 0]``). The one placement of
    every vehicle-frame mesh the renderer draws (meshes, shadow casters, contact shadows)
    and of the labels' vertices, so all of them agree to the bit."""
    px, py = p[..., 0], p[..., 1]
    return x + c * px - s * py, y + s * px + c * py, z + p[..., 2]


def vehicle_world_positions(v: VehicleInstance, mesh: Mesh) -> np.ndarray:
    """(N, 3) mesh vertices of vehicle ``v`` in the CARLA world frame, metres."""
    c, s = math.cos(math.radians(v.yaw_deg)), math.sin(math.radians(v.yaw_deg))
    return np.column_stack(place(v.x, v.y, v.z, c, s, mesh.positions.astype(np.float64)))


class Renderer:
    """Headless CPU renderer of one map.

    Args:
        road_map: a ``dashtraj.roads.RoadMap``; its static meshes are built once.
        width, height: image size, pixels.
        fov_deg: horizontal field of view, degrees.
        msaa: samples of the colour pass (0 or 1 = none). With 0, colour, ids and depth
            are drawn in one pass (three attachments); with MSAA, colour has its own
            pass, since ids need one sample at each pixel centre.
        seed: building placement seed.
        ctx: an existing moderngl context to share; None creates a headless EGL one.
        threads: llvmpipe threads for a new context (see ``dashtraj.render.gl``).
        look: a ``dashtraj.render.look.LookConfig`` (weather, materials, camera);
            None = ``LookConfig()``, clear daytime. Change it with ``set_look``: it
            changes pixels, never labels, ids or depth.
        clutter: draw the street clutter (``dashtraj.render.clutter``: never labelled).

    Example:
        >>> r = Renderer(m, 640, 360)  # doctest: +SKIP
        >>> f = r.render((0, 0, 1.5, 0, 0, 0), [(1, ident, 15, 0, 0, 0)])  # doctest: +SKIP
        >>> f.labels[0].detection_class  # doctest: +SKIP
        'car_back'
    """

    #: silhouette pass: "bits" (all vehicles in one pass, OR-ed bit masks) or "layers"
    #: (the reference: one pass and readback per layer of non-overlapping vehicles)
    silhouette_mode = "bits"
    #: dark contact shadows on the road under the vehicles (colour only, never labels)
    contact_shadows = True
    #: per-pass CPU seconds, summed over the frames drawn while it is a dict (the pass
    #: table of ``bench/bench_render.py``): every pass then ends with ``ctx.finish()``, so
    #: the work llvmpipe defers counts toward the pass that queued it. None: no fences.
    pass_times: dict | None = None

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
        look: LookConfig | None = None,
        clutter: bool = True,
    ):
        import moderngl

        # the noise texture (0.5 s of numpy FFTs and sorts, which release the GIL) is made
        # in a thread while the context, the shaders and the scene's meshes are built
        noise = _in_thread(noise_texture, NOISE_PX)
        self.road_map = road_map
        self.width, self.height = int(width), int(height)
        self.fov_deg = float(fov_deg)
        self.msaa = int(msaa) if msaa and msaa > 1 else 0
        self.k = intrinsics(self.width, self.height, self.fov_deg)
        self._proj = _gl_projection(self.k, self.width, self.height)
        self._owns_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_context(threads)
        check_samples(self.ctx, self.msaa)
        self._make_current()  # a given context may not be the current one
        ctx = self.ctx
        vs = shaders.VS
        # the same vertex shader in every pass: identical positions, so the pixels of a
        # vehicle in the frame are always a subset of its silhouette's. The colour passes
        # (0: colour only, 2: colour + id + depth) use one compiled variant per material
        # group and look flags (``_colour_prog``); 1: id + depth, 3: silhouettes, 4: the
        # sun's shadow map
        self._prog_id = ctx.program(vertex_shader=vs, fragment_shader=shaders.FS_ID)
        self._prog_sil = ctx.program(vertex_shader=vs, fragment_shader=shaders.FS_SIL)
        self._prog_depth = ctx.program(vertex_shader=vs, fragment_shader=shaders.FS_DEPTH)
        self._prog_caster = ctx.program(vertex_shader=shaders.VS_CASTER,
                                        fragment_shader=shaders.FS_DEPTH)
        self._progs = (self._prog_id, self._prog_sil, self._prog_depth, self._prog_caster)
        # (which, group, flags) -> program, shared by the renderers of one context (each
        # variant is compiled and JIT-ed once per context); ``prog.extra`` holds the token
        # of the renderer whose look its uniforms hold
        self._variants: dict[tuple, Any] = _shared_programs(ctx)
        self._token = object()
        self._cvaos: dict[tuple, Any] = {}  # (which, group, flags, buffer id) -> vao
        self._uniforms: dict[str, Any] = {}
        self._flags: tuple = ()
        self._sky_buf = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], "f4").tobytes())
        self._noise = ctx.texture((NOISE_PX, NOISE_PX), 4, noise().tobytes())
        self._noise.build_mipmaps()
        self._noise.repeat_x = self._noise.repeat_y = True
        self._noise.filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
        self._shadow_tex = ctx.depth_texture((SHADOW_MAP_PX, SHADOW_MAP_PX))
        self._shadow_tex.compare_func = ""  # read as depth values (nearest texel) + compare
        self._shadow_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._shadow_tex.repeat_x = self._shadow_tex.repeat_y = False
        self._fbo_shadow = ctx.framebuffer(depth_attachment=self._shadow_tex)
        # the static casters' depth for the last light box, copied into the shadow map
        # while the box stays the same (``_shadow_pass``; needs glCopyImageSubData, GL 4.3)
        self._static_shadow = None
        self._static_shadow_key = None
        if ctx.version_code >= 430:
            tex = ctx.depth_texture((SHADOW_MAP_PX, SHADOW_MAP_PX))
            self._static_shadow = (tex, ctx.framebuffer(depth_attachment=tex))
        size = (self.width, self.height)
        self._fbos = []
        if self.msaa:
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
            self._fbos += [self._fbo_ms, self._fbo_rgb, self._fbo_id]
        else:
            self._fbo_all = ctx.framebuffer(
                color_attachments=[
                    ctx.renderbuffer(size, 4),
                    ctx.renderbuffer(size, 1, dtype="i4"),
                    ctx.renderbuffer(size, 1, dtype="f4"),
                ],
                depth_attachment=ctx.depth_renderbuffer(size),
            )
            self._fbos.append(self._fbo_all)
        self._fbo_sil = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 1, dtype="i4")])
        self._fbo_bits = ctx.framebuffer(color_attachments=[ctx.renderbuffer(size, 1, dtype="u4")])
        self._fbos += [self._fbo_sil, self._fbo_bits]
        self._logic_op = None
        scene = scene_meshes(road_map, seed, clutter)
        self._static = []
        self._casters = []  # indices into _static of the groups that cast shadows
        # drawn after the vehicles, near to far, so hidden fragments fail the depth test early
        props = scene.props if scene.props is not None else Mesh.concat([])
        code = scene.ground.colors[::3, 3].round().astype(int)  # material per triangle
        ground = {
            "asphalt": code == MAT_ASPHALT,
            "sidewalk": (code == MAT_SIDEWALK) | (code == MAT_CURB),
        }
        ground["grass"] = ~(ground["asphalt"] | ground["sidewalk"])
        groups = [(props, "props", False, True), (scene.buildings, "facade", False, True)]
        groups += [(_subset(scene.ground, ground[g]), g, False, False) for g in ground]
        groups.append((scene.marks, "mark", True, False))
        for mesh, group, offset, caster in groups:
            if mesh.n_vertices:
                data, tiles = _tiled(mesh.interleaved(0.0))
                buf = ctx.buffer(data.tobytes())
                if caster:
                    self._casters.append(len(self._static))
                self._static.append((self._vaos(buf), offset, tiles, group, buf))
        # corners of every static tile's box, all groups in one array: one matrix product
        # per frame and view culls them all (``_static_runs``)
        n_tiles = [len(e[2][0]) for e in self._static]
        self._tile_corners = (np.concatenate([_box_corners(e[2][2], e[2][3]) for e in self._static])
                              if self._static else np.zeros((0, 8, 3)))
        self._tile_split = np.cumsum(n_tiles)[:-1]
        self._groups = sorted({e[3] for e in self._static} | {"vehicle"})
        self._vbuf = None
        self._vbuf_bytes = 0
        self._ibuf = None  # the vehicles' triangle-list indices (``_upload_indices``)
        self._ibuf_bytes = 0
        self._ikey = None
        self._icache = None
        self._sbuf = None  # contact shadows under the vehicles (colour passes only, id 0)
        self._sbuf_bytes = 0
        # the vehicles' shadow casters: caster mesh key -> (mesh buffer, instance buffer,
        # its capacity in instances, vao), and the (8, 3) box corners per key
        self._caster_draws: dict[tuple, list] = {}
        self._caster_boxes: dict[tuple, np.ndarray] = {}
        self._shadow_rows: dict[tuple, np.ndarray] = {}
        self._vdata: dict[int, tuple[Mesh, np.ndarray, np.ndarray]] = {}
        self._moderngl = moderngl
        self.set_look(look if look is not None else LookConfig())

    # ------------------------------------------------------------------ GL plumbing
    def _lap(self, name: str | None) -> None:
        """Charge the CPU time since the last lap to pass ``name`` of ``pass_times``
        (None: start the clock); does nothing while ``pass_times`` is None."""
        if self.pass_times is None:
            return
        self.ctx.finish()
        now = time.process_time()
        if name is not None:
            self.pass_times[name] = self.pass_times.get(name, 0.0) + now - self._lap_t
        self._lap_t = now

    def _vaos(self, buf, ibuf=None):
        # attributes a program does not use are optimised away: skip their bytes
        ctx = self.ctx
        kw = {} if ibuf is None else {"index_buffer": ibuf, "index_element_size": 4}
        return {
            1: ctx.vertex_array(self._prog_id, [(buf, "3f 28x 1i", "in_pos", "in_id")], **kw),
            3: ctx.vertex_array(self._prog_sil, [(buf, "3f 32x", "in_pos")], **kw),
            4: ctx.vertex_array(self._prog_depth, [(buf, "3f 32x", "in_pos")], **kw),
        }

    def _colour_prog(self, which: int, group: str):
        """The compiled colour program of pass ``which`` (0 or 2, or "sky") for a material
        group under the current look's flags (compiled once, on first use)."""
        key = (which, group, self._flags)
        prog = self._variants.get(key)
        if prog is None:
            legacy, shadows, textures, noise, clouds, wet = self._flags
            if which == "sky":
                src = shaders.variant(shaders.SKY_FS, None, legacy, False, textures, noise,
                                      clouds)
                prog = self.ctx.program(vertex_shader=shaders.SKY_VS, fragment_shader=src)
            else:
                src = shaders.variant(shaders.FS_COLOR if which == 0 else shaders.FS_ALL,
                                      group, legacy, shadows, textures, noise, wet=wet)
                prog = self.ctx.program(vertex_shader=shaders.VS, fragment_shader=src)
            for name, unit in (("noise_tex", 1), ("shadow_map", 2)):
                if name in prog:
                    prog[name].value = unit
            self._variants[key] = prog
            prog.extra = None
        if prog.extra is not self._token:  # last used by another renderer (or new)
            self._set_uniforms(prog, self._uniforms)
            prog.extra = self._token
        return prog

    def _colour_vao(self, which, group: str, buf):
        key = (which, group, self._flags, buf.glo)
        vao = self._cvaos.get(key)
        if vao is None:
            prog = self._colour_prog(which, group)
            if which == "sky":
                vao = self.ctx.vertex_array(prog, [(buf, "2f", "in_pos")])
            else:
                # attributes a variant does not use are optimised away: skip their bytes
                layout = [("in_pos", "3f", "12x"), ("in_normal", "3f", "12x"),
                          ("in_color", "4f", "16x"), ("in_id", "1i", "4x")]
                fmt, names = [], []
                for name, used, skipped in layout:
                    if name in prog:
                        fmt.append(used)
                        names.append(name)
                    else:
                        fmt.append(skipped)
                kw = ({"index_buffer": self._ibuf, "index_element_size": 4}
                      if buf is self._vbuf and self._ibuf is not None else {})
                vao = self.ctx.vertex_array(prog, [(buf, " ".join(fmt), *names)], **kw)
            self._cvaos[key] = vao
        return vao

    def _current_colour_progs(self):
        return [p for k, p in self._variants.items() if k[2] == self._flags]

    @staticmethod
    def _set_uniforms(prog, values: dict) -> None:
        for name, v in values.items():
            if name in prog:
                if isinstance(v, bytes):
                    prog[name].write(v)
                else:
                    prog[name].value = v

    # ------------------------------------------------------------------ look
    def set_look(self, look: LookConfig) -> None:
        """Use ``look`` (weather, materials, camera) for the next frames. Cheap (uniforms
        only); changes pixels, never labels, ids or depth."""
        if not isinstance(look, LookConfig):
            raise TypeError(f"look must be a LookConfig, got {type(look).__name__}")
        self._make_current()
        self.look = look
        lt = lighting(look)
        mat, cam = look.materials, look.camera
        self._shadows_on = bool(mat.shadows and not look.legacy and lt.shadow_strength > 0.0
                                and look.weather.sun_altitude_angle > 0.0)
        self._flags = (bool(look.legacy), self._shadows_on, bool(mat.textures) and not look.legacy,
                       cam.noise_stddev > 0 and not look.legacy,
                       lt.cloud_cover > 0.02 and not look.legacy,
                       (lt.wetness > 0 or lt.deposits > 0) and not look.legacy)
        values = {
            "sun_dir": lt.sun_dir, "sun_rgb": lt.sun_rgb, "amb_sky": lt.ambient_sky,
            "amb_ground": lt.ambient_ground, "sky_zen": lt.sky_zenith, "sky_hor": lt.sky_horizon,
            "fog_rgb": lt.fog_rgb, "fog_sigma": lt.fog_sigma, "fog_start": lt.fog_start,
            "cloud": lt.cloud_cover, "wb": lt.white_balance,
            "gamma_fit": gamma_fit(cam.gamma),
            **_vignette_uniforms(cam.lens_circle_multiplier, cam.lens_circle_falloff,
                                 1.0 + (self.height / self.width) ** 2),
            "noise_std": float(cam.noise_stddev), "img_size": (self.width, self.height),
            "tex_off": mat.texture_offset, "tex_scale": max(float(mat.texture_scale), 1e-3),
            "shadow_strength": lt.shadow_strength, "wetness": lt.wetness,
            "deposits": lt.deposits, "asphalt_rgb": mat.asphalt_rgb,
            "sidewalk_rgb": mat.sidewalk_rgb, "grass_rgb": mat.grass_rgb,
            "facade_tint": mat.facade_tint, "mark_wear": float(mat.mark_wear),
            "foliage_tint": mat.foliage_tint, "prop_tint": mat.prop_tint,
            "road_wear": float(mat.road_wear),
        }
        values = {k: (tuple(float(x) for x in v) if np.ndim(v) else v) for k, v in values.items()}
        self._uniforms.update(values)
        self._lighting = lt
        for prog in self._current_colour_progs():
            if prog.extra is self._token:
                self._set_uniforms(prog, values)

    def _frame_uniforms(self, pose, vs) -> None:
        """Per-frame uniforms (camera position, sky rays, noise seed) and the shadow pass."""
        m = world_to_opencv(pose)
        pix_to_world = m[:3, :3].T @ np.linalg.inv(self.k)
        seed = float(zlib.crc32(np.array([*pose, self.look.seed], np.float64).tobytes()) % 9973)
        per_frame = {"cam_pos": tuple(float(c) for c in pose[:3]), "seed": seed,
                     "pix_to_world": pix_to_world.T.astype("f4").tobytes()}
        per_frame["light_mvp"] = (self._shadow_pass(pose, vs) if self._shadows_on
                                  else np.eye(4, dtype="f4").tobytes())
        self._uniforms.update(per_frame)
        self._noise.use(1)
        progs = [self._colour_prog("sky", "sky")]
        for g in self._groups:
            progs.append(self._colour_prog(2 if not self.msaa else 0, g))
        for prog in progs:
            self._set_uniforms(prog, per_frame)

    def light_matrix(self, pose) -> np.ndarray:
        """(4, 4) world → clip matrix of the sun's orthographic shadow map: it covers the
        camera's view frustum up to ``SHADOW_RANGE_M`` and the casters up to
        ``SHADOW_CASTER_REACH_M`` toward the sun, in a box snapped outward to
        ``SHADOW_SNAP_M`` in the sun's frame."""
        sun = self._lighting.sun_dir
        k, w, h = self.k, self.width, self.height
        uv = np.array([[0, 0], [w, 0], [0, h], [w, h]], float)
        rays = np.column_stack([(uv[:, 0] - k[0, 2]) / k[0, 0], (uv[:, 1] - k[1, 2]) / k[1, 1],
                                np.ones(4)])
        pts = np.concatenate([rays * NEAR_M, rays * SHADOW_RANGE_M])
        m = world_to_opencv(pose)
        world = (pts - m[:3, 3]) @ m[:3, :3]  # inverse of a rigid transform
        f = -sun
        up = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
        r = np.cross(f, up)
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        rot = np.stack([r, u, f])
        lp = world @ rot.T
        lo, hi = lp.min(axis=0), lp.max(axis=0)
        lo[2] -= SHADOW_CASTER_REACH_M
        hi[2] += 5.0
        # snapped outward to a grid: nearby poses share the box (and the static casters'
        # cached depth, ``_shadow_pass``), and the box depends on this pose alone
        lo = np.floor(lo / SHADOW_SNAP_M) * SHADOW_SNAP_M
        hi = np.ceil(hi / SHADOW_SNAP_M) * SHADOW_SNAP_M
        scale = 2.0 / (hi - lo)
        out = np.eye(4)
        out[:3, :3] = rot * scale[:, None]
        out[:3, 3] = -(hi + lo) / (hi - lo)
        return out

    def _shadow_pass(self, pose, vs) -> bytes:
        """Draw the sun's shadow map (pass 0): the static caster groups by tile, then the
        vehicles whose boxes touch the light's frustum, as their shadow casters
        (``meshes.shadow_caster_mesh``). Returns the light matrix (column-major float32
        bytes).

        The static casters' depth is drawn into a cache once per light box (the box is
        snapped, so consecutive frames usually share it) and copied into the map: the
        same texels as drawing them every frame, since nothing else about them changes."""
        mgl = self._moderngl
        self._lap("scene setup (vehicles, culling, projection)")
        lm = self.light_matrix(pose)
        lmb = lm.T.astype("f4").tobytes()
        ctx = self.ctx
        ctx.enable(mgl.DEPTH_TEST)
        ctx.enable(mgl.CULL_FACE)  # closed meshes: the faces toward the sun suffice
        ctx.front_face = "ccw"
        cache = self._static_shadow if self._casters else None
        if cache is None:
            self._fbo_shadow.use()
            self._fbo_shadow.clear(depth=1.0)
            self._draw_static_casters(lm, lmb)
        else:
            if self._static_shadow_key != lmb:
                cache[1].use()
                cache[1].clear(depth=1.0)
                self._draw_static_casters(lm, lmb)
                self._static_shadow_key = lmb
            import ctypes

            args = [ctypes.c_uint, ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                    ctypes.c_int]
            copy = gl_function("glCopyImageSubData", *args, *args, ctypes.c_int, ctypes.c_int,
                               ctypes.c_int)
            tex_2d = 0x0DE1
            copy(cache[0].glo, tex_2d, 0, 0, 0, 0, self._shadow_tex.glo, tex_2d, 0, 0, 0, 0,
                 SHADOW_MAP_PX, SHADOW_MAP_PX, 1)
            self._fbo_shadow.use()
        if len(vs):
            self._draw_casters(vs, lm)
        self._shadow_tex.use(2)
        self._lap("shadow map")
        return lmb

    def _draw_static_casters(self, lm: np.ndarray, lmb: bytes) -> None:
        """Draw the static caster groups' tiles in the light's frustum into the bound
        depth framebuffer."""
        mgl = self._moderngl
        self._prog_depth["mvp"].write(lmb)
        runs = self._static_runs(lm)
        for i in self._casters:
            vaos = self._static[i][0]
            for first, count in runs[i]:
                vaos[4].render(mgl.TRIANGLES, first=first, vertices=count)

    def _draw_sky(self, pose) -> None:
        """Fill the pixels no geometry covered (depth still 1) with the sky, in the rows
        above ``SKY_MARGIN`` × H below the lowest point of the horizon (beneath it the
        ground plane covers every pixel)."""
        mgl = self._moderngl
        ctx = self.ctx
        rows = self._sky_rows(pose)
        if rows <= 0:
            return
        ctx.depth_func = "<="
        ctx.depth_mask = False
        ctx.disable(mgl.CULL_FACE)
        ctx.scissor = (0, 0, self.width, rows)
        self._colour_vao("sky", "sky", self._sky_buf).render(mgl.TRIANGLES)
        ctx.scissor = None
        ctx.depth_func = "<"
        ctx.depth_mask = True
        ctx.enable(mgl.CULL_FACE)

    def _sky_rows(self, pose) -> int:
        """Image rows from the top that can show sky: up to the lowest row where a ray
        through the left or right image edge points above the horizon (ray z is linear
        in the pixel coordinates), plus a margin of ``SKY_MARGIN`` × H; 0 when the
        camera sees no sky."""
        m = world_to_opencv(pose)
        a = m[:3, :3].T @ np.linalg.inv(self.k)  # pixel (u, v, 1) -> world ray
        zr = a[2]  # ray z = zr[0] u + zr[1] v + zr[2]
        h = self.height
        best = -1.0
        for u in (0.0, float(self.width)):
            c = zr[0] * u + zr[2]
            if abs(zr[1]) < 1e-12:
                best = max(best, h if c > 0 else -1.0)
                continue
            v0 = -c / zr[1]  # z = 0 on this edge
            best = max(best, v0 if zr[1] < 0 else (h if v0 < h else -1.0))
        if best < 0:
            return 0
        return int(min(h, math.ceil(best + SKY_MARGIN * h)))

    def _post(self, rgb: np.ndarray, pose) -> np.ndarray:
        from dashtraj.render.post import camera_post

        return camera_post(rgb, self.look, pose)

    def _upload_vehicles(self, data: np.ndarray):
        nbytes = data.nbytes
        if self._vbuf is None or nbytes > self._vbuf_bytes:
            cap = max(nbytes, 1 << 16)
            cap = 1 << (cap - 1).bit_length()
            if self._vbuf is not None:
                self._release_vehicle_vaos()
                self._vbuf.release()
            self._vbuf = self.ctx.buffer(reserve=cap, dynamic=True)
            self._vbuf_bytes = cap
            self._vveh = self._vaos(self._vbuf, self._ibuf)
        if nbytes:
            self._vbuf.write(data)

    def _upload_indices(self, rows, starts):
        """Write the vehicles' triangle-list indices (colour/id passes, then silhouettes)
        into the index buffer; returns the colour indices and the (first index, count)
        ranges of each vehicle in both halves."""
        key = tuple(id(r[0]) for r in rows)
        if key != self._ikey:
            tri, sil = _stacked_rows(rows, 2, starts), _stacked_rows(rows, 3, starts)
            data = np.concatenate([tri, sil]).astype(np.uint32)
            if self._ibuf is None or data.nbytes > self._ibuf_bytes:
                cap = 1 << (max(data.nbytes, 1 << 15) - 1).bit_length()
                self._release_vehicle_vaos()
                if self._ibuf is not None:
                    self._ibuf.release()
                self._ibuf = self.ctx.buffer(reserve=cap, dynamic=True)
                self._ibuf_bytes = cap
                if self._vbuf is not None:
                    self._vveh = self._vaos(self._vbuf, self._ibuf)
            self._ibuf.write(data)
            tc = np.array([len(r[2]) for r in rows], np.int64)
            ts = np.concatenate([[0], np.cumsum(tc)[:-1]])
            ranges = list(zip(ts.tolist(), tc.tolist(), strict=True))
            sil_ranges = [(f + len(tri), c) for f, c in ranges]
            self._ikey = key
            # the meshes stay referenced while their ids key the cache (no id reuse)
            self._icache = (tri, ranges, sil_ranges, [r[0] for r in rows])
        return self._icache[:3]

    def _release_vehicle_vaos(self) -> None:
        if self._vbuf is not None:
            for vao in self._vveh.values():
                vao.release()
            for key in [k for k in self._cvaos if k[3] == self._vbuf.glo]:
                self._cvaos.pop(key).release()

    def _draw_casters(self, vs, lm: np.ndarray) -> None:
        """Draw the shadow casters (``meshes.shadow_caster_mesh``) of the vehicles ``vs``
        whose caster boxes touch the frustum of the light matrix ``lm``: one instanced
        draw per caster mesh (``shaders.VS_CASTER``)."""
        from dashtraj.render.meshes import _params, shadow_caster_mesh

        mgl = self._moderngl
        keys = [_params(v.model) for v in vs]
        for k, v in zip(keys, vs, strict=True):
            if k not in self._caster_boxes:
                p = shadow_caster_mesh(v.model).positions.astype(np.float64)
                self._caster_boxes[k] = _box_corners(p.min(axis=0)[None], p.max(axis=0)[None])[0]
        yaw = np.radians([v.yaw_deg for v in vs])
        cs = np.column_stack([np.cos(yaw), np.sin(yaw)])
        origin = np.array([(v.x, v.y, v.z) for v in vs])
        local = np.stack([self._caster_boxes[k] for k in keys])  # (N, 8, 3)
        corners = np.stack(place(origin[:, None, 0], origin[:, None, 1], origin[:, None, 2],
                                 cs[:, None, 0], cs[:, None, 1], local), axis=-1)
        inside = ~_corners_outside(corners, lm)
        groups: dict[tuple, list[int]] = {}
        for i in np.flatnonzero(inside):
            groups.setdefault(keys[i], []).append(i)
        self._prog_caster["mvp"].write(lm.T.astype("f4").tobytes())
        inst = np.column_stack([origin, cs]).astype("f4")
        for k, idx in groups.items():
            d = self._caster_draws.get(k)
            if d is None or d[2] < len(idx):
                cap = max(64, 1 << (len(idx) - 1).bit_length())
                if d is None:
                    pos = shadow_caster_mesh(vs[idx[0]].model).positions
                    mesh_buf = self.ctx.buffer(np.ascontiguousarray(pos, "f4").tobytes())
                else:
                    mesh_buf = d[0]
                    d[3].release()
                    d[1].release()
                inst_buf = self.ctx.buffer(reserve=cap * 20, dynamic=True)
                vao = self.ctx.vertex_array(self._prog_caster, [
                    (mesh_buf, "3f", "in_pos"), (inst_buf, "3f 2f/i", "in_origin", "in_yaw")])
                d = self._caster_draws[k] = [mesh_buf, inst_buf, cap, vao]
            d[1].write(inst[idx].tobytes())
            d[3].render(mgl.TRIANGLES, instances=len(idx))

    def _upload_contact_shadows(self, vs, drawn) -> int:
        """Write the contact shadows of the drawn vehicles (``vehicle_shapes.
        contact_shadow_mesh``, instance id 0) into their buffer; returns the vertex count."""
        if not self.contact_shadows or self.look.legacy:
            return 0
        from dashtraj.render.vehicle_shapes import contact_shadow_mesh

        rows, poses = [], []
        for v in (vs[i] for i in np.flatnonzero(drawn)):
            m = v.model
            key = (float(m.length_m), float(m.width_m), str(getattr(m, "body_type", "sedan")))
            r = self._shadow_rows.get(key)
            if r is None:
                r = self._shadow_rows[key] = contact_shadow_mesh(*key).interleaved(0.0)
            rows.append(r)
            poses.append((v.x, v.y, v.z, math.radians(v.yaw_deg), len(r)))
        if not rows:
            return 0
        data = np.concatenate(rows)
        cnt = [p[4] for p in poses]
        c = np.repeat([math.cos(p[3]) for p in poses], cnt)
        s = np.repeat([math.sin(p[3]) for p in poses], cnt)
        data[:, :3] = np.column_stack(place(*(np.repeat([p[j] for p in poses], cnt)
                                              for j in range(3)),
                                            c, s, data[:, :3].astype(np.float64)))
        nbytes = data.nbytes
        if self._sbuf is None or nbytes > self._sbuf_bytes:
            cap = 1 << (max(nbytes, 1 << 15) - 1).bit_length()
            if self._sbuf is not None:
                for key in [k for k in self._cvaos if k[3] == self._sbuf.glo]:
                    self._cvaos.pop(key).release()
                self._sbuf.release()
            self._sbuf = self.ctx.buffer(reserve=cap, dynamic=True)
            self._sbuf_bytes = cap
        self._sbuf.write(data)
        return len(data)

    def _draw_contact_shadows(self, which: int, mvp: bytes, n_vertices: int) -> None:
        """Draw the contact shadows in a colour pass (after the road, pulled toward the
        camera by a polygon offset) into the colour attachment only: ids, depth and the
        depth buffer stay exactly as without them."""
        if not n_vertices or which not in (0, 2):
            return
        import ctypes

        vao = self._colour_vao(which, "asphalt", self._sbuf)
        vao.program["mvp"].write(mvp)
        mask = gl_function("glColorMaski", ctypes.c_uint, *[ctypes.c_ubyte] * 4)
        depth_mask = gl_function("glDepthMask", ctypes.c_ubyte)
        if which == 2:  # colour only: the id and depth attachments keep the scene's values
            mask(1, 0, 0, 0, 0)
            mask(2, 0, 0, 0, 0)
        depth_mask(0)
        self.ctx.polygon_offset = (0.0, -4.0)
        vao.render(self._moderngl.TRIANGLES, first=0, vertices=n_vertices)
        self.ctx.polygon_offset = (0.0, 0.0)
        depth_mask(1)
        if which == 2:
            mask(1, 1, 1, 1, 1)
            mask(2, 1, 1, 1, 1)

    def _draw_scene(self, which: int, mvp: bytes, vehicle_runs, shadow_vertices: int = 0):
        mgl = self._moderngl
        colour = which in (0, 2)

        def vao_of(vaos, group, buf):
            if not colour:
                return vaos[which]
            vao = self._colour_vao(which, group, buf)
            vao.program["mvp"].write(mvp)
            return vao

        if not colour:
            self._progs[0]["mvp"].write(mvp)
        if vehicle_runs:
            vao = vao_of(self._vveh, "vehicle", self._vbuf)
            for first, count in vehicle_runs:
                vao.render(mgl.TRIANGLES, first=first, vertices=count)
        for (vaos, offset, _tiles, group, buf), runs in zip(self._static, self._runs, strict=True):
            if not runs:
                continue
            if offset:
                self.ctx.polygon_offset = (0.0, -2.0)  # units only: no slope term
            vao = vao_of(vaos, group, buf)
            for first, count in runs:
                vao.render(mgl.TRIANGLES, first=first, vertices=count)
            if offset:
                self.ctx.polygon_offset = (0.0, 0.0)
        self._draw_contact_shadows(which, mvp, shadow_vertices)

    def _static_runs(self, mvp: np.ndarray) -> list[list[tuple[int, int]]]:
        """Per static group, the (first, count) vertex runs of its tiles whose boxes touch
        the frustum of ``mvp`` (``_corners_outside``: all groups in one product)."""
        out = np.split(_corners_outside(self._tile_corners, mvp), self._tile_split)
        return [
            _runs(zip(e[2][0][~o].tolist(), e[2][1][~o].tolist(), strict=True))
            for e, o in zip(self._static, out, strict=True)
        ]

    def _mesh_rows(self, v: VehicleInstance) -> tuple:
        """Cached (mesh, (U, 11) float32 unique model-frame rows of its mesh, (3T,) int32
        triangle-list indices into them, (3T,) the same with rows of equal position
        merged (the silhouette pass, positions only), rows of its convex hull's vertices
        (``labels.hull_rows``)) of a vehicle's mesh."""
        from dashtraj.render.labels import hull_rows

        mesh = vehicle_mesh(v.model, v.rgb)
        hit = self._vdata.get(id(mesh))
        if hit is None or hit[0] is not mesh:
            if len(self._vdata) > 1024:
                self._vdata.clear()
            rows, tri = _indexed(mesh.interleaved(0.0))
            _, first, inv = np.unique(rows[:, :3], axis=0, return_index=True, return_inverse=True)
            sil = first[inv.ravel()].astype(np.int32)[tri]
            hit = (mesh, rows, tri, sil, hull_rows(rows[:, :3]))
            self._vdata[id(mesh)] = hit
        return hit

    # ------------------------------------------------------------------ frame
    def mvp(self, camera_pose) -> np.ndarray:
        """(4, 4) world → clip matrix (float64) for a camera pose."""
        return self._proj @ world_to_opencv(camera_pose)

    def render(self, camera_pose, vehicles=(), labels: bool = True, depth: bool = True) -> Frame:
        """Render one frame.

        Args:
            camera_pose: (x, y, z, yaw_deg, pitch_deg, roll_deg) of the camera, CARLA
                world (metres, degrees).
            vehicles: ``VehicleInstance`` objects or tuples (instance_id ≥ 1, identity
                or model, x, y, z, yaw_deg), CARLA world.
            labels: compute per-vehicle labels (``Frame.labels``).
            depth: read back the depth image; False leaves ``Frame.depth`` None.

        Returns:
            a :class:`Frame`.
        """
        from dashtraj.render.labels import compute_labels, vehicle_boxes

        mgl = self._moderngl
        ctx = self.ctx
        self._make_current()
        self._lap(None)
        h, w = self.height, self.width
        vs = as_instances(vehicles)
        n = len(vs)
        pose = tuple(float(c) for c in camera_pose)
        mvp64 = self.mvp(pose)
        rows = [self._mesh_rows(v) for v in vs]
        counts = np.array([len(r[1]) for r in rows], np.int64)
        starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        hull = _stacked_rows(rows, 4, starts) if n else None
        tri = None
        if n:
            tri, ranges, sil_ranges = self._upload_indices(rows, starts)
        else:
            ranges, sil_ranges = [], []
        if n:
            data = np.concatenate([r[1] for r in rows])
            yaw = np.radians([v.yaw_deg for v in vs])
            c = np.repeat(np.cos(yaw), counts)
            s = np.repeat(np.sin(yaw), counts)
            world = np.column_stack(place(np.repeat([v.x for v in vs], counts),
                                          np.repeat([v.y for v in vs], counts),
                                          np.repeat([v.z for v in vs], counts),
                                          c, s, data[:, :3].astype(np.float64)))
            data[:, :3] = world
            nx, ny = data[:, 3].astype(np.float64), data[:, 4].astype(np.float64)
            data[:, 3] = c * nx - s * ny
            data[:, 4] = s * nx + c * ny
            data[:, 10] = np.repeat(np.array([v.instance_id for v in vs], np.int32), counts).view(
                np.float32
            )
            self._upload_vehicles(data)
        else:
            world = np.zeros((0, 3))
        if labels and n:
            proj = vehicle_boxes(self, pose, world, starts, hull, tri)
            drawn = proj.boxes_nonempty()
        else:
            proj = None
            # a vehicle's box is its hull vertices' box
            drawn = (_vehicles_in_frustum(world[hull], np.searchsorted(hull, starts), mvp64)
                     if n else np.zeros(0, bool))
        vruns = _runs([ranges[i] for i in np.flatnonzero(drawn)])
        n_shadow = self._upload_contact_shadows(vs, drawn) if n else 0
        self._runs = self._static_runs(mvp64)
        mvp = mvp64.T.astype("f4").tobytes()  # column-major for GLSL
        self._frame_uniforms(pose, vs)
        self._lap("scene setup (vehicles, culling, projection)")

        ctx.enable(mgl.DEPTH_TEST)
        ctx.disable(mgl.BLEND)
        ctx.enable(mgl.CULL_FACE)
        ctx.front_face = FRONT_FACE
        rgb = np.empty((h, w, 3), np.uint8)
        instance = np.empty((h, w), np.int32)
        dimg = np.empty((h, w), np.float32) if depth else None
        if self.msaa:
            # pass 1: colour (MSAA) -> resolve; pass 2: ids + depth, one sample per pixel
            self._fbo_ms.use()
            self._fbo_ms.clear(*SKY_RGB, 1.0, depth=1.0)
            self._draw_scene(0, mvp, vruns, n_shadow)
            self._lap("colour (MSAA)")
            self._draw_sky(pose)
            self._lap("sky")
            region = None  # without depth, ids are only needed where vehicles can be
            if not depth:
                if proj is None and n:
                    proj = vehicle_boxes(self, pose, world, starts, hull, tri)
                b = proj.boxes[drawn] if n else np.zeros((0, 4), np.int64)
                b = b[(b[:, 2] > b[:, 0]) & (b[:, 3] > b[:, 1])]
                region = (0, 0, 0, 0)
                if len(b):
                    c0, r0 = int(b[:, 0].min()), int(b[:, 1].min())
                    region = (c0, r0, int(b[:, 2].max()) - c0, int(b[:, 3].max()) - r0)
            self._fbo_id.use()
            if region is None:
                self._clear_buffers(False)
                self._draw_scene(1, mvp, vruns)
            elif region[2] and region[3]:
                self._clear_buffers(False, region)  # scissor stays: the rest has no vehicle
                self._draw_scene(1, mvp, vruns)
                ctx.scissor = None
            self._lap("ids + depth")
            ctx.copy_framebuffer(self._fbo_rgb, self._fbo_ms)
            self._fbo_rgb.read_into(rgb, components=3, alignment=1)
            self._lap("readback")
            rgb = self._post(rgb, pose)
            self._lap("camera post (rain, blur, JPEG)")
            fbo, a_id, a_depth = self._fbo_id, 0, 1
            if region is not None:
                instance[:] = 0
                if region[2] and region[3]:
                    c0, r0, rw, rh = region
                    sub = np.empty((rh, rw), np.int32)
                    fbo.read_into(sub, viewport=region, components=1, dtype="i4", alignment=1)
                    instance[r0 : r0 + rh, c0 : c0 + rw] = sub
                frame = Frame(rgb, instance, None, self.k.copy(), pose)
                self._lap("readback")
                if labels:
                    frame.labels = compute_labels(self, frame, vs, proj, sil_ranges, mvp)
                    self._lap("labels (counts, boxes, truncation)")
                return frame
        else:
            # one pass: colour, ids and depth (three attachments)
            fbo = self._fbo_all
            fbo.use()
            self._clear_buffers(True)
            self._draw_scene(2, mvp, vruns, n_shadow)
            self._lap("colour + ids + depth")
            self._draw_sky(pose)
            self._lap("sky")
            fbo.read_into(rgb, components=3, attachment=0, alignment=1)
            self._lap("readback")
            rgb = self._post(rgb, pose)
            self._lap("camera post (rain, blur, JPEG)")
            a_id, a_depth = 1, 2
        fbo.read_into(instance, components=1, attachment=a_id, dtype="i4", alignment=1)
        if dimg is not None:
            fbo.read_into(dimg, components=1, attachment=a_depth, dtype="f4", alignment=1)
        frame = Frame(rgb, instance, dimg, self.k.copy(), pose)
        self._lap("readback")
        if labels:
            frame.labels = compute_labels(self, frame, vs, proj, sil_ranges, mvp)
            self._lap("labels (counts, boxes, truncation)")
        return frame

    def _bitwise_or(self, on: bool) -> None:
        """Enable/disable GL's OR logic op (moderngl exposes no logic op: call GL directly)."""
        import ctypes

        if on:
            gl_function("glEnable", ctypes.c_uint)(0x0BF2)  # GL_COLOR_LOGIC_OP
            gl_function("glLogicOp", ctypes.c_uint)(0x1507)  # GL_OR
        else:
            gl_function("glDisable", ctypes.c_uint)(0x0BF2)

    def _clear_buffers(self, colour: bool, region=None) -> None:
        """Clear the bound framebuffer per attachment: [sky colour,] id 0, depth +inf
        (sky: fragments always have depth ≥ NEAR_M), z 1; in ``region`` if given.

        moderngl clears every attachment with one colour; GL's glClearBuffer* clears
        each draw buffer with its own value."""
        import ctypes

        f4 = ctypes.c_float * 4
        cf = gl_function("glClearBufferfv", ctypes.c_uint, ctypes.c_int, ctypes.c_void_p)
        ci = gl_function("glClearBufferiv", ctypes.c_uint, ctypes.c_int, ctypes.c_void_p)
        gl_color, gl_depth = 0x1800, 0x1801
        if getattr(self, "_clear_args", None) is None:
            self._clear_args = (
                f4(*SKY_RGB, 1.0),
                (ctypes.c_int * 4)(0, 0, 0, 0),
                f4(math.inf, 0, 0, 0),
                f4(1, 0, 0, 0),
            )
        sky, zero_i, inf_f, one = self._clear_args
        self.ctx.scissor = region
        k = 0
        if colour:
            cf(gl_color, 0, sky)
            k = 1
        ci(gl_color, k, zero_i)
        cf(gl_color, k + 1, inf_f)
        cf(gl_depth, 0, one)

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
        self._lap("labels (counts, boxes, truncation)")
        n = len(ranges)
        counts = np.zeros(n, np.int64)
        tight = np.full((n, 4), -1, np.int64)
        bl = np.asarray(boxes).tolist()  # Python ints: cheap to index one by one
        todo = [i for i in range(n) if bl[i][2] > bl[i][0] and bl[i][3] > bl[i][1]]
        # greedy layering: vehicles whose boxes overlap go to different layers
        layers: list[list[int]] = []
        for i in sorted(todo, key=lambda j: (bl[j][0], bl[j][1], j)):
            for layer in layers:
                if not any(_overlap(bl[i], bl[j]) for j in layer):
                    layer.append(i)
                    break
            else:
                layers.append([i])
        if not layers:
            return counts, tight
        if self.silhouette_mode == "layers":
            self._silhouettes_layers(layers, boxes, ranges, mvp, counts, tight)
        else:
            # 32 layers per pass: layer l sets bit l of a uint32 image (logic op OR)
            for k in range(0, len(layers), 32):
                self._silhouettes_bits(layers[k : k + 32], boxes, ranges, mvp, counts, tight)
        self._lap("labels: silhouette pass")
        return counts, tight

    def _silhouettes_bits(self, layers, boxes, ranges, mvp, counts, tight) -> None:
        mgl = self._moderngl
        members = [j for layer in layers for j in layer]
        c0, r0 = int(boxes[members, 0].min()), int(boxes[members, 1].min())
        c1, r1 = int(boxes[members, 2].max()), int(boxes[members, 3].max())
        vp = (c0, r0, c1 - c0, r1 - r0)
        ctx = self.ctx
        ctx.disable(mgl.DEPTH_TEST)
        prog = self._prog_sil
        prog["mvp"].write(mvp)
        fbo = self._fbo_bits
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, viewport=vp)
        self._bitwise_or(True)
        try:
            for b, layer in enumerate(layers):
                prog["bit"].value = 1 << b
                for first, count in _runs([ranges[j] for j in sorted(layer)]):
                    self._vveh[3].render(mgl.TRIANGLES, first=first, vertices=count)
        finally:
            self._bitwise_or(False)
            ctx.enable(mgl.DEPTH_TEST)
        bits = np.empty((r1 - r0, c1 - c0), np.uint32)
        fbo.read_into(bits, viewport=vp, components=1, dtype="u4", alignment=1)
        bl = np.asarray(boxes).tolist()
        for b, layer in enumerate(layers):
            bit = np.uint32(1 << b)
            for j in layer:
                bc0, br0, bc1, br1 = bl[j]
                m = (bits[br0 - r0 : br1 - r0, bc0 - c0 : bc1 - c0] & bit) != 0
                _count_and_box(m, bl[j], j, counts, tight)

    def _silhouettes_layers(self, layers, boxes, ranges, mvp, counts, tight) -> None:
        mgl = self._moderngl
        self.ctx.disable(mgl.DEPTH_TEST)
        self._prog_id["mvp"].write(mvp)
        self._fbo_sil.use()
        for layer in layers:
            c0, r0 = min(boxes[j, 0] for j in layer), min(boxes[j, 1] for j in layer)
            c1, r1 = max(boxes[j, 2] for j in layer), max(boxes[j, 3] for j in layer)
            vp = (int(c0), int(r0), int(c1 - c0), int(r1 - r0))
            self._fbo_sil.clear(0.0, 0.0, 0.0, 0.0, viewport=vp)
            for j in layer:
                first, count = ranges[j]
                self._prog_id["mvp"].write(mvp)
                self._vveh[1].render(mgl.TRIANGLES, first=first, vertices=count)
            buf = self._fbo_sil.read(viewport=vp, components=1, dtype="i4", alignment=1)
            ids = np.frombuffer(buf, np.int32).reshape(r1 - r0, c1 - c0)
            for j in layer:
                sub = ids[boxes[j, 1] - r0 : boxes[j, 3] - r0, boxes[j, 0] - c0 : boxes[j, 2] - c0]
                _count_and_box(sub != 0, boxes[j], j, counts, tight)
        self.ctx.enable(mgl.DEPTH_TEST)

    def _make_current(self) -> None:
        """Make this renderer's context the thread's current one (about 1 µs). GL calls
        go to the current context, which is the last one created or made current: without
        this, a renderer whose context was not the newest drew into another renderer's
        context (stray surfaces and garbage ids in its frames)."""
        self.ctx.__enter__()

    def release(self) -> None:
        """Free this renderer's GL objects, and the context if the renderer created it."""
        self._make_current()
        if self._owns_ctx:
            self.ctx.release()
            return
        for fbo in self._fbos:
            for att in (*fbo.color_attachments, fbo.depth_attachment):
                if att is not None:
                    att.release()
            fbo.release()
        for vao in self._cvaos.values():
            vao.release()
        for vaos, _, _, _, buf in self._static:
            for vao in vaos.values():
                vao.release()
            buf.release()
        if self._vbuf is not None:
            for vao in self._vveh.values():
                vao.release()
            self._vbuf.release()
        if self._ibuf is not None:
            self._ibuf.release()
        if self._sbuf is not None:
            self._sbuf.release()
        for mesh_buf, inst_buf, _, vao in self._caster_draws.values():
            vao.release()
            inst_buf.release()
            mesh_buf.release()
        for p in self._progs:
            p.release()  # the shared colour variants live as long as the context
        self._sky_buf.release()
        self._fbo_shadow.release()
        self._shadow_tex.release()
        if self._static_shadow is not None:
            self._static_shadow[1].release()
            self._static_shadow[0].release()
        self._noise.release()


def _shared_programs(ctx) -> dict:
    """The colour-variant programs of a context (kept in ``ctx.extra``)."""
    store = ctx.extra if isinstance(ctx.extra, dict) else None
    if store is None:
        store = {}
        ctx.extra = store
    return store.setdefault("dashtraj.render.colour_variants", {})


def _subset(mesh: Mesh, tri_mask: np.ndarray) -> Mesh:
    """The triangles of ``mesh`` selected by a (T,) bool mask."""
    rows = np.repeat(np.asarray(tri_mask, bool), 3)
    return Mesh(mesh.positions[rows], mesh.normals[rows], mesh.colors[rows])


def _count_and_box(mask: np.ndarray, box, j: int, counts: np.ndarray, tight: np.ndarray) -> None:
    """Pixel count and tight box (image pixels) of a boolean mask over ``box``."""
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return
    mask = mask[rows[0] : rows[-1] + 1]  # the rows outside hold no pixel
    cols = np.flatnonzero(mask.any(axis=0))
    counts[j] = int(np.count_nonzero(mask))
    tight[j] = (box[0] + cols[0], box[1] + rows[0], box[0] + cols[-1] + 1, box[1] + rows[-1] + 1)


def _indexed(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(U, C) unique rows of a (3T, C) triangle-list array, in order of first use, and
    the (3T,) int32 indices that rebuild it."""
    _, first, inv = np.unique(data, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)  # unique rows in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return np.ascontiguousarray(data[first[order]]), rank[inv.ravel()].astype(np.int32)


def _stacked_rows(rows, field: int, starts: np.ndarray) -> np.ndarray:
    """Row indices ``field`` of each vehicle's cached mesh rows (`Renderer._mesh_rows`),
    offset to where its rows start in the frame's stacked vertices (``starts``) and
    concatenated."""
    return np.concatenate([r[field] + s0 for r, s0 in zip(rows, starts[:-1].tolist(),
                                                          strict=True)])


def _runs(ranges) -> list[tuple[int, int]]:
    """Merge (first, count) ranges in order into contiguous runs."""
    out: list[tuple[int, int]] = []
    for f, c in ranges:
        if out and out[-1][0] + out[-1][1] == f:
            out[-1] = (out[-1][0], out[-1][1] + c)
        else:
            out.append((f, c))
    return out


def _vehicles_in_frustum(world: np.ndarray, starts: np.ndarray, mvp: np.ndarray) -> np.ndarray:
    """(N,) bool: the world box of each vehicle's vertices touches the view frustum."""
    s = starts[:-1]
    lo = np.minimum.reduceat(world, s, axis=0)
    hi = np.maximum.reduceat(world, s, axis=0)
    return ~_boxes_outside(lo, hi, mvp)


TILE_M = 40.0


def _tiled(data: np.ndarray, tile_m: float = TILE_M):
    """Sort a triangle list (3T, 11) by ground tile of its triangles' centroids.

    Returns the sorted rows and a tile table: (first vertex, vertex count, lo (3,),
    hi (3,)) arrays, one row per non-empty tile, lo/hi the tile's bounding box in the
    CARLA world frame. Triangles larger than a tile (the grass plane) get their own
    always-tested tile, drawn after the others; culling whole tiles never changes which
    pixels are drawn.
    """
    tri = data[:, :3].reshape(-1, 3, 3).astype(np.float64)
    c = tri.mean(axis=1)
    key = np.floor(c[:, :2] / tile_m).astype(np.int64)
    big = (np.ptp(tri[:, :, :2], axis=1) > tile_m).any(axis=1)
    # big triangles (the grass plane under everything) sort last: drawn after the road
    # surfaces, most of their samples fail the depth test early
    key[big] = np.iinfo(np.int64).max // 4 + np.arange(big.sum())[:, None]
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


def _boxes_outside(lo: np.ndarray, hi: np.ndarray, mvp: np.ndarray) -> np.ndarray:
    """(T,) bool: the world boxes lo/hi (T, 3) lie wholly outside one frustum plane."""
    return _corners_outside(_box_corners(lo, hi), mvp)


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(T, 8, 3) corners of the world boxes lo/hi (T, 3)."""
    return np.stack(
        [np.where(np.array(b)[None, :], hi, lo) for b in np.ndindex(2, 2, 2)], axis=1
    )


def _corners_outside(corners: np.ndarray, mvp: np.ndarray) -> np.ndarray:
    """(T,) bool: the boxes with corners (T, 8, 3) lie wholly outside one frustum plane."""
    clip = corners @ mvp[:, :3].T + mvp[:, 3]  # (T, 8, 4)
    w = clip[..., 3]
    return (
        (clip[..., 0] < -w).all(1)
        | (clip[..., 0] > w).all(1)
        | (clip[..., 1] < -w).all(1)
        | (clip[..., 1] > w).all(1)
        | (w < NEAR_M).all(1)
        | (clip[..., 2] > w).all(1)
    )


def _vignette_uniforms(multiplier: float, falloff: float, r2_max: float) -> dict:
    a = vignette_fit(float(multiplier), float(falloff), float(r2_max))
    return {"vig_lo": a[:4], "vig_hi": a[4:]}


def _overlap(a, b) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


@functools.lru_cache(maxsize=64)
def gamma_fit(gamma: float) -> tuple[float, float, float, float]:
    """Coefficients (a, b, c, d) with a x + b √x + c x^¼ + d x² ≈ x^(1/gamma) on [0, 1]
    (least squares on 4,001 points; the shader's display encoding: square roots are
    cheap on llvmpipe, pow is not). Max error 0.7 levels of 255 at gamma 2.2, 1.3 at 2.4."""
    x = np.linspace(0.0, 1.0, 4001)
    a = np.column_stack([x, np.sqrt(x), np.sqrt(np.sqrt(x)), x * x])
    coef, *_ = np.linalg.lstsq(a, x ** (1.0 / max(float(gamma), 0.1)), rcond=None)
    return tuple(float(v) for v in coef)


VIGNETTE_DEGREE = 7


@functools.lru_cache(maxsize=64)
def vignette_fit(multiplier: float, falloff: float, r2_max: float) -> tuple[float, ...]:
    """Coefficients a0 … a7 with Σ a_k s^k ≈ 1 / (1 + multiplier · s^(falloff / 2)) for
    s = r² on [0, ``r2_max``] (r: distance from the image centre in half image widths):
    the shader's vignetting as seven multiply-adds instead of a pow (Chebyshev fit on
    4,001 points, in float64). Max error over the randomized ranges (multiplier 0 … 1.5,
    falloff 3 … 6; worst at 1.5 and 3), evaluated in float32: 0.42 levels of 255 at 16:9,
    0.57 at 4:3; 0.011 at the default 0.35 and 5."""
    m, e = max(float(multiplier), 0.0), max(float(falloff), 0.0) / 2.0
    if m == 0.0:
        return (1.0,) + (0.0,) * VIGNETTE_DEGREE
    s = np.linspace(0.0, float(r2_max), 4001)
    fit = np.polynomial.chebyshev.Chebyshev.fit(s, 1.0 / (1.0 + m * s ** e), VIGNETTE_DEGREE)
    return tuple(float(v) for v in fit.convert(kind=np.polynomial.Polynomial).coef)


def _in_thread(fn, *args):
    """Start ``fn(*args)`` in a thread; returns a function that waits for its result (and
    raises its exception)."""
    import threading

    box: list = []

    def run() -> None:
        try:
            box.append((True, fn(*args)))
        except BaseException as exc:  # re-raised by the caller
            box.append((False, exc))

    t = threading.Thread(target=run, name="dashtraj-render-init", daemon=True)
    t.start()

    def result():
        t.join()
        ok, value = box[0]
        if not ok:
            raise value
        return value

    return result


NOISE_FILES_KEPT = 4
"""Noise texture files kept in the cache folder (the most recently used; 4 MB each)."""


@functools.lru_cache(maxsize=2)
def noise_texture(size: int = NOISE_PX, seed: int = 7) -> np.ndarray:
    """`build_noise_texture`, kept per (size, seed) in this process and as a file in the
    cache folder (`dashtraj.cache.cache_root` ``("textures")``, named after the size, the
    seed and dashtraj's code, `dashtraj.cache.code_sha256`): every later process (the
    ``--workers`` of a run, the next run) reads it in milliseconds instead of building it
    (0.5-0.8 s). A file that is not whole is built again. Read-only."""
    import hashlib

    from dashtraj.cache import building, cache_root, code_sha256, prune, touch, write_whole

    name = hashlib.sha256(f"{int(size)}\0{int(seed)}\0{code_sha256()}".encode()).hexdigest()
    path = cache_root("textures") / f"noise-{name[:32]}.npy"

    def read() -> np.ndarray | None:
        try:
            a = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError):
            return None
        if a.shape != (size, size, 4) or a.dtype != np.uint8:
            return None
        touch(path)
        return a

    out = read()
    if out is None:
        with building(path) as writable:
            out = read() if writable else None  # built while we waited
            if out is None:
                out = build_noise_texture(size, seed)
                if writable and write_whole(path, lambda fh: np.save(fh, out)):
                    prune(path.parent, "noise-*.npy", NOISE_FILES_KEPT)
    out.flags.writeable = False
    return out


def build_noise_texture(size: int = NOISE_PX, seed: int = 7) -> np.ndarray:
    """(size, size, 4) uint8 tileable noise, one pattern per channel, each uniform on
    0 … 255 (rank-equalised): R fine grain (≈ 4 texels), G soft blotches (≈ 200 texels),
    B medium (≈ 50 texels), A fractal (clouds, paint wear); built (`noise_texture` caches).
    Band-limited white noise filtered in the Fourier domain, so it tiles. Rank
    equalisation: value v of a channel of n texels gets level ⌊rank(v) · 256 / n⌋, i.e.
    the number of the 255 level boundaries (the values of rank ⌈k · n / 256⌉) that are
    ≤ v: one sort and a binary search instead of an argsort, and real FFTs (0.5 s
    instead of 0.9 s at 1024²; the same bytes as the complex FFTs and argsort ranks that
    they replaced, at 1024² and in the tests)."""
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    r = np.hypot(f[:, None], np.fft.rfftfreq(size)[None, :])  # the real FFT's half plane
    out = np.empty((size, size, 4), np.uint8)
    filters = (
        np.exp(-((r / 0.25) ** 2)),
        np.exp(-((r / 0.005) ** 2)),
        np.exp(-((r / 0.02) ** 2)),
        np.where(r > 0, 1.0 / np.maximum(r, 1.0 / size) ** 1.6, 0.0),
    )
    n = size * size
    first_rank = -(-np.arange(1, 256) * n // 256)  # ⌈k n / 256⌉, k = 1 … 255
    for c, filt in enumerate(filters):
        x = np.fft.irfft2(np.fft.rfft2(rng.standard_normal((size, size))) * filt,
                          s=(size, size))
        bounds = np.sort(x, axis=None)[first_rank]
        out[:, :, c] = np.searchsorted(bounds, x, side="right").astype(np.uint8)
    return out
