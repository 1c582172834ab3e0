"""Street clutter beside the roads: the things a detector must learn are NOT vehicles.

Traffic lights on poles with arms over the approach lanes at junctions, palms, conifers
and round trees, bushes and hedges, rocks and embankments, planters, benches, bins,
road signs, fences and walls. Every piece stands off the driving lanes (its footprint is
checked against the lane borders and, point by point, against the driving lanes
themselves; only a traffic light's arm and heads and palm fronds reach over the road,
above 4.5 m), and
nothing here is ever labelled: the clutter is drawn with instance id 0 in the props
group.

Deterministic: everything is drawn from the generator handed in (the scene seed's).
Colours are base colours in linear 0..1; the shader multiplies foliage by the look's
``materials.foliage_tint`` and the other clutter by ``materials.prop_tint``
(``dashtraj.render.randomize`` draws both). Frame: CARLA world, metres.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

from dashtraj.errors import OffRoadError
from dashtraj.render.meshes import (
    BARK,
    FOLIAGE,
    GROUND_Z_M,
    MAT_BARK,
    MAT_FOLIAGE,
    MAT_LAMP,
    MAT_LIT,
    MAT_METAL,
    POLE,
    Mesh,
    _blob,
    _mesh,
    _outer_borders,
    hexahedron,
)
from dashtraj.roads.types import LaneType

MAT_ROCK = 15
"""Material code of rocks, embankments and concrete (noise-textured in the props shader)."""

ROCK = ((0.42, 0.40, 0.37), (0.50, 0.47, 0.42), (0.36, 0.33, 0.30), (0.55, 0.53, 0.50))
CONCRETE = ((0.62, 0.60, 0.57), (0.50, 0.49, 0.47), (0.70, 0.66, 0.58))
WOOD = ((0.42, 0.30, 0.18), (0.55, 0.40, 0.25))
BIN = ((0.15, 0.30, 0.18), (0.20, 0.20, 0.22), (0.45, 0.45, 0.47), (0.10, 0.22, 0.40))
SIGN = ((0.80, 0.08, 0.06), (0.08, 0.25, 0.65), (0.92, 0.92, 0.90), (0.95, 0.75, 0.08))
FENCE = ((0.30, 0.31, 0.32), (0.55, 0.42, 0.28), (0.75, 0.75, 0.73))
WALL = ((0.60, 0.55, 0.48), (0.48, 0.35, 0.28), (0.66, 0.66, 0.64), (0.40, 0.40, 0.42))
PALM = ((0.30, 0.45, 0.16), (0.36, 0.48, 0.20))
CONIFER = ((0.10, 0.22, 0.10), (0.14, 0.26, 0.12), (0.12, 0.20, 0.14))
LIGHT_BOX = (0.08, 0.08, 0.08)
LIGHT_ON = ((0.95, 0.10, 0.05), (1.00, 0.65, 0.05), (0.15, 0.95, 0.35))
LIGHT_OFF = (0.18, 0.18, 0.17)

KINDS = ("palm", "conifer", "round", "bush", "hedge", "rock", "embankment", "planter",
         "bench", "bin", "sign", "fence", "wall", "none")
_P = np.array([0.09, 0.09, 0.08, 0.12, 0.06, 0.07, 0.04, 0.06, 0.06, 0.07, 0.09, 0.05, 0.05,
               0.07])
_P = _P / _P.sum()

ARM_Z_M = 5.6  # traffic light arms hang this high over the road


# --------------------------------------------------------------------------- primitives
def _obox(c, t, half_u: float, half_v: float, z0: float, z1: float, color,
          material: int = MAT_LIT) -> Mesh:
    """A box on the ground plan point ``c`` (2,), long axis ``t`` (unit (2,)),
    ``half_u`` along t, ``half_v`` across, from z0 to z1."""
    c = np.asarray(c, np.float64)
    t = np.asarray(t, np.float64)
    n = np.array([-t[1], t[0]])
    ring = np.array([c + a * half_u * t + b * half_v * n
                     for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    return hexahedron(np.vstack([np.column_stack([ring, np.full(4, z0)]),
                                 np.column_stack([ring, np.full(4, z1)])]), color,
                      material=material)


def _prism(c, r0: float, r1: float, z0: float, z1: float, color, material: int,
           sides: int = 8, phase: float = 0.0) -> Mesh:
    """A ``sides``-gon frustum (r0 at z0, r1 at z1; r1 = 0: a cone) with caps."""
    a = np.arange(sides) * (2 * np.pi / sides) + phase
    j = (np.arange(sides) + 1) % sides
    cx, cy = float(c[0]), float(c[1])
    lo = np.column_stack([cx + r0 * np.cos(a), cy + r0 * np.sin(a), np.full(sides, z0)])
    hi = np.column_stack([cx + r1 * np.cos(a), cy + r1 * np.sin(a), np.full(sides, z1)])
    tris = [np.stack([lo, lo[j], hi[j]], 1)]
    if r1 > 0:
        tris.append(np.stack([lo, hi[j], hi], 1))
        tris.append(np.stack([np.repeat([[cx, cy, z1]], sides, 0), hi, hi[j]], 1))
    tris.append(np.stack([np.repeat([[cx, cy, z0]], sides, 0), lo[j], lo], 1))
    tris = np.concatenate(tris)
    # outward normals: reference on the axis at each triangle's height
    cen = np.column_stack([np.full(len(tris), cx), np.full(len(tris), cy),
                           tris[:, :, 2].mean(axis=1)])
    caps = np.abs(tris[:, :, 2].max(axis=1) - tris[:, :, 2].min(axis=1)) < 1e-9
    cen[caps, 2] = 0.5 * (z0 + z1)
    return _mesh(tris, color, centre=cen, material=material)


def _rock(c, radius: float, height: float, z: float, color, rng: np.random.Generator) -> Mesh:
    """An irregular low polyhedron: a ring of 7 jittered points, a jittered top."""
    k = 7
    a = np.arange(k) * (2 * np.pi / k) + rng.uniform(0, 2 * np.pi)
    rr = radius * rng.uniform(0.7, 1.0, k)
    cx, cy = float(c[0]), float(c[1])
    base = np.column_stack([cx + rr * np.cos(a), cy + rr * np.sin(a), np.full(k, z)])
    mid = np.column_stack([cx + 0.75 * rr * np.cos(a + 0.3), cy + 0.75 * rr * np.sin(a + 0.3),
                           z + height * rng.uniform(0.45, 0.8, k)])
    top = np.array([cx + rng.uniform(-0.2, 0.2) * radius, cy + rng.uniform(-0.2, 0.2) * radius,
                    z + height])
    j = (np.arange(k) + 1) % k
    tris = np.concatenate([np.stack([base, base[j], mid[j]], 1), np.stack([base, mid[j], mid], 1),
                           np.stack([mid, mid[j], np.repeat(top[None], k, 0)], 1)])
    return _mesh(tris, color, centre=(cx, cy, z + 0.3 * height), material=MAT_ROCK)


def _two_sided(tris: np.ndarray, color, material: int) -> Mesh:
    """Thin leaves and plates: both faces (the renderer culls back faces)."""
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    mid = tris.mean(axis=1)
    return Mesh.concat([_mesh(tris, color, centre=mid - n, material=material),
                        _mesh(tris, color, centre=mid + n, material=material)])


def _plate(c3, normal2, half_w: float, half_h: float, color, sides: int = 4,
           material: int = MAT_LIT) -> Mesh:
    """A flat sign plate centred at ``c3`` facing the plan direction ``normal2``:
    a rectangle (sides 4), a diamond (sides -4) or an octagon/disc (sides 8)."""
    nx, ny = float(normal2[0]), float(normal2[1])
    u = np.array([-ny, nx, 0.0])
    v = np.array([0.0, 0.0, 1.0])
    c = np.asarray(c3, np.float64)
    if sides == 4:
        pts = [c + a * half_w * u + b * half_h * v for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    else:
        k = abs(sides)
        ph = np.pi / 4 if sides == -4 else np.pi / k
        ang = np.arange(k) * 2 * np.pi / k + (0.0 if sides == -4 else ph)
        pts = [c + half_w * math.cos(t) * u + half_h * math.sin(t) * v for t in ang]
    pts = np.array(pts)
    tris = np.stack([np.repeat(c[None], len(pts), 0), pts, np.roll(pts, -1, axis=0)], 1)
    return _two_sided(tris, color, material)


# --------------------------------------------------------------------------- pieces
def _palm(c, z, rng) -> list[Mesh]:
    h = rng.uniform(6.0, 11.0)
    lean = rng.uniform(-0.4, 0.4, 2)
    top = np.array([c[0] + lean[0], c[1] + lean[1]])
    trunk = []
    for f0, f1 in ((0.0, 0.5), (0.5, 1.0)):
        p = c + (top - c) * (0.5 * (f0 + f1))
        trunk.append(_prism(p, 0.22 - 0.08 * f0, 0.18 - 0.08 * f1, z + f0 * h, z + f1 * h,
                            BARK, MAT_BARK, 6))
    col = PALM[int(rng.integers(len(PALM)))]
    n_leaf = int(rng.integers(7, 11))
    a0 = rng.uniform(0, 2 * np.pi)
    leaves = []
    crown = np.array([top[0], top[1], z + h])
    for i in range(n_leaf):
        a = a0 + i * 2 * np.pi / n_leaf
        d = np.array([math.cos(a), math.sin(a), 0.0])
        s = np.array([-d[1], d[0], 0.0])
        ln = rng.uniform(2.2, 3.4)
        mid = crown + d * 0.55 * ln + np.array([0, 0, 0.35])
        tip = crown + d * ln + np.array([0, 0, -rng.uniform(0.9, 1.4)])
        w = 0.32
        leaves.append(np.array([crown, mid - s * w, mid]))
        leaves.append(np.array([crown, mid, mid + s * w]))
        leaves.append(np.array([mid - s * w, tip, mid]))
        leaves.append(np.array([mid, tip, mid + s * w]))
    return [*trunk, _two_sided(np.array(leaves), col, MAT_FOLIAGE)]


def _conifer(c, z, rng, foot: float) -> list[Mesh]:
    h = rng.uniform(5.0, 12.0)
    r = foot * rng.uniform(0.6, 1.0)
    col = CONIFER[int(rng.integers(len(CONIFER)))]
    out = [_prism(c, 0.15, 0.12, z, z + 0.25 * h, BARK, MAT_BARK, 6)]
    tiers = 3
    for i in range(tiers):
        z0 = z + h * (0.18 + 0.22 * i)
        rr = r * (1.0 - 0.28 * i)
        out.append(_prism(c, rr, 0.0, z0, z0 + h * 0.42, col, MAT_FOLIAGE, 8,
                          rng.uniform(0, np.pi)))
    return out


def _round_tree(c, z, rng, foot: float) -> list[Mesh]:
    h = rng.uniform(4.0, 9.0)
    r = foot * rng.uniform(0.7, 1.0)
    trunk = h * rng.uniform(0.3, 0.45)
    col = FOLIAGE[int(rng.integers(len(FOLIAGE)))]
    out = [_prism(c, 0.16, 0.12, z, z + trunk + 0.5, BARK, MAT_BARK, 6)]
    out.append(_blob((c[0], c[1], z + trunk + (h - trunk) / 2), r, h - trunk, col, sides=8))
    if rng.uniform() < 0.5:  # a second lobe: less of a lollipop
        off = rng.uniform(-0.2, 0.2, 2) * r
        out.append(_blob((c[0] + off[0], c[1] + off[1], z + trunk + 0.7 * (h - trunk)),
                         0.7 * r, 0.6 * (h - trunk), col, sides=7))
    return out


def _bush(c, z, rng, r) -> list[Mesh]:
    col = FOLIAGE[int(rng.integers(len(FOLIAGE)))]
    h = rng.uniform(0.6, 1.5)
    return [_blob((c[0], c[1], z + 0.45 * h), r, h, col, sides=7)]


def _traffic_head(p3, facing2, rng, lit: int) -> list[Mesh]:
    """A signal head (0.35 × 0.3 × 1.0 m box) with three lamps facing ``facing2``;
    lamp ``lit`` (0 red, 1 amber, 2 green) is emissive, the others dark."""
    f = np.asarray(facing2, np.float64)
    out = [_obox(p3[:2], f, 0.15, 0.18, p3[2] - 0.5, p3[2] + 0.5, LIGHT_BOX, MAT_METAL)]
    for i in range(3):
        zc = p3[2] + 0.3 - 0.3 * i
        col = LIGHT_ON[i] if i == lit else LIGHT_OFF
        c3 = np.array([p3[0] + f[0] * 0.16, p3[1] + f[1] * 0.16, zc])
        out.append(_plate(c3, f, 0.11, 0.11, col, 8, MAT_LAMP if i == lit else MAT_METAL))
    return out


def _traffic_light(base, z, nvec, tvec_face, rng) -> list[Mesh]:
    """A pole at ``base`` with an arm toward the road (−``nvec``) at ``ARM_Z_M`` and two
    signal heads on it plus one on the pole, all facing ``tvec_face`` (toward the
    approaching traffic)."""
    arm = rng.uniform(3.5, 6.5)
    lit = int(rng.integers(3))
    out = [_prism(base, 0.14, 0.11, z, z + ARM_Z_M + 0.4, POLE, MAT_METAL, 8)]
    tip = base - nvec * arm
    mid = 0.5 * (base + tip)
    out.append(_obox(mid, -nvec, 0.5 * arm, 0.07, z + ARM_Z_M - 0.08, z + ARM_Z_M + 0.08,
                     POLE, MAT_METAL))
    for f in (0.6, 1.0):
        p = base - nvec * (arm * f - 0.1)
        out += _traffic_head(np.array([p[0], p[1], z + ARM_Z_M - 0.55]), tvec_face, rng, lit)
    p = base + tvec_face * 0.25
    out += _traffic_head(np.array([p[0], p[1], z + 3.0]), tvec_face, rng, lit)
    return out


# --------------------------------------------------------------------------- placement
def _frame(outer, st, z, side: int, d: float):
    """Point ``d`` m along a road side's outer border: (plan point, unit tangent, unit
    normal away from the road, ground z)."""
    i = int(min(max(np.searchsorted(st, d), 1), len(outer) - 1))
    tvec = outer[i] - outer[i - 1]
    tvec = tvec / max(np.linalg.norm(tvec), 1e-9)
    nvec = np.array([-tvec[1], tvec[0]]) * (-1.0 if side > 0 else 1.0)
    base = outer[i - 1] + tvec * (d - st[i - 1])
    gz = float(np.interp(d, st, z)) if len(z) == len(st) else float(z[0])
    return base, tvec, nvec, gz


def _driving_clear(m, pts: np.ndarray, margin: float) -> bool:
    """True when every plan point is at least ``margin`` m outside every driving lane."""
    try:
        pr = m.project(pts, LaneType.Driving)
    except OffRoadError:  # a map without driving lanes: nothing to avoid
        return True
    return bool(np.all(np.abs(pr.lateral_m) >= pr.lane_width / 2 + margin))


def clutter_mesh(m, lane_pts: np.ndarray, buildings: list, rng: np.random.Generator,
                 spacing_m: float = 7.0, taken: list | None = None) -> Mesh:
    """All the clutter of a map (see the module docstring).

    Args:
        m: a ``dashtraj.roads.RoadMap``.
        lane_pts: (N, 2) lane border samples (every lane type), CARLA world, metres.
        buildings: (x, y, radius) circles of the buildings (kept clear).
        rng: the generator (deterministic for its state).
        spacing_m: mean gap between clutter candidates along a road side.
        taken: (x, y, radius) of props already placed (kept clear; extended).

    Candidates every ``spacing_m`` (jittered) along each road side's outer border, 0.6–5 m
    outward; a piece is kept when its footprint stays 0.3 m from every lane border sample,
    outside every building and earlier piece, and 0.5 m outside every driving lane.
    Traffic lights: one per junction approach (the right-hand side of each road end that
    touches a junction), 0.8 m outside the outer border.
    """
    tree = cKDTree(lane_pts)
    taken = [] if taken is None else taken
    parts: list[Mesh] = []
    jpts = [np.concatenate(m.lane_border_polylines(lane.key)) for lane in m.lane_list
            if lane.junction >= 0 and len(m.lane_border_polylines(lane.key)[0])]
    jtree = cKDTree(np.concatenate(jpts)) if jpts else None

    def free(c, foot: float, extra=()) -> bool:
        pts = np.vstack([np.asarray(c, float)[None], *[np.asarray(e, float) for e in extra]])
        if np.min(tree.query(pts)[0]) < foot + 0.3:
            return False
        if any(math.hypot(c[0] - bx, c[1] - by) < br + foot for bx, by, br in buildings):
            return False
        if any(math.hypot(c[0] - sx, c[1] - sy) < sr + foot for sx, sy, sr in taken):
            return False
        ring = [c + foot * np.array([math.cos(a), math.sin(a)])
                for a in np.arange(6) * np.pi / 3]
        return _driving_clear(m, np.vstack([pts, ring]), 0.5)

    for side, key, outer, st in _outer_borders(m):
        z = m.lane_polyline(key, driving_order=False)[:, 2]

        def frame(d, outer=outer, st=st, z=z, side=side):
            return _frame(outer, st, z, side, d)

        # traffic lights where this side's road end meets a junction (approach side)
        if jtree is not None:
            d_end = st[-1] - 0.5 if side < 0 else 0.5
            base, tvec, nvec, gz = frame(d_end)
            if jtree.query(outer[-1] if side < 0 else outer[0])[0] < 4.0:
                p = base + nvec * 0.8
                if free(p, 0.5):
                    face = -tvec if side < 0 else tvec  # toward the approaching traffic
                    taken.append((p[0], p[1], 0.3))
                    parts += _traffic_light(p, gz + GROUND_Z_M, nvec, face, rng)
        for d in np.arange(spacing_m / 2, st[-1] - 1.0, spacing_m):
            d = float(d + rng.uniform(-2.0, 2.0))
            kind = KINDS[int(rng.choice(len(KINDS), p=_P))]
            off = rng.uniform(0.6, 5.0)
            sub = np.random.default_rng(rng.integers(2**32))  # the piece's own draws
            if kind == "none" or not 1.0 <= d <= st[-1] - 1.0:
                continue
            base, tvec, nvec, gz = frame(d)
            gz = gz + GROUND_Z_M - 0.02
            foot = {"palm": 0.4, "conifer": 1.6, "round": 2.2, "bush": 0.9, "rock": 0.9,
                    "planter": 0.6, "bench": 0.9, "bin": 0.35, "sign": 0.4}.get(kind, 0.0)
            if kind in ("hedge", "fence", "wall", "embankment"):
                length = sub.uniform(4.0, 12.0)
                depth = {"hedge": 0.9, "fence": 0.1, "wall": 0.35,
                         "embankment": sub.uniform(3.0, 6.0)}[kind]
                c = base + nvec * (off + depth / 2) + tvec * length / 2
                ends = [c + tvec * length / 2 + nvec * depth / 2 * s for s in (-1, 1)]
                ends += [c - tvec * length / 2 + nvec * depth / 2 * s for s in (-1, 1)]
                ends += [c + tvec * a * length / 2 - nvec * depth / 2
                         for a in np.linspace(-1.0, 1.0, int(length) + 2)]
                if not free(c, depth / 2, ends):
                    continue
                taken.append((c[0], c[1], 0.5 * math.hypot(length, depth)))
                if kind == "hedge":
                    col = FOLIAGE[int(sub.integers(len(FOLIAGE)))]
                    parts.append(_obox(c, tvec, length / 2, depth / 2, gz,
                                       gz + sub.uniform(0.8, 1.8), col, MAT_FOLIAGE))
                elif kind == "wall":
                    col = WALL[int(sub.integers(len(WALL)))]
                    parts.append(_obox(c, tvec, length / 2, depth / 2, gz,
                                       gz + sub.uniform(0.8, 2.5), col, MAT_ROCK))
                elif kind == "fence":
                    col = FENCE[int(sub.integers(len(FENCE)))]
                    hgt = sub.uniform(1.0, 2.0)
                    for k in range(int(length // 2.0) + 1):
                        p = c + tvec * (-length / 2 + min(k * 2.0, length))
                        parts.append(_obox(p, tvec, 0.05, 0.05, gz, gz + hgt, col, MAT_METAL))
                    for zz in (0.35, 0.9) if hgt < 1.4 else (0.35, 0.9, hgt - 0.1):
                        parts.append(_obox(c, tvec, length / 2, 0.03, gz + zz - 0.04,
                                           gz + zz + 0.04, col, MAT_METAL))
                else:  # embankment: a slope rising away from the road
                    hgt = sub.uniform(1.5, 4.0)
                    col = ROCK[int(sub.integers(len(ROCK)))] if sub.uniform() < 0.5 else \
                        FOLIAGE[int(sub.integers(len(FOLIAGE)))]
                    mat = MAT_ROCK if col in ROCK else MAT_FOLIAGE
                    q0 = c - nvec * depth / 2
                    q1 = c + nvec * depth / 2
                    a0, a1 = q0 - tvec * length / 2, q0 + tvec * length / 2
                    b0, b1 = q1 - tvec * length / 2, q1 + tvec * length / 2
                    P = [np.array([*p, zz]) for p, zz in
                         ((a0, gz), (a1, gz), (b1, gz + hgt), (b0, gz + hgt), (b0, gz), (b1, gz))]
                    tris = np.array([[P[0], P[1], P[2]], [P[0], P[2], P[3]],  # slope
                                     [P[0], P[3], P[4]], [P[1], P[5], P[2]],  # ends
                                     [P[4], P[3], P[2]], [P[4], P[2], P[5]]])  # back
                    cen = np.array([*(c + nvec * depth * 0.2), gz + 0.2 * hgt])
                    parts.append(_mesh(tris, col, centre=cen, material=mat))
                continue
            c = base + nvec * (off + foot)
            if not free(c, foot):
                continue
            taken.append((c[0], c[1], foot))
            if kind == "palm":
                parts += _palm(c, gz, sub)
            elif kind == "conifer":
                parts += _conifer(c, gz, sub, foot)
            elif kind == "round":
                parts += _round_tree(c, gz, sub, foot)
            elif kind == "bush":
                parts += _bush(c, gz, sub, foot)
            elif kind == "rock":
                col = ROCK[int(sub.integers(len(ROCK)))]
                parts.append(_rock(c, foot, sub.uniform(0.4, 1.4), gz, col, sub))
            elif kind == "planter":
                col = CONCRETE[int(sub.integers(len(CONCRETE)))]
                hgt = sub.uniform(0.4, 0.8)
                if sub.uniform() < 0.5:
                    parts.append(_obox(c, tvec, foot, foot, gz, gz + hgt, col, MAT_ROCK))
                else:
                    parts.append(_prism(c, foot, foot * 0.9, gz, gz + hgt, col, MAT_ROCK, 8))
                parts += _bush(c, gz + hgt - 0.1, sub, foot * 0.95)
            elif kind == "bench":
                wood = WOOD[int(sub.integers(len(WOOD)))]
                parts.append(_obox(c, tvec, 0.85, 0.22, gz + 0.42, gz + 0.48, wood, MAT_LIT))
                back = c + nvec * 0.2
                parts.append(_obox(back, tvec, 0.85, 0.03, gz + 0.5, gz + 0.85, wood, MAT_LIT))
                for s in (-0.7, 0.7):
                    parts.append(_obox(c + tvec * s, tvec, 0.04, 0.2, gz, gz + 0.45, POLE,
                                       MAT_METAL))
            elif kind == "bin":
                col = BIN[int(sub.integers(len(BIN)))]
                parts.append(_prism(c, 0.3, 0.33, gz, gz + sub.uniform(0.8, 1.1), col,
                                    MAT_METAL, 8))
            elif kind == "sign":
                hgt = sub.uniform(2.2, 3.0)
                parts.append(_prism(c, 0.04, 0.04, gz, gz + hgt, POLE, MAT_METAL, 5))
                col = SIGN[int(sub.integers(len(SIGN)))]
                shape = int(sub.choice([4, -4, 8]))
                face = -tvec if side < 0 else tvec
                ctr = np.array([c[0] + face[0] * 0.05, c[1] + face[1] * 0.05, gz + hgt - 0.35])
                parts.append(_plate(ctr, face, 0.35, 0.35, col, shape, MAT_METAL))
    return Mesh.concat(parts)
