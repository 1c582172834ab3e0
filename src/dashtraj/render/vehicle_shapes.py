"""Rounded per-class vehicle meshes (cars, trucks, buses, two-wheelers with riders).

The bodies are lofts: a cross-section ring (y, z) at a few stations along x, joined by
quads, so the hood slopes into the nose, the boot into the tail, the shoulders and sills
are bevelled and the greenhouse is tapered with a raked, curved windscreen and rear
window. Glass all round (side windows, windscreen, rear window) carries ``MAT_GLASS``
(the shader adds a Fresnel sky reflection and a sharp specular); the roof, pillars and
roof rails are paint. Every four-wheeler gets dark wheel arches behind its tyres,
lighter rims on the tyres, head and tail lamps, a grille and a number plate front and
back; two-wheelers get rims (spoked rings for bicycles) and a rider (helmet on a
motorcycle). :func:`contact_shadow_mesh` is the dark footprint drawn under a vehicle
(its own draw, id 0: never part of a label).

Frame: the vehicle frame of ``dashtraj.render.meshes`` (x forward, y right, z up,
metres, origin on the ground at the footprint centre). Every mesh stays inside the
catalog's length × width × height (tyres and rims stand out ≤ 1.5 cm at the sides).
Deterministic: no randomness.
"""

from __future__ import annotations

from dataclasses import astuple
from functools import lru_cache

import numpy as np

from dashtraj.render.meshes import (
    GLASS,
    GRILLE,
    HEADLIGHT,
    MAT_GLASS,
    MAT_LIT,
    MAT_METAL,
    MAT_PAINT,
    MAT_TYRE,
    RIDER_BODY,
    RIDER_HEAD,
    TAILLIGHT,
    TYRE,
    Mesh,
    _mesh,
    box,
    hexahedron,
    wheel,
)
from dashtraj.world.catalog import Trim

ARCH = (0.025, 0.025, 0.027)  # wheel wells: near black
RIM = (0.62, 0.63, 0.65)
RIM_DARK = (0.09, 0.09, 0.10)
GLASS_TINTED = (0.025, 0.03, 0.04)
ROOF_COLORS = {"black": (0.02, 0.02, 0.022), "white": (0.86, 0.86, 0.84)}
RIDERS = {"navy": RIDER_BODY, "black": (0.02, 0.02, 0.025), "brown": (0.30, 0.17, 0.08),
          "red": (0.60, 0.05, 0.05), "hivis": (0.85, 0.80, 0.05)}
DEFAULT_TRIM = astuple(Trim())
"""(roof, rims, glass, tail, cladding, rider): the catalog's default ``Trim`` as a tuple."""
RAIL_M = 0.04
"""Height of roof rails; the roof under them is lowered by as much (inside H)."""
PLATE = (0.88, 0.88, 0.84)
TRIM = (0.07, 0.07, 0.08)  # bumper strips, sills
HELMET = (0.10, 0.10, 0.11)
MAT_SHADOW = 14
"""Material code of the contact shadow (the shader darkens the road under a vehicle)."""


# --------------------------------------------------------------------------- lofts
def _loft(xs, rings, closed: bool = True):
    """Quads joining cross-section rings at stations ``xs``.

    Args:
        xs: (S,) stations along x, metres.
        rings: (S, K, 2) ring points (y, z) per station, same topology everywhere.
        closed: join the last ring point back to the first.

    Returns:
        tris (2 Q, 3, 3), per-triangle outward reference centres (2 Q, 3), and per
        triangle its station segment i and ring edge k.
    """
    xs = np.asarray(xs, np.float64)
    rings = np.asarray(rings, np.float64)
    s, k = rings.shape[:2]
    p = np.concatenate([np.broadcast_to(xs[:, None, None], (s, k, 1)), rings], axis=2)
    e = k if closed else k - 1
    ka, kb = np.arange(e), (np.arange(e) + 1) % k
    a, b = p[:-1][:, ka], p[:-1][:, kb]
    c, d = p[1:][:, kb], p[1:][:, ka]  # (S-1, E, 3)
    t1 = np.stack([a, b, c], axis=2)
    t2 = np.stack([a, c, d], axis=2)
    tris = np.concatenate([t1.reshape(-1, 3, 3), t2.reshape(-1, 3, 3)])
    zc = 0.5 * (rings[:-1, :, 1].mean(axis=1) + rings[1:, :, 1].mean(axis=1))
    xm = 0.5 * (xs[:-1] + xs[1:])
    cen = np.stack([xm, np.zeros_like(xm), zc], axis=1)  # (S-1, 3)
    cen = np.repeat(cen[:, None], e, axis=1).reshape(-1, 3)
    seg = np.repeat(np.arange(s - 1), e)
    edge = np.tile(np.arange(e), s - 1)
    two = np.concatenate
    return tris, two([cen, cen]), two([seg, seg]), two([edge, edge])


def _cap(x: float, ring, inward: float) -> np.ndarray:
    """Fan triangles closing a ring at station ``x``; ``inward`` = direction (+1/-1) to the
    body's inside (for the normal's reference point). Returns (tris, centre)."""
    ring = np.asarray(ring, np.float64)
    k = len(ring)
    cy, cz = ring.mean(axis=0)
    pts = np.column_stack([np.full(k, x), ring])
    c = np.array([x, cy, cz])
    tris = np.stack([np.repeat(c[None], k, 0), pts, np.roll(pts, -1, axis=0)], axis=1)
    return tris, np.array([x + inward, cy, cz])


def _bevel_ring(w: float, zb: float, zt: float, bev: float, sh: float) -> list:
    """8-point section: bevelled sill (``bev``) and rounded shoulder (``sh``)."""
    sh = min(sh, 0.45 * (zt - zb))
    bev = min(bev, 0.3 * (zt - zb))
    return [(-w + bev, zb), (-w, zb + bev), (-w, zt - sh), (-w + 1.3 * sh, zt),
            (w - 1.3 * sh, zt), (w, zt - sh), (w, zb + bev), (w - bev, zb)]


def _solid(xs, rings, color, material) -> Mesh:
    """A closed loft with end caps."""
    tris, cen, _, _ = _loft(xs, rings)
    c0, r0 = _cap(xs[0], rings[0], +1.0)
    c1, r1 = _cap(xs[-1], rings[-1], -1.0)
    tris = np.concatenate([tris, c0, c1])
    cen = np.concatenate([cen, np.repeat(r0[None], len(c0), 0), np.repeat(r1[None], len(c1), 0)])
    return _mesh(tris, color, centre=cen, material=material)


# --------------------------------------------------------------------------- details
def _disc(cx: float, y: float, cz: float, radius: float, color, material, sides: int = 10,
          side: float = 1.0) -> Mesh:
    """A flat disc facing ±y (``side``) at (cx, y, cz)."""
    a = np.arange(sides) * (2 * np.pi / sides)
    ring = np.column_stack([cx + radius * np.cos(a), np.full(sides, y), cz + radius * np.sin(a)])
    c = np.array([cx, y, cz])
    tris = np.stack([np.repeat(c[None], sides, 0), ring, np.roll(ring, -1, axis=0)], axis=1)
    return _mesh(tris, color, centre=(cx, y - side, cz), material=material)


def _face_x(x: float, y0: float, y1: float, z0: float, z1: float, color, sign: float,
            emissive: float = 0.0, material: int | None = None) -> Mesh:
    """A flat quad across the vehicle at ``x`` facing ``sign`` · x (lamps, plates, grilles:
    details on an end face need no sides)."""
    q = np.array([[x, y0, z0], [x, y1, z0], [x, y1, z1], [x, y0, z1]])
    return _mesh(np.stack([q[[0, 1, 2]], q[[0, 2, 3]]]), color, emissive,
                 centre=(x - sign, 0.5 * (y0 + y1), 0.5 * (z0 + z1)), material=material)


def _face_y(y: float, x0: float, x1: float, z0: float, z1: float, color, sign: float,
            material: int | None = None) -> Mesh:
    """A flat quad along the vehicle at ``y`` facing ``sign`` · y (side windows, strips)."""
    q = np.array([[x0, y, z0], [x1, y, z0], [x1, y, z1], [x0, y, z1]])
    return _mesh(np.stack([q[[0, 1, 2]], q[[0, 2, 3]]]), color,
                 centre=(0.5 * (x0 + x1), y - sign, 0.5 * (z0 + z1)), material=material)


def _tyre(cx: float, cy: float, r: float, w: float, sides: int = 10) -> Mesh:
    """``meshes.wheel`` without the cap that faces the vehicle's centre (never seen)."""
    m = wheel(cx, cy, r, w, sides)
    if cy == 0.0:
        return m
    y_in = cy - np.sign(cy) * w / 2
    tri_y = m.positions[:, 1].reshape(-1, 3)
    keep = np.repeat(~(np.abs(tri_y - y_in) < 1e-6).all(axis=1), 3)
    return Mesh(m.positions[keep], m.normals[keep], m.colors[keep])


def _arch(xw: float, y: float, r: float, zb: float, ztop: float, side: float) -> Mesh:
    """A dark wheel well on the body side at y (facing ``side``): half disc of radius
    r + 6 cm above the axle, a rectangle down to the sill."""
    ra = r + 0.06
    top = min(ra, max(ztop - r - 0.02, 0.05))
    a = np.linspace(0.0, np.pi, 9)
    arc = np.column_stack([xw + ra * np.cos(a), np.full(9, y), r + top * np.sin(a)])
    c = np.array([xw, y, r])
    tris = [np.stack([np.repeat(c[None], 8, 0), arc[:-1], arc[1:]], axis=1)]
    z0 = min(zb, r)
    q = np.array([[xw - ra, y, z0], [xw + ra, y, z0], [xw + ra, y, r], [xw - ra, y, r]])
    tris.append(np.stack([q[[0, 1, 2]], q[[0, 2, 3]]]))
    return _mesh(np.concatenate(tris), ARCH, centre=(xw, y - side, r), material=MAT_TYRE)


def _wheel_set(xs, W: float, r: float, tyre_w: float, zb: float, ztop: float,
               rim=RIM) -> list[Mesh]:
    """Tyres (outer face at W/2 + 1 cm), arches behind them and rims (colour ``rim``)."""
    parts: list[Mesh] = []
    yo = W / 2 - tyre_w / 2 + 0.01
    for x in xs:
        for s in (-1.0, 1.0):
            parts.append(_arch(x, s * (W / 2 + 0.003), r, zb, ztop, s))
            parts.append(_tyre(x, s * yo, r, tyre_w))
            parts.append(_disc(x, s * (W / 2 + 0.013), r, 0.6 * r, rim, MAT_METAL, 8, side=s))
    return parts


def _caster_wheels(xs, W: float, r: float, tyre_w: float) -> list[Mesh]:
    """Shadow casters of the tyres of ``_wheel_set``: one box per tyre (its bounding box,
    lifted like ``meshes.wheel``'s flat bottom edge)."""
    yo = W / 2 - tyre_w / 2 + 0.01
    z0 = r * (1.0 - np.cos(np.pi / 10))
    return [box((x - r, s * yo - tyre_w / 2, z0), (x + r, s * yo + tyre_w / 2, 2 * r), TYRE,
                material=MAT_TYRE) for x in xs for s in (-1.0, 1.0)]


def _front_back(L: float, w_end: float, zl0: float, zl1: float, zp: float, lamp_w: float,
                lamp_gap: float = 0.06, grille: tuple | None = None,
                tail_bar: bool = False) -> list[Mesh]:
    """Lamps (head white, tail red: a pair, or one light bar across the back when
    ``tail_bar``), plates and a grille on the end faces at x = ±L/2 (each protruding
    ≤ 1.5 cm)."""
    parts: list[Mesh] = []
    yo = w_end - lamp_gap - lamp_w / 2
    for front in (True, False):
        sgn = 1.0 if front else -1.0
        col = HEADLIGHT if front else TAILLIGHT
        if tail_bar and not front:
            zb0 = max(zl0, zl1 - 0.08)
            parts.append(_face_x(-(L / 2 + 0.008), -(yo + lamp_w / 2), yo + lamp_w / 2, zb0,
                                 zl1, col, -1.0, 1.0))
        else:
            for s in (-1.0, 1.0):
                parts.append(_face_x(sgn * (L / 2 + 0.008), s * yo - lamp_w / 2,
                                     s * yo + lamp_w / 2, zl0, zl1, col, sgn, 1.0))
        pw = min(0.26, 0.3 * w_end)
        parts.append(_face_x(sgn * (L / 2 + 0.011), -pw, pw, zp, zp + 0.12, PLATE, sgn,
                             material=MAT_LIT))
    if grille is not None:
        gy, gz0, gz1 = grille
        parts.append(_face_x(L / 2 + 0.006, -gy, gy, gz0, gz1, GRILLE, 1.0))
    return parts


# --------------------------------------------------------------------------- cars
_GREENHOUSE = {  # windscreen rake, rear rake (shares of the greenhouse height), roof taper
    "sedan": (0.75, 0.65, 0.12),
    "coupe": (0.85, 0.9, 0.13),
    "hatchback": (0.7, 0.25, 0.11),
    "suv": (0.5, 0.15, 0.09),
    "van": (0.4, 0.06, 0.06),
    "pickup": (0.55, 0.08, 0.09),
}


def car_mesh(body, L, W, H, wb, r, clear, hood, c0, c1, belt, paint,
             detail: bool = True, trim: tuple = DEFAULT_TRIM) -> Mesh:
    """A rounded car of class ``body`` (sedan, hatchback, suv, coupe, van, pickup, or
    anything else treated as a sedan) inside L × W × H metres, in its ``trim``
    (``DEFAULT_TRIM``'s fields: a two-tone or glass roof or roof rails, dark rims, tinted
    windows, a tail light bar, dark cladding on the sills and bumpers).

    ``detail=False`` gives its shadow caster (``shadow_caster_mesh``): the same body,
    greenhouse and bed walls, tyres as boxes, and none of the parts that lie within
    1.5 cm of the body (pillars, lamps, plates, grille, bumper strips, arches, rims,
    the inset rear window)."""
    roof, rims, tint, tail, cladding, _ = trim
    glass_col = GLASS_TINTED if tint == "tinted" else GLASS
    Hc = H - RAIL_M if roof == "rails" else H  # the roof's height (rails reach H)
    zb = clear
    zbelt = min(max(zb + 0.25, belt * Hc), Hc - 0.3)
    rf, rr, taper = _GREENHOUSE.get(body, _GREENHOUSE["sedan"])
    w = W / 2
    # lower body: stations rear → front; the hood drops to the nose, the boot to the tail
    drop_f = 0.16 if body not in ("van", "suv") else 0.1
    drop_r = 0.10 if body in ("sedan", "coupe") else 0.05
    e1, e2 = min(0.14, 0.05 * L), min(0.45, 0.12 * L)
    xs = np.array([-L / 2, -L / 2 + e1, -L / 2 + e2, L / 2 - e2, L / 2 - e1, L / 2])
    tops = zbelt - np.array([drop_r, 0.4 * drop_r, 0.0, 0.0, 0.45 * drop_f, drop_f])
    bots = zb + np.array([0.1, 0.03, 0.0, 0.0, 0.03, 0.1])
    wid = w - np.array([0.12, 0.03, 0.0, 0.0, 0.03, 0.12])
    rings = [_bevel_ring(wi, b, t, 0.06, 0.09) for wi, b, t in zip(wid, bots, tops, strict=True)]
    parts = [_solid(xs, rings, paint, MAT_PAINT)]
    # greenhouse: from cabin_end (rear) to cabin_start (front), fractions from the front
    xf = L / 2 - min(max(c0, hood, 0.03), 0.6) * L
    xr = L / 2 - min(max(c1, c0 + 0.25), 0.99) * L
    xr = max(xr, -L / 2 + 0.05)
    gh = Hc - zbelt
    span = xf - xr
    lf = min(rf * gh * 1.2, 0.4 * span)
    lr = min(rr * gh * 1.2, 0.35 * span)
    wt = w - 0.03 - taper * W / 2
    # (x, height fraction): curved windscreen and rear window
    prof = [(xr, 0.04), (xr + 0.5 * lr, 0.7), (xr + lr, 1.0), (xf - lf, 1.0),
            (xf - 0.55 * lf, 0.78), (xf, 0.04)]
    if lr < 0.08:
        prof = [(xr, 1.0), *prof[3:]]
    gx = np.array([p[0] for p in prof])
    gz = zbelt + gh * np.array([p[1] for p in prof])
    grings = []
    for z in gz:
        rail = min(0.07, 0.3 * (z - zbelt))
        wz = w - 0.03 - (w - 0.03 - wt) * (z - zbelt) / gh
        grings.append([(-(w - 0.03), zbelt - 0.01), (-wz, z - rail), (-wz + 0.04, z),
                       (wz - 0.04, z), (wz, z - rail), (w - 0.03, zbelt - 0.01)])
    tris, cen, seg, edge = _loft(gx, grings, closed=False)
    roof_seg = np.array([abs(gz[i] - Hc) < 1e-9 and abs(gz[i + 1] - Hc) < 1e-9
                         for i in range(len(gx) - 1)])
    on_roof = (edge >= 1) & (edge <= 3) & roof_seg[seg]  # the roof and its rounded edges
    glass = (edge == 0) | (edge == 4) | ((edge == 2) & ~roof_seg[seg])
    if roof == "glass":
        glass = glass | on_roof
    painted = ~glass
    if roof in ROOF_COLORS:
        painted = painted & ~on_roof
        parts.append(_mesh(tris[on_roof], ROOF_COLORS[roof], centre=cen[on_roof],
                           material=MAT_PAINT))
    parts.append(_mesh(tris[glass], glass_col, centre=cen[glass], material=MAT_GLASS))
    parts.append(_mesh(tris[painted], paint, centre=cen[painted], material=MAT_PAINT))
    if roof == "rails":  # two dark rails along the roof's edges, RAIL_M tall
        yr = wt - 0.04 - 0.06
        for s in (-1.0, 1.0):
            parts.append(box((xr + lr + 0.05, s * yr - 0.025, Hc - 0.01),
                             (xf - lf - 0.05, s * yr + 0.025, H), TRIM))
    # end caps of the greenhouse (flat-backed vans/pickups: a glass rear window panel)
    for x, rg, inward in ((gx[0], grings[0], 1.0), (gx[-1], grings[-1], -1.0)):
        ct, cc = _cap(x, rg, inward)
        parts.append(_mesh(ct, paint, centre=cc, material=MAT_PAINT))
    if lr < 0.08 and detail:  # near-vertical back: rear window inset in the painted panel
        parts.append(box((xr - 0.012, -0.7 * wt, zbelt + 0.25 * gh), (xr + 0.01, 0.7 * wt,
                         zbelt + 0.85 * gh), glass_col, material=MAT_GLASS))
    # pillars: B (and C for long cabins) as thin painted slabs across the greenhouse
    n_p = (2 if span > 2.6 else 1) if detail else 0
    for j in range(n_p):
        xm = xr + lr + (j + 1) * (xf - lf - xr - lr) / (n_p + 1)
        zt = Hc - 0.03
        wz = w - 0.03 - (w - 0.03 - wt) * (zt - zbelt) / gh + 0.006  # follows the taper
        yb = w - 0.025
        parts.append(hexahedron(np.array(
            [[xm - 0.06, -yb, zbelt], [xm + 0.06, -yb, zbelt], [xm + 0.06, yb, zbelt],
             [xm - 0.06, yb, zbelt], [xm - 0.06, -wz, zt], [xm + 0.06, -wz, zt],
             [xm + 0.06, wz, zt], [xm - 0.06, wz, zt]]), paint, material=MAT_PAINT))
    if body == "pickup" and xr > -L / 2 + 0.5:  # open bed walls behind the cab
        parts.append(box((-L / 2 + 0.1, -w + 0.02, tops[2]), (xr, -w + 0.1, tops[2] + 0.3),
                         paint, material=MAT_PAINT))
        parts.append(box((-L / 2 + 0.1, w - 0.1, tops[2]), (xr, w - 0.02, tops[2] + 0.3),
                         paint, material=MAT_PAINT))
    if not detail:
        return Mesh.concat([*parts, *_caster_wheels([wb / 2, -wb / 2], W, r, 0.24)])
    # bumpers: dark strips low on both ends; lamps, plates, grille
    bumper = 0.2 if cladding else 0.1
    for sgn in (-1.0, 1.0):
        parts.append(_face_x(sgn * (L / 2 + 0.004), -(w - 0.14), w - 0.14, bots[0],
                             bots[0] + bumper, TRIM, sgn))
        if cladding:  # dark sills between the wheel arches
            parts.append(_face_y(sgn * (w + 0.004), -wb / 2 + r + 0.06, wb / 2 - r - 0.06,
                                 zb + 0.05, zb + 0.2, TRIM, sgn))
    zl1 = tops[-1] - 0.05
    zl0 = max(zl1 - 0.16, bots[-1] + 0.2)
    zp = bots[0] + 0.13 + (0.06 if cladding else 0.0)
    parts += _front_back(L, wid[0], zl0, zl1, zp, 0.3, 0.05,
                         grille=(0.3 * W, zp + 0.13, max(zp + 0.2, zl0)),
                         tail_bar=tail == "bar")
    parts += _wheel_set([wb / 2, -wb / 2], W, r, 0.24, zb, tops[2],
                        rim=RIM_DARK if rims == "dark" else RIM)
    return Mesh.concat(parts)


# --------------------------------------------------------------------------- trucks, buses
def big_vehicle_mesh(body, L, W, H, wb, r, clear, c1, paint, detail: bool = True,
                     trim: tuple = DEFAULT_TRIM) -> Mesh:
    """A bus (rounded box, glazed window band, big windscreen) or a truck (rounded cab,
    cargo box, chassis), inside L × W × H metres; of its ``trim`` only the rims apply.

    ``detail=False`` gives its shadow caster: the body solids and the chassis, tyres as
    boxes, none of the glass panels, strips, lamps, plates, grilles, arches and rims that
    lie within 1.5 cm of the body."""
    w = W / 2
    zb = max(clear, 0.3)
    parts: list[Mesh] = []
    if body == "bus":
        xs = np.array([-L / 2, -L / 2 + 0.12, L / 2 - 0.15, L / 2])
        rings = [_bevel_ring(w - d, zb + 0.05 * (d > 0.05), H - 0.06 * (d > 0.05), 0.06, 0.22)
                 for d in (0.06, 0.0, 0.0, 0.08)]
        parts.append(_solid(xs, rings, paint, MAT_PAINT))
        zw0, zw1 = 0.42 * H, 0.86 * H
        if detail:
            for s in (-1.0, 1.0):
                parts.append(_face_y(s * (w + 0.008), -L / 2 + 0.4, L / 2 - 1.0, zw0, zw1, GLASS,
                                     s, MAT_GLASS))
                parts.append(_face_y(s * (w + 0.006), -L / 2 + 0.2, L / 2 - 0.2, zb, zb + 0.25,
                                     TRIM, s))
                # door: glass down to the step, behind the front axle
                parts.append(_face_y(s * (w + 0.01), wb / 2 + r + 0.15,
                                     min(wb / 2 + r + 1.2, L / 2 - 0.3), zb + 0.1, zw1, GLASS, s,
                                     MAT_GLASS))
            parts.append(box((L / 2 - 0.02, -(w - 0.15), 0.32 * H), (L / 2 + 0.012, w - 0.15,
                             0.93 * H), GLASS, material=MAT_GLASS))
            parts.append(box((-L / 2 - 0.012, -(w - 0.3), 0.58 * H), (-L / 2 + 0.02, w - 0.3,
                             0.86 * H), GLASS, material=MAT_GLASS))
        zl = zb + 0.25
        axles = [wb / 2, -wb / 2]
        ztop = zw0
        if detail:
            parts += _front_back(L, w - 0.08, zl, zl + 0.22, zb + 0.08, 0.32, 0.1)
    else:  # truck: rounded cab at the front, cargo box behind, dark chassis under it
        cab_l = c1 * L if 0.1 < c1 < 0.6 else min(2.3, 0.35 * L)
        zcab = min(H, max(2.4, 0.8 * H))
        xs = np.array([L / 2 - cab_l, L / 2 - 0.18, L / 2])
        rings = [_bevel_ring(w - d, zb + 0.06 * (d > 0), zcab - 0.08 * (d > 0), 0.06, 0.25)
                 for d in (0.0, 0.0, 0.1)]
        parts.append(_solid(xs, rings, paint, MAT_PAINT))
        if detail:
            parts.append(box((L / 2 - 0.02, -(w - 0.2), 0.55 * zcab), (L / 2 + 0.01, w - 0.2,
                             0.88 * zcab), GLASS, material=MAT_GLASS))
            for s in (-1.0, 1.0):
                parts.append(_face_y(s * (w + 0.008), L / 2 - cab_l + 0.3, L / 2 - 0.35,
                                     0.55 * zcab, 0.86 * zcab, GLASS, s, MAT_GLASS))
        cargo = 0.55 * paint + 0.45 * np.array([0.9, 0.9, 0.88])
        xc = np.array([-L / 2, -L / 2 + 0.05, L / 2 - cab_l - 0.15, L / 2 - cab_l - 0.1])
        crings = [_bevel_ring(w - d, zb + 0.35, H - d, 0.02, 0.06) for d in (0.03, 0, 0, 0.03)]
        parts.append(_solid(xc, crings, cargo, MAT_LIT))
        parts.append(box((-L / 2 + 0.3, -(w - 0.12), zb), (L / 2 - 0.3, w - 0.12, zb + 0.36),
                         GRILLE))
        zl = zb + 0.3
        axles = [wb / 2, -wb / 2] + ([-wb / 2 + 2.2 * r] if L > 8.0 else [])
        ztop = zb + 0.35 + 0.5
        if detail:
            parts += _front_back(L, w - 0.1, zl, zl + 0.25, zb + 0.06, 0.3, 0.08,
                                 grille=(0.3 * W, zl + 0.3, min(0.5 * zcab, zl + 0.9)))
    if not detail:
        return Mesh.concat([*parts, *_caster_wheels(axles, W, r, 0.32)])
    parts += _wheel_set(axles, W, r, 0.32, zb, ztop, rim=RIM_DARK if trim[1] == "dark" else RIM)
    return Mesh.concat(parts)


# --------------------------------------------------------------------------- two-wheelers
def _ring_wheel(cx: float, r: float, tw: float, spokes: int = 6, sides: int = 12,
                rim=RIM) -> Mesh:
    """A see-through bicycle wheel: a tyre ring (outer r, inner 0.86 r) and thin spokes
    (colour ``rim``)."""
    a = np.arange(sides) * (2 * np.pi / sides) + np.pi / sides  # flat edge at the bottom
    j = (np.arange(sides) + 1) % sides
    parts = []
    ri = 0.86 * r
    for y in (-tw / 2, tw / 2):
        o = np.column_stack([cx + r * np.cos(a), np.full(sides, y), r + r * np.sin(a)])
        i = np.column_stack([cx + ri * np.cos(a), np.full(sides, y), r + ri * np.sin(a)])
        tris = np.concatenate([np.stack([o, o[j], i[j]], 1), np.stack([o, i[j], i], 1)])
        parts.append(_mesh(tris, TYRE, centre=(cx, -np.sign(y), r), material=MAT_TYRE))
    o = np.column_stack([cx + r * np.cos(a), r + r * np.sin(a)])
    y0, y1 = -tw / 2, tw / 2
    q0 = np.column_stack([o[:, 0], np.full(sides, y0), o[:, 1]])
    q1 = np.column_stack([o[:, 0], np.full(sides, y1), o[:, 1]])
    tread = np.concatenate([np.stack([q0, q0[j], q1[j]], 1), np.stack([q0, q1[j], q1], 1)])
    parts.append(_mesh(tread, TYRE, centre=(cx, 0.0, r), material=MAT_TYRE))
    for k in range(spokes):
        t = k * np.pi / spokes
        d = np.array([np.cos(t), 0.0, np.sin(t)]) * ri
        n = np.array([-np.sin(t), 0.0, np.cos(t)]) * 0.006
        c = np.array([cx, 0.0, r])
        q = np.array([c - d - n, c + d - n, c + d + n, c - d + n])
        for yy in (-0.004, 0.004):
            qq = q + np.array([0.0, yy, 0.0])
            parts.append(_mesh(np.stack([qq[[0, 1, 2]], qq[[0, 2, 3]]]), rim,
                               centre=(cx, -np.sign(yy), r), material=MAT_METAL))
    parts.append(_disc(cx, 0.0, r, 0.05, GRILLE, MAT_METAL, 6))
    return Mesh.concat(parts)


def two_wheeler_mesh(body, L, W, H, wb, r, paint, detail: bool = True,
                     trim: tuple = DEFAULT_TRIM) -> Mesh:
    """A motorcycle (fairing, tank, rims, helmeted rider) or a bicycle (spoked wheels,
    frame, rider), inside L × W × H metres (the rider's head may reach H + 0.45 m, as the
    catalog's two-wheeler height is the vehicle's); of its ``trim`` the rims (a
    motorcycle's) and the rider's jacket apply.

    ``detail=False`` gives its shadow caster: a motorcycle's tyres become boxes and its
    rims go; a bicycle keeps everything (its see-through wheels have no solid proxy)."""
    tw = 0.12 if body == "motorcycle" else 0.04
    rim = RIM_DARK if trim[1] == "dark" else RIM
    jacket = RIDERS[trim[5]]
    r = min(r, 0.45 * H)
    xw = min(wb / 2, L / 2 - r)
    zf = r + 0.05
    parts: list[Mesh] = []
    if body == "motorcycle":
        for x in (xw, -xw):
            if not detail:
                parts.append(box((x - r, -tw / 2, 0.0), (x + r, tw / 2, 2 * r), TYRE,
                                 material=MAT_TYRE))
                continue
            parts.append(wheel(x, 0.0, r, tw, 14))
            for s in (-1.0, 1.0):
                parts.append(_disc(x, s * (tw / 2 + 0.003), r, 0.62 * r, rim, MAT_METAL, 10, s))
        # engine block (dark), tank + fairing (paint), seat (dark), exhaust (metal)
        parts.append(box((-0.25, -0.16, r - 0.05), (0.35, 0.16, zf + 0.2), GRILLE))
        xs = np.array([-xw + 0.05, -0.1, 0.25, xw - 0.12])
        rings = [_bevel_ring(hw, zb, zt, 0.03, 0.05) for hw, zb, zt in
                 ((0.1, zf + 0.25, zf + 0.42), (0.16, zf + 0.2, zf + 0.45),
                  (0.19, zf + 0.15, zf + 0.55), (0.17, zf + 0.1, zf + 0.72))]
        parts.append(_solid(xs, rings, paint, MAT_PAINT))
        parts.append(box((-xw + 0.05, -0.13, zf + 0.42), (0.05, 0.13, zf + 0.5), TRIM))
        parts.append(box((-xw - 0.05, 0.14, r - 0.05), (0.1, 0.22, r + 0.05), RIM,
                         material=MAT_METAL))
        parts.append(box((xw - 0.2, -0.05, r), (xw - 0.08, 0.05, zf + 0.6), GRILLE))  # fork
        parts.append(box((xw - 0.12, -0.09, zf + 0.45), (xw - 0.04, 0.09, zf + 0.6),
                         HEADLIGHT, 1.0))
        parts.append(box((-L / 2 + 0.05, -0.08, zf + 0.35), (-L / 2 + 0.12, 0.08, zf + 0.45),
                         TAILLIGHT, 1.0))
        parts.append(box((-L / 2 + 0.04, -0.08, zf + 0.18), (-L / 2 + 0.06, 0.08, zf + 0.3),
                         PLATE, material=MAT_LIT))
        seat = zf + 0.45
        head = HELMET
    else:
        parts += [_ring_wheel(xw, r, tw, rim=rim), _ring_wheel(-xw, r, tw, rim=rim)]
        parts.append(box((-xw, -0.02, r - 0.02), (0.0, 0.02, r + 0.03), paint,
                         material=MAT_PAINT))  # chain stay
        down = np.array([[-0.05, -0.02, r - 0.02], [0.02, -0.02, r - 0.02],
                         [0.02, 0.02, r - 0.02], [-0.05, 0.02, r - 0.02],
                         [xw - 0.1, -0.02, zf + 0.35], [xw - 0.03, -0.02, zf + 0.35],
                         [xw - 0.03, 0.02, zf + 0.35], [xw - 0.1, 0.02, zf + 0.35]])
        parts.append(hexahedron(down, paint, material=MAT_PAINT))  # down tube
        parts.append(box((-0.2, -0.02, zf + 0.3), (xw - 0.05, 0.02, zf + 0.36), paint,
                         material=MAT_PAINT))  # top tube
        parts.append(box((-0.12, -0.02, r), (-0.06, 0.02, zf + 0.4), paint,
                         material=MAT_PAINT))  # seat tube
        parts.append(box((xw - 0.06, -0.02, r), (xw - 0.02, 0.02, zf + 0.45), rim,
                         material=MAT_METAL))  # fork
        parts.append(box((xw - 0.12, -0.25, zf + 0.42), (xw - 0.04, 0.25, zf + 0.47), GRILLE))
        parts.append(box((-xw - 0.02, -0.04, r + 0.15), (-xw + 0.03, 0.04, r + 0.23),
                         TAILLIGHT, 1.0))
        seat = zf + 0.42
        head = RIDER_HEAD
    # rider: legs, torso leaning forward, head (helmet on a motorcycle), arms to the bars
    hip_x = -0.15
    parts.append(box((hip_x - 0.12, -0.2, seat - 0.35), (hip_x + 0.25, 0.2, seat + 0.05),
                     jacket))
    for s in (-1.0, 1.0):  # shins down to the pegs / pedals
        parts.append(box((hip_x + 0.15, s * 0.2 - 0.06, r - 0.05),
                         (hip_x + 0.27, s * 0.2 + 0.06, seat - 0.3), TRIM))
    top = max(H + 0.45, seat + 0.75)
    torso = np.array(
        [
            [hip_x - 0.15, -0.2, seat], [hip_x + 0.15, -0.2, seat],
            [hip_x + 0.15, 0.2, seat], [hip_x - 0.15, 0.2, seat],
            [hip_x + 0.0, -0.21, top - 0.25], [hip_x + 0.3, -0.21, top - 0.25],
            [hip_x + 0.3, 0.21, top - 0.25], [hip_x + 0.0, 0.21, top - 0.25],
        ]
    )
    parts.append(hexahedron(torso, jacket))
    hx = hip_x + 0.16
    hr = 0.13 if body == "motorcycle" else 0.11
    hrings = [_bevel_ring(hr * f, top - 0.26, top - 0.26 + 0.26 * g, 0.03, 0.06)
              for f, g in ((0.7, 0.8), (1.0, 1.0), (1.0, 1.0), (0.7, 0.8))]
    parts.append(_solid(np.array([hx - hr, hx - 0.5 * hr, hx + 0.5 * hr, hx + hr]), hrings,
                        head, MAT_LIT))
    for s in (-1.0, 1.0):
        parts.append(box((hip_x + 0.2, s * 0.21 - 0.04, top - 0.45),
                         (xw - 0.05, s * 0.21 + 0.04, top - 0.37), jacket))
    return Mesh.concat(parts)


# --------------------------------------------------------------------------- contact shadow
@lru_cache(maxsize=256)
def contact_shadow_mesh(length: float, width: float, body: str) -> Mesh:
    """The dark footprint under a vehicle (vehicle frame, 6 mm above the ground: below
    every tyre's lowest point): a soft outer band around a dark core under the body;
    two-wheelers get a narrow strip. ``colors``: r multiplies the road's albedo, g its
    sunlight (the shader's material ``MAT_SHADOW``). Drawn with instance id 0, so it
    never enters a label."""
    if body in ("motorcycle", "bicycle"):
        hl, hw = 0.42 * length, 0.16
    else:
        hl, hw = 0.5 * length - 0.04, 0.5 * width - 0.03
    parts = []
    for lo, wo, z, k in ((hl, hw, 0.006, (0.85, 0.35, 0.0)),
                         (hl - 0.25, hw - 0.18, 0.007, (0.6, 0.0, 0.0))):
        if lo <= 0 or wo <= 0:
            continue
        q = np.array([[-lo, -wo, z], [lo, -wo, z], [lo, wo, z], [-lo, wo, z]])
        parts.append(_mesh(np.stack([q[[0, 1, 2]], q[[0, 2, 3]]]), k, up=True,
                           material=MAT_SHADOW))
    return Mesh.concat(parts)
