"""OpenDRIVE plan-view geometry: reference lines and cubic profiles, vectorised.

Everything here works in the OpenDRIVE frame (x east, y north, heading counter-
clockwise from +x, radians) and in metres. The flip to CARLA's frame happens in
`dashtraj.roads.map`.

Supported `<geometry>` records (OpenDRIVE 1.4–1.8, §7.4 of 1.6):

- ``line``;
- ``arc`` (constant curvature);
- ``spiral`` (clothoid, curvature linear in s), integrated with Gauss–Legendre;
- ``poly3`` (v = a + b u + c u² + d u³ in the local frame), re-parametrised by arc length;
- ``paramPoly3`` (u(p), v(p) cubic; ``pRange`` ``normalized`` p ∈ [0, 1] or
  ``arcLength`` p ∈ [0, length]), re-parametrised by true arc length like CARLA.

Every evaluator maps an array of road s (metres from road start) to arrays x, y,
heading (rad) and curvature (1/m).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

# 24-point Gauss–Legendre nodes and weights on [-1, 1]: exact for polynomials of
# degree 47; used for the clothoid and for arc-length tables.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)


@dataclass(frozen=True, slots=True)
class Cubic:
    """A piecewise cubic profile f(s) = a + b ds + c ds² + d ds³, ds = s - start.

    Used for elevation, laneOffset and lane widths. `starts` are sorted, metres;
    `coeffs` is (K, 4) in the order a, b, c, d. Below the first start the first
    piece is extrapolated, as OpenDRIVE readers do.
    """

    starts: np.ndarray
    coeffs: np.ndarray

    @staticmethod
    def constant(value: float = 0.0) -> Cubic:
        return Cubic(np.zeros(1), np.array([[value, 0.0, 0.0, 0.0]]))

    @staticmethod
    def from_records(records: list[tuple[float, float, float, float, float]]) -> Cubic:
        """Build from (start, a, b, c, d) records; an empty list gives zero."""
        if not records:
            return Cubic.constant(0.0)
        if len(records) == 1:
            r = records[0]
            return Cubic(np.array([r[0]]), np.array([r[1:]], dtype=float))
        records = sorted(records, key=lambda r: r[0])
        arr = np.asarray(records, dtype=float)
        return Cubic(arr[:, 0].copy(), arr[:, 1:].copy())

    def _piece(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.searchsorted(self.starts, s, side="right") - 1
        np.maximum(i, 0, out=i)  # searchsorted never exceeds len(starts)
        return self.coeffs[i], s - self.starts[i]

    def __call__(self, s: np.ndarray | float) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        if len(self.starts) == 1 and not self.coeffs[0, 1:].any():
            return np.full(s.shape, self.coeffs[0, 0])
        c, ds = self._piece(s)
        return c[..., 0] + ds * (c[..., 1] + ds * (c[..., 2] + ds * c[..., 3]))

    def derivative(self, s: np.ndarray | float) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        if len(self.starts) == 1 and not self.coeffs[0, 1:].any():
            return np.zeros(s.shape)
        c, ds = self._piece(s)
        return c[..., 1] + ds * (2.0 * c[..., 2] + 3.0 * ds * c[..., 3])

    def value_and_derivative(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(f(s), f'(s)) with one piece lookup."""
        s = np.asarray(s, dtype=float)
        if len(self.starts) == 1:
            a, b, c, d = self.coeffs[0]
            if not (b or c or d):
                return np.full(s.shape, a), np.zeros(s.shape)
            ds = s - self.starts[0]
            return (a + ds * (b + ds * (c + ds * d)), b + ds * (2.0 * c + 3.0 * ds * d))
        co, ds = self._piece(s)
        a, b, c, d = co[..., 0], co[..., 1], co[..., 2], co[..., 3]
        return a + ds * (b + ds * (c + ds * d)), b + ds * (2.0 * c + 3.0 * ds * d)

    @property
    def is_zero(self) -> bool:
        return not self.coeffs.any()


@dataclass(frozen=True, slots=True)
class Geometry:
    """One `<geometry>` record of a plan view.

    `kind` is "line", "arc", "spiral", "poly3" or "paramPoly3"; `params` holds the
    kind's attributes (curvature; curvStart/curvEnd; a..d; aU..dV and pRange).
    """

    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str
    params: dict = field(default_factory=dict)


def _arc_length_table(du, dv, p_end: float, n: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative arc length of a planar curve with derivative (du(p), dv(p)).

    Returns parameters p (n+1,) on [0, p_end] and arc lengths (n+1,), each
    interval integrated with 24-point Gauss–Legendre (error ≪ 1 µm for cubics).
    """
    p = np.linspace(0.0, p_end, n + 1)
    h = p_end / n
    mid = 0.5 * (p[:-1] + p[1:])
    nodes = mid[:, None] + 0.5 * h * _GL_X[None, :]
    speed = np.hypot(du(nodes), dv(nodes))
    seg = 0.5 * h * (speed @ _GL_W)
    return p, np.concatenate([[0.0], np.cumsum(seg)])


def _invert_arc_length(target: np.ndarray, ptab: np.ndarray, arc: np.ndarray, speed,
                       iterations: int = 3) -> np.ndarray:
    """Parameter p whose arc length from 0 is `target`, to well under a micrometre.

    Starts from the table, then Newton steps whose residual integrates the exact
    speed from the nearest table node to p (24-point Gauss–Legendre).
    """
    p = np.interp(target, arc, ptab)
    for _ in range(iterations):
        i = np.clip(np.searchsorted(ptab, p, side="right") - 1, 0, len(ptab) - 2)
        p0 = ptab[i]
        half = 0.5 * (p - p0)
        nodes = (p0 + half)[:, None] + half[:, None] * _GL_X[None, :]
        length = arc[i] + half * (speed(nodes) @ _GL_W)
        sp = speed(p)
        p = p + np.where(sp > 1e-12, (target - length) / np.maximum(sp, 1e-12), 0.0)
    return p


class PlanView:
    """A road's reference line: the sequence of its `<geometry>` records.

    `evaluate(s)` returns (x, y, hdg, curvature) arrays in the OpenDRIVE frame.
    s outside [0, length] is clamped onto the nearest record and extrapolated
    along it.
    """

    def __init__(self, geometries: list[Geometry]):
        if not geometries:
            raise ValueError("a plan view needs at least one geometry")
        self.geometries = list(geometries)
        self.starts = np.array([g.s for g in self.geometries])
        self.length = float(self.geometries[-1].s + self.geometries[-1].length)
        self._tables: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        # Lines and arcs only (most roads): evaluate all records in one vectorised pass.
        self._lines_arcs = len(self.geometries) > 1 and all(
            g.kind in ("line", "arc") for g in self.geometries)
        if self._lines_arcs:
            k = np.array([g.params["curvature"] if g.kind == "arc" else 0.0
                          for g in self.geometries])
            k[np.abs(k) < 1e-12] = 0.0  # read as lines, as `_eval_one` does
            hdg = np.array([g.hdg for g in self.geometries])
            self._la = (np.array([g.x for g in self.geometries]),
                        np.array([g.y for g in self.geometries]), hdg, k,
                        np.cos(hdg), np.sin(hdg), np.where(k == 0.0, 1.0, k))

    def evaluate(self, s: np.ndarray | float) -> tuple[np.ndarray, ...]:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        if len(self.geometries) == 1:
            return self._eval_one(0, s - self.starts[0])
        idx = np.searchsorted(self.starts, s, side="right") - 1
        np.clip(idx, 0, len(self.geometries) - 1, out=idx)
        out = [np.empty_like(s) for _ in range(4)]
        for i in np.unique(idx):
            m = idx == i
            vals = self._eval_one(int(i), s[m] - self.starts[i])
            for o, v in zip(out, vals, strict=True):
                o[m] = v
        return tuple(out)

    def evaluate_sorted(self, s: np.ndarray) -> tuple[np.ndarray, ...]:
        """`evaluate` for s sorted ascending: contiguous slices per record, no masks."""
        if len(self.geometries) == 1:
            return self._eval_one(0, s - self.starts[0])
        cuts = np.searchsorted(s, self.starts[1:], side="left")
        if self._lines_arcs:
            bounds = np.empty(len(cuts) + 2, dtype=np.int64)
            bounds[0], bounds[1:-1], bounds[-1] = 0, cuts, len(s)
            gi = np.repeat(np.arange(len(self.geometries)), bounds[1:] - bounds[:-1])
            x0, y0, hdg, k, cos0, sin0, k_div = (a[gi] for a in self._la)
            ds = s - self.starts[gi]
            h = hdg + k * ds
            arc = k != 0.0
            x = np.where(arc, x0 + (np.sin(h) - sin0) / k_div, x0 + ds * cos0)
            y = np.where(arc, y0 - (np.cos(h) - cos0) / k_div, y0 + ds * sin0)
            return x, y, h, k
        bounds = [0, *cuts.tolist(), len(s)]
        parts = [self._eval_one(i, s[a:b] - self.starts[i])
                 for i, (a, b) in enumerate(itertools.pairwise(bounds)) if b > a]
        return tuple(np.concatenate([pt[j] for pt in parts]) for j in range(4))

    # -- one record ---------------------------------------------------------------
    def _eval_one(self, i: int, ds: np.ndarray) -> tuple[np.ndarray, ...]:
        g = self.geometries[i]
        kind = g.kind
        if kind == "line":
            c, sn = np.cos(g.hdg), np.sin(g.hdg)
            return g.x + ds * c, g.y + ds * sn, np.full_like(ds, g.hdg), np.zeros_like(ds)
        if kind == "arc":
            k = g.params["curvature"]
            if abs(k) < 1e-12:
                return self._line(g, ds)
            h = g.hdg + k * ds
            x = g.x + (np.sin(h) - np.sin(g.hdg)) / k
            y = g.y - (np.cos(h) - np.cos(g.hdg)) / k
            return x, y, h, np.full_like(ds, k)
        if kind == "spiral":
            return self._spiral(g, ds)
        if kind == "poly3":
            return self._poly3(i, g, ds)
        if kind == "paramPoly3":
            return self._param_poly3(i, g, ds)
        raise ValueError(f"unknown geometry kind {kind!r}")

    @staticmethod
    def _line(g: Geometry, ds: np.ndarray) -> tuple[np.ndarray, ...]:
        c, sn = np.cos(g.hdg), np.sin(g.hdg)
        return g.x + ds * c, g.y + ds * sn, np.full_like(ds, g.hdg), np.zeros_like(ds)

    @staticmethod
    def _spiral(g: Geometry, ds: np.ndarray) -> tuple[np.ndarray, ...]:
        # Clothoid: curvature k(t) = k0 + c t, heading h(t) = h0 + k0 t + c t²/2.
        k0 = g.params["curvStart"]
        k1 = g.params["curvEnd"]
        c = (k1 - k0) / g.length if g.length > 0 else 0.0
        # Panels so that each spans at most ~0.5 rad of heading change.
        total_turn = abs(k0) * g.length + 0.5 * abs(c) * g.length**2
        panels = max(1, int(np.ceil(total_turn / 0.5)))
        frac = (np.arange(panels)[:, None] + 0.5 * (_GL_X[None, :] + 1.0)) / panels  # (P,24)
        t = ds[:, None, None] * frac[None, :, :]
        h = g.hdg + k0 * t + 0.5 * c * t * t
        w = (0.5 / panels) * _GL_W[None, None, :]
        x = g.x + ds * np.sum(np.cos(h) * w, axis=(1, 2))
        y = g.y + ds * np.sum(np.sin(h) * w, axis=(1, 2))
        hd = g.hdg + k0 * ds + 0.5 * c * ds * ds
        return x, y, hd, k0 + c * ds

    def _table(self, i: int, du, dv, p_end: float) -> tuple[np.ndarray, np.ndarray]:
        if i not in self._tables:
            self._tables[i] = _arc_length_table(du, dv, p_end)
        return self._tables[i]

    def _poly3(self, i: int, g: Geometry, ds: np.ndarray) -> tuple[np.ndarray, ...]:
        a, b, c, d = (g.params[k] for k in ("a", "b", "c", "d"))

        def dv(u):
            return b + u * (2 * c + 3 * d * u)

        # The local u range is not stored; grow it until the arc length covers `length`.
        u_end = g.length
        p, arc = self._table(i, lambda u: np.ones_like(u), dv, u_end)
        while arc[-1] < g.length and u_end < 1e6:
            u_end *= 1.5
            self._tables.pop(i)
            p, arc = self._table(i, lambda u: np.ones_like(u), dv, u_end)
        u = _invert_arc_length(ds, p, arc, lambda q: np.hypot(1.0, dv(q)))
        v = a + u * (b + u * (c + d * u))
        dvu = dv(u)
        ddv = 2 * c + 6 * d * u
        return self._local_to_world(g, u, v, 1.0, dvu, 0.0, ddv)

    def _param_poly3(self, i: int, g: Geometry, ds: np.ndarray) -> tuple[np.ndarray, ...]:
        P = g.params
        au, bu, cu, du_ = P["aU"], P["bU"], P["cU"], P["dU"]
        av, bv, cv, dv_ = P["aV"], P["bV"], P["cV"], P["dV"]
        p_end = 1.0 if P.get("pRange", "normalized") == "normalized" else g.length
        if p_end <= 0:
            p_end = 1.0

        def dU(p):
            return bu + p * (2 * cu + 3 * du_ * p)

        def dV(p):
            return bv + p * (2 * cv + 3 * dv_ * p)

        ptab, arc = self._table(i, dU, dV, p_end)
        # Arc lengths beyond the table are mapped linearly (scaled to the stated length).
        scale = arc[-1] / g.length if g.length > 0 else 1.0
        target = ds * scale
        p = _invert_arc_length(target, ptab, arc, lambda q: np.hypot(dU(q), dV(q)))
        u = au + p * (bu + p * (cu + du_ * p))
        v = av + p * (bv + p * (cv + dv_ * p))
        return self._local_to_world(
            g, u, v, dU(p), dV(p), 2 * cu + 6 * du_ * p, 2 * cv + 6 * dv_ * p
        )

    @staticmethod
    def _local_to_world(g, u, v, du, dv, ddu, ddv) -> tuple[np.ndarray, ...]:
        c, s = np.cos(g.hdg), np.sin(g.hdg)
        x = g.x + u * c - v * s
        y = g.y + u * s + v * c
        du = np.broadcast_to(du, np.shape(u))
        ddu = np.broadcast_to(ddu, np.shape(u))
        h = g.hdg + np.arctan2(dv, du)
        speed2 = du * du + dv * dv
        k = (du * ddv - dv * ddu) / np.maximum(speed2, 1e-18) ** 1.5
        return x, y, h, k
