"""Triangle meshes for the CPU renderer: the static town scene and parametric vehicles.

A :class:`Mesh` is a flat list of triangles (no index buffer) with one normal and
one colour per vertex, so faces are flat-shaded, and a material code per vertex
(``MAT_*``: the renderer's shader picks textures, specular and reflections by it).
Every mesh is built with numpy, deterministically (buildings and roadside props from
seeded generators).

Frames:
    scene meshes are in the CARLA world frame (metres, x forward/east, y right/south,
    z up; left-handed). Vehicle meshes are in the vehicle frame: x forward, y right,
    z up, origin on the ground at the centre of the vehicle's footprint (CARLA's
    bounding box centre dropped to the ground). Triangle winding is not relied on
    (the renderer does not cull faces); normals point outward, fixed per part.
"""

from __future__ import annotations

import hashlib
import math
import threading
import weakref
import zipfile
from collections import OrderedDict
from dataclasses import astuple, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Protocol

import numpy as np
from scipy.spatial import cKDTree

from dashtraj.roads.types import LaneType
from dashtraj.world.catalog import Trim

# --------------------------------------------------------------------------- colours (linear 0..1)
ASPHALT = (0.20, 0.20, 0.21)
ASPHALT_JUNCTION = (0.21, 0.21, 0.22)
SIDEWALK = (0.55, 0.54, 0.52)
CURB = (0.62, 0.61, 0.59)
GRASS = (0.30, 0.42, 0.22)
MARK_WHITE = (0.92, 0.92, 0.90)
MARK_YELLOW = (0.90, 0.72, 0.12)
GLASS = (0.08, 0.10, 0.13)
TYRE = (0.05, 0.05, 0.05)
HEADLIGHT = (1.00, 0.97, 0.80)
TAILLIGHT = (0.85, 0.05, 0.04)
GRILLE = (0.12, 0.12, 0.12)
RIDER_BODY = (0.15, 0.22, 0.45)
RIDER_HEAD = (0.80, 0.62, 0.50)
FACADES = np.array(
    [
        (0.62, 0.58, 0.52),
        (0.70, 0.66, 0.60),
        (0.55, 0.45, 0.38),
        (0.48, 0.50, 0.54),
        (0.74, 0.72, 0.68),
        (0.60, 0.42, 0.33),
        (0.42, 0.44, 0.47),
        (0.66, 0.60, 0.46),
    ]
)

# material codes (the 4th colour component of every vertex; 1 = emissive keeps the old
# meaning of that component)
MAT_LIT, MAT_LAMP, MAT_ASPHALT, MAT_SIDEWALK, MAT_MARK, MAT_PAINT, MAT_GLASS = 0, 1, 2, 3, 4, 5, 6
MAT_TYRE, MAT_FACADE, MAT_GRASS, MAT_CURB, MAT_FOLIAGE, MAT_METAL, MAT_BARK = (
    7, 8, 9, 10, 11, 12, 13)
BARK = (0.30, 0.22, 0.16)
FOLIAGE = ((0.20, 0.34, 0.12), (0.26, 0.38, 0.14), (0.16, 0.28, 0.12), (0.30, 0.36, 0.16))
POLE = (0.45, 0.46, 0.47)

SIDEWALK_HEIGHT_M = 0.15
MARK_LIFT_M = 0.005  # road marks float this high above the asphalt (tyres: ≥ 1 cm)
BROKEN_ON_M, BROKEN_OFF_M = 3.0, 6.0
GROUND_Z_M = -0.03

_ASPHALT_TYPES = (
    LaneType.Driving
    | LaneType.Bidirectional
    | LaneType.Parking
    | LaneType.Shoulder
    | LaneType.Stop
    | LaneType.Entry
    | LaneType.Exit
    | LaneType.OnRamp
    | LaneType.OffRamp
    | LaneType.Biking
    | LaneType.RoadWorks
    | LaneType.Tram
    | LaneType.Rail
    | LaneType.Restricted
)


@dataclass(frozen=True)
class Mesh:
    """Flat-shaded triangles.

    Attributes:
        positions: (3T, 3) float32, metres (frame stated by the builder).
        normals: (3T, 3) float32 unit normals, same frame.
        colors: (3T, 4) float32: RGB in 0..1 and the material code (``MAT_*``;
            1 = ``MAT_LAMP``, unlit, e.g. lamps).
    """

    positions: np.ndarray
    normals: np.ndarray
    colors: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.positions)

    @staticmethod
    def concat(meshes: list[Mesh]) -> Mesh:
        meshes = [m for m in meshes if m.n_vertices]
        if not meshes:
            z = np.zeros((0, 3), np.float32)
            return Mesh(z, z.copy(), np.zeros((0, 4), np.float32))
        return Mesh(
            *(
                np.concatenate([getattr(m, f) for m in meshes]).astype(np.float32)
                for f in ("positions", "normals", "colors")
            )
        )

    def interleaved(self, ids: np.ndarray | float = 0.0) -> np.ndarray:
        """(3T, 11) float32 rows: position, normal, colour+emissive, id (the GL layout)."""
        idcol = np.broadcast_to(np.asarray(ids, np.float32).reshape(-1, 1), (self.n_vertices, 1))
        return np.hstack([self.positions, self.normals, self.colors, idcol]).astype(np.float32)


# --------------------------------------------------------------------------- primitives
def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays: `numpy.cross`'s products and differences
    in its order (the same bits), without its per-call axis handling."""
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _mesh(tris: np.ndarray, color, emissive: float = 0.0, centre=None, up: bool = False,
          material: int | None = None) -> Mesh:
    """Mesh from (T, 3, 3) triangles; normals face away from ``centre`` (or +z if ``up``).

    ``material`` (``MAT_*``) defaults to ``MAT_LAMP`` when ``emissive`` else ``MAT_LIT``."""
    tris = np.asarray(tris, np.float64).reshape(-1, 3, 3)
    cross = _cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    n = cross / np.where(length > 0, length, 1.0)
    if up:
        n = np.where(n[:, 2:3] < 0, -n, n)
    elif centre is not None:
        out = tris.mean(axis=1) - np.asarray(centre, np.float64)
        n = np.where((n * out).sum(axis=1, keepdims=True) < 0, -n, n)
    # wind every triangle counter-clockwise seen from its normal side (for face culling)
    flip = (cross * n).sum(axis=1) < 0
    tris = tris.copy()
    tris[flip] = tris[flip][:, [0, 2, 1]]
    t = len(tris)
    col = np.asarray(color, np.float64)
    col = np.broadcast_to(col.reshape(-1, 3) if col.ndim > 1 else col, (t, 3))
    code = material if material is not None else (MAT_LAMP if emissive else MAT_LIT)
    rgba = np.concatenate([col, np.full((t, 1), float(code))], axis=1)
    return Mesh(
        tris.reshape(-1, 3).astype(np.float32),
        np.repeat(n, 3, axis=0).astype(np.float32),
        np.repeat(rgba, 3, axis=0).astype(np.float32),
    )


_HEXA_FACES = np.array(
    [[0, 1, 2, 3], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
)


def hexahedron(corners: np.ndarray, color, emissive: float = 0.0,
               material: int | None = None) -> Mesh:
    """A convex six-faced solid from 8 corners (bottom ring then top ring, same order)."""
    c = np.asarray(corners, np.float64).reshape(8, 3)
    q = c[_HEXA_FACES]  # (6, 4, 3)
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return _mesh(tris, color, emissive, centre=c.mean(axis=0), material=material)


def box(lo, hi, color, emissive: float = 0.0, material: int | None = None) -> Mesh:
    """Axis-aligned box between corners ``lo`` and ``hi`` (x, y, z), metres."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    c = np.array(
        [
            [x0, y0, z0],
            [x1, y0, z0],
            [x1, y1, z0],
            [x0, y1, z0],
            [x0, y0, z1],
            [x1, y0, z1],
            [x1, y1, z1],
            [x0, y1, z1],
        ]
    )
    return hexahedron(c, color, emissive, material)


def wheel(cx: float, cy: float, radius: float, width: float, sides: int = 10) -> Mesh:
    """A tyre: a ``sides``-gon prism with its axis along y, centred at (cx, cy, radius)."""
    # a flat edge at the bottom, r (1 - cos(π/sides)) above the ground: no z-fight with the road
    a = np.arange(sides) * (2 * np.pi / sides) + 1.5 * np.pi + np.pi / sides
    ring = np.column_stack([cx + radius * np.cos(a), radius + radius * np.sin(a)])  # x, z
    i, j = np.arange(sides), (np.arange(sides) + 1) % sides
    y0, y1 = cy - width / 2, cy + width / 2

    def p(k, y):
        return np.column_stack([ring[k, 0], np.full(len(k), y), ring[k, 1]])

    side = np.concatenate(
        [np.stack([p(i, y0), p(j, y0), p(j, y1)], 1), np.stack([p(i, y0), p(j, y1), p(i, y1)], 1)]
    )
    c0 = np.tile([[cx, y0, radius]], (sides, 1))
    c1 = np.tile([[cx, y1, radius]], (sides, 1))
    caps = np.concatenate(
        [np.stack([c0, p(i, y0), p(j, y0)], 1), np.stack([c1, p(i, y1), p(j, y1)], 1)]
    )
    return _mesh(np.concatenate([side, caps]), TYRE, centre=(cx, cy, radius), material=MAT_TYRE)


# --------------------------------------------------------------------------- vehicles
class VehicleModelLike(Protocol):
    """The catalog fields the renderer reads (``dashtraj.world.catalog.VehicleModel``)."""

    vehicle_class: str
    body_type: str
    length_m: float
    width_m: float
    height_m: float
    wheelbase_m: float
    wheel_radius_m: float


_PARAMS: dict[int, tuple] = {}  # id(model) -> (model, its _params tuple)


def _params(model) -> tuple:
    """The shape parameters of a model (the key of its meshes), cached per model object
    (models are frozen dataclasses; the cache holds the model, so its id stays its own):
    every vehicle of every frame asks for them."""
    hit = _PARAMS.get(id(model))
    if hit is not None and hit[0] is model:
        return hit[1]
    g = getattr
    p = (
        str(g(model, "body_type", "sedan")),
        float(model.length_m),
        float(model.width_m),
        float(model.height_m),
        float(g(model, "wheelbase_m", 0.6 * model.length_m)),
        float(g(model, "wheel_radius_m", 0.33)),
        float(g(model, "ground_clearance_m", 0.15)),
        float(g(model, "hood_fraction", 0.3)),
        float(g(model, "cabin_start_fraction", 0.3)),
        float(g(model, "cabin_end_fraction", 0.85)),
        float(g(model, "beltline_fraction", 0.55)),
        _trim(g(model, "trim", None)),
    )
    if len(_PARAMS) > 4096:
        _PARAMS.clear()
    _PARAMS[id(model)] = (model, p)
    return p


def _trim(trim) -> tuple:
    """The catalog ``Trim`` as ``vehicle_shapes``' tuple (its defaults when None)."""
    return astuple(trim if trim is not None else Trim())


def vehicle_mesh(model, rgb) -> Mesh:
    """A parametric vehicle in the vehicle frame (x forward, y right, z up, metres).

    Args:
        model: a catalog ``VehicleModel`` (or anything with its attribute names:
            body_type, length_m, width_m, height_m, wheelbase_m, wheel_radius_m, and
            optionally ground_clearance_m, hood_fraction, cabin_start_fraction,
            cabin_end_fraction, beltline_fraction; fractions of the length from the
            front, of the height from the ground).
        rgb: paint colour, 3 ints 0..255.

    Returns:
        a cached :class:`Mesh` (``dashtraj.render.vehicle_shapes``: rounded lofted
        bodies, glass all round, wheel arches, rims, lamps, grille and plates; the front
        carries white head lamps, the back red tail lamps).
    """
    paint = tuple(round(float(c)) for c in rgb)
    return _vehicle_mesh_cached(_params(model), paint)


def _body_mesh(p: tuple, paint: np.ndarray, detail: bool) -> Mesh:
    """The ``vehicle_shapes`` mesh of the model parameters ``p`` (``_params``), by body."""
    body, length, width, height, wb, r, clear, hood, c0, c1, belt, trim = p
    from dashtraj.render import vehicle_shapes as vs

    if body in ("motorcycle", "bicycle"):
        return vs.two_wheeler_mesh(body, length, width, height, wb, r, paint, detail=detail,
                                   trim=trim)
    if body in ("truck", "bus"):
        return vs.big_vehicle_mesh(body, length, width, height, wb, r, clear, c1, paint,
                                   detail=detail, trim=trim)
    return vs.car_mesh(body, length, width, height, wb, r, clear, hood, c0, c1, belt, paint,
                       detail=detail, trim=trim)


@lru_cache(maxsize=512)
def _vehicle_mesh_cached(p: tuple, paint255: tuple) -> Mesh:
    paint = np.array(paint255, np.float64) / 255.0
    return _with_vehicle_materials(_body_mesh(p, paint, detail=True), paint)


def shadow_caster_mesh(model) -> Mesh:
    """The vehicle's caster in the sun's shadow map (vehicle frame, metres; cached per
    model): ``vehicle_mesh`` without the parts that lie within 1.5 cm of its body
    (lamps, plates, grilles, strips, pillars, glass panels, arches, rims) and with boxes
    for tyres (``vehicle_shapes``' ``detail=False``): a sedan casts 206 triangles
    instead of 380. At the shadow map's texel (≈ 0.2 m on the ground) the shadows match
    the full mesh's but for the tyres' corners; never used for ids, depth or labels."""
    return _shadow_caster_cached(_params(model))


@lru_cache(maxsize=256)
def _shadow_caster_cached(p: tuple) -> Mesh:
    return _body_mesh(p, np.full(3, 0.5), detail=False)


def _with_vehicle_materials(mesh: Mesh, paint: np.ndarray) -> Mesh:
    """Mark the painted parts ``MAT_PAINT`` and the windows ``MAT_GLASS`` (by colour;
    lamps and tyres already carry their codes)."""
    col = mesh.colors.copy()
    lit = col[:, 3] == MAT_LIT
    rgb = col[:, :3].astype(np.float64)
    is_paint = lit & (np.abs(rgb - paint).max(axis=1) < 1e-6)
    is_glass = lit & ~is_paint & (np.abs(rgb - np.array(GLASS)).max(axis=1) < 1e-6)
    col[is_paint, 3] = MAT_PAINT
    col[is_glass, 3] = MAT_GLASS
    return Mesh(mesh.positions, mesh.normals, col)


# --------------------------------------------------------------------------- road scene
SIMPLIFY_TOL_M = 0.002  # static polylines: samples within 2 mm of a chord are dropped
SIMPLIFY_MAX_M = 30.0  # ... but no chord longer than this (keeps tile culling useful)


def _dist_to_chord(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances of (K, 3) points to the segment a–b."""
    ab = b - a
    den = float(ab @ ab)
    t = np.clip(((p - a) @ ab) / den, 0.0, 1.0) if den > 0 else np.zeros(len(p))
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def simplify_stations(
    lines: list[np.ndarray], tol: float = SIMPLIFY_TOL_M, max_len: float = SIMPLIFY_MAX_M
) -> np.ndarray:
    """Indices of the samples to keep of polylines sampled at common stations.

    Douglas–Peucker on all ``lines`` (each (M, 3)) at once: a sample is dropped only if
    it lies within ``tol`` metres of the chord of every line, and no kept chord is
    longer than ``max_len``. Straight, flat roads collapse to a few quads.
    """
    m = len(lines[0])
    if m <= 2:
        return np.arange(m)
    keep = np.zeros(m, bool)
    keep[[0, m - 1]] = True
    stack = [(0, m - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        worst, at = 0.0, -1
        for ln in lines:
            d = _dist_to_chord(ln[i + 1 : j], ln[i], ln[j])
            k = int(np.argmax(d))
            if d[k] > worst:
                worst, at = float(d[k]), i + 1 + k
        too_long = any(float(np.linalg.norm(ln[j] - ln[i])) > max_len for ln in lines)
        if worst > tol or too_long:
            if worst <= tol:
                at = (i + j) // 2
            keep[at] = True
            stack += [(i, at), (at, j)]
    return np.flatnonzero(keep)


def _strip(left: np.ndarray, right: np.ndarray, color, z_left=None, z_right=None,
           material: int = MAT_LIT) -> Mesh:
    """Quads between two (M, 3) polylines sampled at the same stations; normals up.

    Samples that add nothing (within ``SIMPLIFY_TOL_M`` of both chords) are dropped."""
    keep = simplify_stations([np.asarray(left, float), np.asarray(right, float)])
    left, right = left[keep], right[keep]
    a0, a1, b0, b1 = left[:-1], left[1:], right[:-1], right[1:]
    tris = np.concatenate([np.stack([a0, b0, b1], 1), np.stack([a0, b1, a1], 1)])
    return _mesh(tris, color, up=True, material=material)


def _wall(base: np.ndarray, height: float, color, material: int = MAT_CURB) -> Mesh:
    """Vertical quads of ``height`` metres above a (M, 3) polyline (curb faces), two-sided."""
    base = base[simplify_stations([np.asarray(base, float)])]
    top = _lift(base, height)
    a0, a1, b0, b1 = base[:-1], base[1:], top[:-1], top[1:]
    tris = np.concatenate([np.stack([a0, a1, b1], 1), np.stack([a0, b1, b0], 1)])
    if not len(tris):
        return Mesh.concat([])
    both = np.concatenate([tris, tris[:, [0, 2, 1]]])  # two-sided: seen from road and kerb
    return _mesh(both, color, material=material)


def _lift(points: np.ndarray, dz: float) -> np.ndarray:
    """Copy of (M, 3) points raised by ``dz`` metres."""
    out = np.array(points, np.float64)
    out[:, 2] += dz
    return out


def _offset(line: np.ndarray, d: float) -> np.ndarray:
    """Offset a (M, 3) polyline by ``d`` metres to its right (CARLA frame: (-sin, cos))."""
    if len(line) < 2:
        return line
    t = np.gradient(line[:, :2], axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)
    out = line.copy()
    out[:, 0] += -t[:, 1] * d
    out[:, 1] += t[:, 0] * d
    return out


def _resample(line: np.ndarray, s: np.ndarray, s_new: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(s_new, s, line[:, k]) for k in range(3)])


def _mark_pieces(line: np.ndarray, s: np.ndarray, s_a: float, s_b: float, broken: bool):
    """Sub-polylines of ``line`` (stations ``s``) covering [s_a, s_b], dashed if broken."""
    if s_b - s_a < 0.05:
        return []
    if broken:
        starts = np.arange(s_a, s_b, BROKEN_ON_M + BROKEN_OFF_M)
        spans = [(a, min(a + BROKEN_ON_M, s_b)) for a in starts]
    else:
        spans = [(s_a, s_b)]
    out = []
    for a, b in spans:
        inner = s[(s > a) & (s < b)]
        st = np.concatenate([[a], inner, [b]])
        out.append(_resample(line, s, st))
    return out


def _marks_mesh(border: np.ndarray, s: np.ndarray, s_end: float, marks) -> list[Mesh]:
    parts = []
    for i, mk in enumerate(marks):
        kinds = mk.type.lower().split()
        if not kinds or kinds[0] in ("none", "curb", "grass", "botts", "botts dots"):
            continue
        a = s[0] + mk.s_offset
        b = (s[0] + marks[i + 1].s_offset) if i + 1 < len(marks) else s_end
        col = MARK_YELLOW if mk.color.lower() == "yellow" else MARK_WHITE
        w = max(0.1, min(float(mk.width or 0.12), 0.3))
        offsets = [0.0] if len(kinds) == 1 else [-(w / 2 + 0.06), w / 2 + 0.06]
        for kind, off in zip(kinds, offsets, strict=False):
            for piece in _mark_pieces(border, s, a, b, kind == "broken"):
                if len(piece) < 2:
                    continue
                c = _lift(_offset(piece, off), MARK_LIFT_M)
                parts.append(_strip(_offset(c, -w / 2), _offset(c, w / 2), col,
                                    material=MAT_MARK))
    return parts


@dataclass(frozen=True)
class SceneMeshes:
    """The static scene of one map, CARLA world frame.

    Attributes:
        ground: grass plane and road/sidewalk surfaces.
        buildings: box buildings.
        marks: lane markings (drawn with a depth offset on top of the asphalt).
        extent: (x_min, y_min, x_max, y_max) of the map, metres.
        props: roadside props (street lamps, trees) and clutter (``dashtraj.render.clutter``:
            traffic lights, palms, conifers, bushes, hedges, rocks, embankments, planters,
            benches, bins, signs, fences, walls) beyond the outermost lanes; never labelled.
    """

    ground: Mesh
    buildings: Mesh
    marks: Mesh
    extent: tuple[float, float, float, float]
    props: Mesh | None = None


_SCENE_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_SCENES_BY_CONTENT: OrderedDict = OrderedDict()
_SCENE_LOCK = threading.Lock()
SCENES_KEPT = 4
"""How many static scenes `scene_meshes` keeps by map content (the last used ones)."""
SCENE_FILES_KEPT = 16
"""Scene files kept in the cache folder (the most recently used; about 6 MB each)."""
_SCENE_PARTS = ("ground", "buildings", "marks", "props")
_MESH_FIELDS = (("positions", 3), ("normals", 3), ("colors", 4))


def scene_meshes(road_map, seed: int = 0, clutter: bool = True) -> SceneMeshes:
    """Static meshes of a map (built once per map, seed and ``clutter``, then shared).

    A map read from an OpenDRIVE document (`RoadMap.from_file` / ``from_string``) is
    known by its bytes' SHA-256: another `RoadMap` of the same document (each renderer
    opens its recording's map anew) gets the scene already built, in this process, for
    the last `SCENES_KEPT` maps, seeds and ``clutter`` used; building one takes seconds
    (town01: 2.4 s on one core). Such a scene is also kept as a file in the cache folder
    (`dashtraj.cache.cache_root` ``("scenes")``, the last `SCENE_FILES_KEPT` used), named
    after the document, the map's sample step, the seed, ``clutter`` and the code that
    builds it (`dashtraj.cache.code_sha256`), so other processes (``--workers``, the next
    run) read it in milliseconds instead; processes that need one scene at once build it
    once (a file lock). A file that cannot be read is built again; a folder that cannot be
    written leaves the scene built in memory only. Other maps are cached weakly on the map
    object. The scene's arrays are read-only.

    Args:
        road_map: a ``dashtraj.roads.RoadMap``.
        seed: seed of the building, prop and clutter placement.
        clutter: add the street clutter (``dashtraj.render.clutter``) to the props.
    """
    key = seed if clutter else (seed, "no clutter")
    digest = road_map.opendrive.sha256  # "" for a document not parsed from bytes
    with _SCENE_LOCK:  # renderers open on several threads build a scene once
        if digest:
            full = (digest, road_map.sample_step_m, key)
            hit = _SCENES_BY_CONTENT.get(full)
            if hit is None:
                hit = _SCENES_BY_CONTENT[full] = _frozen_scene(
                    _scene_from_file(road_map, seed, clutter))
                while len(_SCENES_BY_CONTENT) > SCENES_KEPT:
                    _SCENES_BY_CONTENT.popitem(last=False)
            _SCENES_BY_CONTENT.move_to_end(full)
            return hit
        per_map = _SCENE_CACHE.setdefault(road_map, {})
        if key not in per_map:
            per_map[key] = _frozen_scene(build_scene_meshes(road_map, seed, clutter))
        return per_map[key]


def scene_file(road_map, seed: int = 0, clutter: bool = True) -> Path:
    """The cache file of a map's scene (`scene_meshes`; the map read from bytes)."""
    from dashtraj.cache import cache_root, code_sha256

    name = (f"{road_map.opendrive.sha256}\0{road_map.sample_step_m!r}\0{int(seed)}\0"
            f"{bool(clutter)}\0{code_sha256()}")
    return cache_root("scenes") / f"scene-{hashlib.sha256(name.encode()).hexdigest()[:32]}.npz"


def _scene_from_file(road_map, seed: int, clutter: bool) -> SceneMeshes:
    """The scene read from its cache file, or built (under a lock on the file, so that
    processes starting at once build it once) and written there."""
    from dashtraj.cache import building, prune, write_whole

    path = scene_file(road_map, seed, clutter)
    scene = _read_scene(path)
    if scene is not None:
        return scene
    with building(path) as writable:
        scene = _read_scene(path) if writable else None  # built while we waited
        if scene is None:
            scene = build_scene_meshes(road_map, seed, clutter)
            if writable and write_whole(path, lambda fh: np.savez(fh, **_scene_arrays(scene))):
                prune(path.parent, "scene-*.npz", SCENE_FILES_KEPT)
    return scene


def _read_scene(path: Path) -> SceneMeshes | None:
    """A scene file's meshes, or None when it is missing or not whole."""
    from dashtraj.cache import touch

    try:
        with np.load(path, allow_pickle=False) as z:
            parts = {}
            for part in _SCENE_PARTS:
                if part == "props" and "props_positions" not in z.files:
                    parts[part] = None
                    continue
                arrays = []
                for field, width in _MESH_FIELDS:
                    a = z[f"{part}_{field}"]
                    if a.dtype != np.float32 or a.ndim != 2 or a.shape[1] != width:
                        return None
                    arrays.append(a)
                if len({len(a) for a in arrays}) != 1:
                    return None
                parts[part] = Mesh(*arrays)
            extent = z["extent"]
            if extent.shape != (4,):
                return None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    touch(path)
    return SceneMeshes(parts["ground"], parts["buildings"], parts["marks"],
                       tuple(float(v) for v in extent), parts["props"])


def _scene_arrays(scene: SceneMeshes) -> dict[str, np.ndarray]:
    """A scene's arrays by name, as its cache file holds them."""
    arrays = {"extent": np.asarray(scene.extent, np.float64)}
    for part in _SCENE_PARTS:
        mesh = getattr(scene, part)
        if mesh is not None:
            for field, _ in _MESH_FIELDS:
                arrays[f"{part}_{field}"] = getattr(mesh, field)
    return arrays


def _frozen_scene(scene: SceneMeshes) -> SceneMeshes:
    """The scene with its meshes' arrays made read-only (a cached scene is shared)."""
    for mesh in (scene.ground, scene.buildings, scene.marks, scene.props):
        if mesh is not None:
            for a in (mesh.positions, mesh.normals, mesh.colors):
                a.flags.writeable = False
    return scene


def build_scene_meshes(road_map, seed: int = 0, clutter: bool = True) -> SceneMeshes:
    """Build (uncached) the static scene: ground, lanes, sidewalks, marks, buildings,
    lamps and trees, and (``clutter``) the street clutter."""
    m = road_map
    surf: list[Mesh] = []
    marks: list[Mesh] = []
    border_pts = []
    for lane in m.lane_list:
        key = lane.key
        left2, right2 = m.lane_border_polylines(key)
        if len(left2) < 2:
            continue
        z = m.lane_polyline(key, driving_order=False)[:, 2]
        s = np.linspace(lane.s0, lane.s1, len(left2))
        left = np.column_stack([left2, z])
        right = np.column_stack([right2, z])
        border_pts += [left2, right2]
        t = lane.type
        if t & LaneType.Sidewalk:
            h = SIDEWALK_HEIGHT_M
            surf.append(_strip(_lift(left, h), _lift(right, h), SIDEWALK, material=MAT_SIDEWALK))
            surf.append(_wall(left, h, CURB))
            surf.append(_wall(right, h, CURB))
        elif t & _ASPHALT_TYPES:
            surf.append(_strip(left, right, ASPHALT_JUNCTION if lane.junction >= 0 else ASPHALT,
                               material=MAT_ASPHALT))
        else:  # border, median, none: low grass verge at road level
            surf.append(_strip(_lift(left, 0.005), _lift(right, 0.005), GRASS,
                               material=MAT_GRASS))
        road = m.opendrive.roads[key[0]]
        sec = road.sections[key[1]]
        rec = sec.lanes.get(key[2])
        if rec is not None and rec.road_marks and not (t & LaneType.Sidewalk):
            outer = right if key[2] < 0 else left
            marks += _marks_mesh(outer, s, lane.s1, rec.road_marks)
        innermost = key[2] == -1 or (key[2] == 1 and -1 not in sec.lanes)
        if innermost and sec.center_marks:
            centre = left if key[2] == -1 else right
            marks += _marks_mesh(centre, s, lane.s1, sec.center_marks)
    x0, y0, x1, y1 = m.extent
    pad = 250.0
    g = np.array(
        [[x0 - pad, y0 - pad], [x1 + pad, y0 - pad], [x1 + pad, y1 + pad], [x0 - pad, y1 + pad]]
    )
    g = np.column_stack([g, np.full(4, GROUND_Z_M)])
    surf.append(_mesh(np.stack([g[[0, 1, 2]], g[[0, 2, 3]]]), GRASS, up=True, material=MAT_GRASS))
    pts = np.concatenate(border_pts) if border_pts else np.zeros((1, 2))
    placed: list[tuple[float, float, float]] = []
    buildings = _buildings(m, pts, np.random.default_rng(seed), placed=placed,
                           jitter=np.random.default_rng([seed, 1]))
    spots: list[tuple[float, float, float]] = []
    props = _props(m, pts, placed, np.random.default_rng([seed, 2]), spots=spots)
    if clutter:
        from dashtraj.render.clutter import clutter_mesh

        props = Mesh.concat([props, clutter_mesh(m, pts, placed,
                                                 np.random.default_rng([seed, 3]), taken=spots)])
    return SceneMeshes(Mesh.concat(surf), buildings, Mesh.concat(marks), (x0, y0, x1, y1),
                       props)


def _outer_borders(m):
    """The outer border of each side of every non-junction road section at least 10 m long.

    Yields ``(side, key, outer, st)``: side -1 (right of +s, negative lanes) or +1, the
    outermost lane's key (road, section, lane), its outer border polyline ((N, 2) CARLA world,
    metres; N >= 2) and the arc length along it at each point (metres).
    """
    for rid in sorted(m.roads):
        road = m.roads[rid]
        if road.junction >= 0 or road.length < 10.0:
            continue
        for k, sec in enumerate(road.sections):
            for side in (-1, 1):
                ids = [i for i in sec.lanes if i * side > 0]
                if not ids:
                    continue
                key = (rid, k, max(ids, key=abs))
                if key not in m.lanes:
                    continue
                left, right = m.lane_border_polylines(key)
                outer = right if side < 0 else left
                if len(outer) < 2:
                    continue
                seg = np.linalg.norm(np.diff(outer, axis=0), axis=1)
                yield side, key, outer, np.concatenate([[0.0], np.cumsum(seg)])


def _buildings(
    m,
    lane_pts: np.ndarray,
    rng: np.random.Generator,
    spacing_m: float = 22.0,
    clearance_m: float = 3.0,
    placed: list | None = None,
    jitter: np.random.Generator | None = None,
) -> Mesh:
    """Box buildings beside the roads, at least ``clearance_m`` from every lane border.

    Candidates are taken every ``spacing_m`` along each non-junction road on both
    sides, beyond its outermost lanes; a footprint is kept if a 1 m grid over it
    stays ``clearance_m`` from all lane border samples and it does not overlap an
    accepted building. Deterministic for a given generator state. Facade colours come
    from ``FACADES`` with a small per-building jitter (drawn from ``jitter``, so placement
    does not depend on it; the shader also seeds each building's windows with it).
    ``placed`` (a list) receives each building's (centre x, centre y, radius).
    """
    tree = cKDTree(lane_pts)
    jitter = jitter if jitter is not None else np.random.default_rng(1)
    placed = [] if placed is None else placed  # centre x, y, radius
    boxes = []
    for side, _key, outer, st in _outer_borders(m):
        for d in np.arange(spacing_m / 2, st[-1] - 4.0, spacing_m):
            i = min(np.searchsorted(st, d), len(outer) - 1)
            j = max(i - 1, 0) if i == len(outer) - 1 else i + 1
            tvec = outer[max(i, j)] - outer[min(i, j)]
            tvec = tvec / max(np.linalg.norm(tvec), 1e-9)
            nvec = np.array([-tvec[1], tvec[0]]) * (-1.0 if side > 0 else 1.0)
            # nvec points away from the road: right of +s for negative lanes
            depth = rng.uniform(8.0, 18.0)
            width = rng.uniform(8.0, 16.0)
            height = rng.choice([rng.uniform(5.0, 12.0), rng.uniform(12.0, 35.0)])
            gap = rng.uniform(2.0, 6.0) + clearance_m
            c = outer[i] + nvec * (gap + depth / 2)
            rad = 0.5 * math.hypot(depth, width)
            if any(
                math.hypot(c[0] - px, c[1] - py) < (rad + pr) * 0.75
                for px, py, pr in placed
            ):
                continue
            u = np.linspace(-0.5, 0.5, max(2, int(width) + 1))
            v = np.linspace(-0.5, 0.5, max(2, int(depth) + 1))
            uu, vv = np.meshgrid(u, v)
            grid = c + uu.reshape(-1, 1) * width * tvec + vv.reshape(-1, 1) * depth * nvec
            if np.min(tree.query(grid)[0]) < clearance_m:
                continue
            placed.append((c[0], c[1], rad))
            corners = np.array(
                [
                    c + a * width / 2 * tvec + b * depth / 2 * nvec
                    for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))
                ]
            )
            col = FACADES[rng.integers(len(FACADES))]
            col = np.clip(col * jitter.uniform(0.9, 1.1, 3), 0.0, 1.0)
            boxes.append(
                hexahedron(
                    np.vstack(
                        [
                            np.column_stack([corners, np.full(4, GROUND_Z_M)]),
                            np.column_stack([corners, np.full(4, height)]),
                        ]
                    ),
                    col,
                    material=MAT_FACADE,
                )
            )
    return Mesh.concat(boxes)


def _blob(centre, radius: float, height: float, color, sides: int = 7) -> Mesh:
    """A low-poly ellipsoid (two rings of ``sides`` + poles): a tree's canopy."""
    cx, cy, cz = centre
    a = np.arange(sides) * (2 * np.pi / sides)
    rings = []
    for zf, rf, ph in ((-0.3, 0.85, 0.0), (0.3, 0.8, np.pi / sides)):
        rings.append(np.column_stack([cx + rf * radius * np.cos(a + ph),
                                      cy + rf * radius * np.sin(a + ph),
                                      np.full(sides, cz + zf * height)]))
    lo, hi = rings
    bot, top = np.array([cx, cy, cz - 0.5 * height]), np.array([cx, cy, cz + 0.5 * height])
    i, j = np.arange(sides), (np.arange(sides) + 1) % sides
    tris = [np.stack([np.repeat(bot[None], sides, 0), lo[j], lo[i]], 1),
            np.stack([np.repeat(top[None], sides, 0), hi[i], hi[j]], 1),
            np.stack([lo[i], lo[j], hi[i]], 1), np.stack([lo[j], hi[j], hi[i]], 1)]
    tris = np.concatenate(tris)
    # flat faces, normals away from the centre
    return _mesh(tris, color, centre=centre, material=MAT_FOLIAGE)


def _props(m, lane_pts: np.ndarray, buildings: list, rng: np.random.Generator,
           spacing_m: float = 12.0, spots: list | None = None) -> Mesh:
    """Street lamps and trees beside the non-junction roads, off every lane.

    Candidates every ``spacing_m`` (jittered) along the outer border of each road
    side, 1.2–2.6 m outward; a prop is kept when its whole footprint (canopy radius
    for trees) stays 0.4 m clear of every lane border sample and outside every
    building's circle. About one candidate in three becomes a lamp post (0.16 m
    square, 5–7 m high, head 0.7 m toward the road), the rest trees (trunk 0.25 m,
    canopy radius 1.0–2.0 m, 4–8 m high) or nothing. Deterministic for ``rng``.
    """
    tree = cKDTree(lane_pts)
    parts: list[Mesh] = []
    spots = [] if spots is None else spots  # (x, y, radius) of each prop (extended)
    for side, key, outer, st in _outer_borders(m):
        z = m.lane_polyline(key, driving_order=False)[:, 2]
        for d in np.arange(spacing_m / 2, st[-1] - 2.0, spacing_m):
            d = d + rng.uniform(-2.0, 2.0)
            kind = rng.choice(3, p=[0.3, 0.5, 0.2])  # lamp, tree, nothing
            off = rng.uniform(1.2, 2.6)
            radius = rng.uniform(1.0, 2.0)
            height = rng.uniform(4.0, 8.0)
            if kind == 2 or not 0.0 <= d <= st[-1]:
                continue
            i = int(min(max(np.searchsorted(st, d), 1), len(outer) - 1))
            tvec = outer[i] - outer[i - 1]
            tvec = tvec / max(np.linalg.norm(tvec), 1e-9)
            nvec = np.array([-tvec[1], tvec[0]]) * (-1.0 if side > 0 else 1.0)
            base = outer[i - 1] + tvec * (d - st[i - 1])
            foot = radius if kind == 1 else 0.3
            c = base + nvec * (off + (foot if kind == 1 else 0.0))
            if tree.query(c)[0] < foot + 0.4:
                continue
            if any(math.hypot(c[0] - bx, c[1] - by) < br + foot
                   for bx, by, br in buildings):
                continue
            if any(math.hypot(c[0] - sx, c[1] - sy) < sr + foot for sx, sy, sr in spots):
                continue
            spots.append((c[0], c[1], foot))
            gz = float(np.interp(d, st, z)) if len(z) == len(st) else float(z[0])
            gz = gz - 0.05  # sunk a little into the ground
            if kind == 0:
                h = rng.uniform(5.0, 7.0)
                parts.append(box((c[0] - 0.08, c[1] - 0.08, gz),
                                 (c[0] + 0.08, c[1] + 0.08, gz + h), POLE,
                                 material=MAT_METAL))
                hx, hy = c[0] - nvec[0] * 0.7, c[1] - nvec[1] * 0.7
                lo = (min(c[0], hx) - 0.12, min(c[1], hy) - 0.12, gz + h - 0.15)
                hi = (max(c[0], hx) + 0.12, max(c[1], hy) + 0.12, gz + h)
                parts.append(box(lo, hi, POLE, material=MAT_METAL))
            else:
                trunk = height * 0.4
                parts.append(box((c[0] - 0.12, c[1] - 0.12, gz), (c[0] + 0.12, c[1] + 0.12,
                                                                  gz + trunk + 0.5),
                                 BARK, material=MAT_BARK))
                col = FOLIAGE[int(rng.integers(len(FOLIAGE)))]
                parts.append(_blob((c[0], c[1], gz + trunk + (height - trunk) / 2),
                                   radius, height - trunk, col))
    return Mesh.concat(parts)
