"""Plan-view geometry against independent closed forms and numerical integration.

Every geometry kind is checked twice: through `PlanView` directly and through a
one-road map read with `RoadMap.from_string` (the reference line is the centre
of a lane pair of equal widths, so lane -1 and lane 1 average to it).
OpenDRIVE frame here (x east, y north, heading counter-clockwise, radians).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, optimize, special

from dashtraj.roads import RoadMap
from dashtraj.roads.planview import Cubic, Geometry, PlanView

POS_TOL_M = 1e-6
HDG_TOL = 1e-9


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _reference_from_map(m: RoadMap, rid: int, s: np.ndarray):
    """OpenDRIVE-frame reference line (x, y) of a road with lanes ±1 of equal width."""
    xl, yl, _, _ = m._lane_pose((rid, 0, 1), s)
    xr, yr, _, _ = m._lane_pose((rid, 0, -1), s)
    return 0.5 * (xl + xr), -0.5 * (yl + yr)  # CARLA y flipped back


# --- line and arc -------------------------------------------------------------------------


def test_line_positions_and_heading():
    pv = PlanView([Geometry(0.0, 1.0, 2.0, 0.3, 10.0, "line")])
    s = np.linspace(0.0, 10.0, 11)
    x, y, h, k = pv.evaluate(s)
    np.testing.assert_allclose(x, 1.0 + s * math.cos(0.3), atol=1e-12)
    np.testing.assert_allclose(y, 2.0 + s * math.sin(0.3), atol=1e-12)
    np.testing.assert_allclose(h, 0.3)
    np.testing.assert_allclose(k, 0.0)
    assert pv.length == 10.0


def _arc_closed_form(x0, y0, h0, k, s):
    """Circle of radius 1/k: centre to the left of the start heading."""
    cx, cy = x0 - math.sin(h0) / k, y0 + math.cos(h0) / k
    h = h0 + k * s
    return cx + np.sin(h) / k, cy - np.cos(h) / k, h


@pytest.mark.parametrize("k", [0.05, -0.08, 0.2])
def test_arc_against_circle(k):
    x0, y0, h0, length = 3.0, -4.0, 0.4, 25.0
    pv = PlanView([Geometry(0.0, x0, y0, h0, length, "arc", {"curvature": k})])
    s = np.linspace(0.0, length, 51)
    x, y, h, kk = pv.evaluate(s)
    ex, ey, eh = _arc_closed_form(x0, y0, h0, k, s)
    np.testing.assert_allclose(x, ex, atol=POS_TOL_M)
    np.testing.assert_allclose(y, ey, atol=POS_TOL_M)
    np.testing.assert_allclose(_wrap(h - eh), 0.0, atol=HDG_TOL)
    np.testing.assert_allclose(kk, k)
    # Every point lies on the circle.
    cx, cy = x0 - math.sin(h0) / k, y0 + math.cos(h0) / k
    np.testing.assert_allclose(np.hypot(x - cx, y - cy), 1 / abs(k), atol=POS_TOL_M)


@settings(max_examples=60, deadline=None)
@given(k=st.floats(-0.5, 0.5).filter(lambda v: abs(v) > 1e-4),
       h0=st.floats(-math.pi, math.pi), s=st.floats(0.0, 60.0))
def test_arc_heading_is_hdg0_plus_k_s(k, h0, s):
    pv = PlanView([Geometry(0.0, 0.0, 0.0, h0, 60.0, "arc", {"curvature": k})])
    x, y, h, _ = pv.evaluate(s)
    ex, ey, _ = _arc_closed_form(0.0, 0.0, h0, k, np.array([s]))
    assert abs(_wrap(h[0] - (h0 + k * s))) < HDG_TOL
    assert math.hypot(x[0] - ex[0], y[0] - ey[0]) < POS_TOL_M


# --- spiral -------------------------------------------------------------------------------


@pytest.mark.parametrize("h0", [0.0, 1.1, -2.5])
@pytest.mark.parametrize("k1", [0.1, -0.04])
def test_clothoid_from_zero_curvature_against_fresnel(h0, k1):
    length = 50.0
    c = k1 / length
    pv = PlanView([Geometry(0.0, 5.0, 7.0, h0, length, "spiral",
                            {"curvStart": 0.0, "curvEnd": k1})])
    s = np.linspace(0.0, length, 41)
    x, y, h, k = pv.evaluate(s)
    # ∫0^s cos(c t²/2) dt = a C(s/a) with a = sqrt(π/|c|); the sine integral flips with c.
    a = math.sqrt(math.pi / abs(c))
    fs, fc = special.fresnel(s / a)
    u, v = a * fc, math.copysign(1.0, c) * a * fs
    ex = 5.0 + u * math.cos(h0) - v * math.sin(h0)
    ey = 7.0 + u * math.sin(h0) + v * math.cos(h0)
    np.testing.assert_allclose(x, ex, atol=POS_TOL_M)
    np.testing.assert_allclose(y, ey, atol=POS_TOL_M)
    np.testing.assert_allclose(_wrap(h - (h0 + 0.5 * c * s * s)), 0.0, atol=HDG_TOL)
    np.testing.assert_allclose(k, c * s, atol=1e-12)


@pytest.mark.parametrize("k0,k1,length", [(0.02, -0.03, 80.0), (-0.1, 0.15, 40.0),
                                          (0.3, 0.31, 30.0)])
def test_general_spiral_against_quad(k0, k1, length):
    h0 = 0.7
    pv = PlanView([Geometry(0.0, -2.0, 1.0, h0, length, "spiral",
                            {"curvStart": k0, "curvEnd": k1})])
    c = (k1 - k0) / length

    def hdg(t):
        return h0 + k0 * t + 0.5 * c * t * t

    s = np.linspace(0.0, length, 17)
    x, y, h, _ = pv.evaluate(s)
    for si, xi, yi, hi in zip(s, x, y, h, strict=True):
        ex = -2.0 + integrate.quad(lambda t: math.cos(hdg(t)), 0.0, si, epsabs=1e-12,
                                   epsrel=1e-12)[0]
        ey = 1.0 + integrate.quad(lambda t: math.sin(hdg(t)), 0.0, si, epsabs=1e-12,
                                  epsrel=1e-12)[0]
        assert math.hypot(xi - ex, yi - ey) < POS_TOL_M, (si, xi - ex, yi - ey)
        assert abs(_wrap(hi - hdg(si))) < HDG_TOL


# --- poly3 --------------------------------------------------------------------------------

POLY3 = (0.5, 0.1, 0.01, -0.0005)  # a, b, c, d


def _poly3_length(u_end):
    _, b, c, d = POLY3
    return integrate.quad(lambda u: math.hypot(1.0, b + 2 * c * u + 3 * d * u * u), 0.0, u_end,
                          epsabs=1e-13, epsrel=1e-13)[0]


@pytest.fixture(scope="module")
def poly3_case():
    x0, y0, h0 = 10.0, -3.0, -0.6
    length = _poly3_length(20.0)
    g = Geometry(0.0, x0, y0, h0, length, "poly3", dict(zip("abcd", POLY3, strict=True)))
    return PlanView([g]), (x0, y0, h0, length)


def test_poly3_points_lie_on_the_cubic_and_s_is_arc_length(poly3_case):
    pv, (x0, y0, h0, length) = poly3_case
    a, b, c, d = POLY3
    s = np.linspace(0.0, length, 33)
    x, y, h, _ = pv.evaluate(s)
    # Back to the local (u, v) frame.
    dx, dy = x - x0, y - y0
    u = dx * math.cos(h0) + dy * math.sin(h0)
    v = -dx * math.sin(h0) + dy * math.cos(h0)
    np.testing.assert_allclose(v, a + b * u + c * u**2 + d * u**3, atol=POS_TOL_M)
    # Arc length between consecutive samples equals their s difference.
    for i in range(len(s) - 1):
        arc = _poly3_length(u[i + 1]) - _poly3_length(u[i])
        assert abs(arc - (s[i + 1] - s[i])) < POS_TOL_M
    np.testing.assert_allclose(u[-1], 20.0, atol=POS_TOL_M)
    np.testing.assert_allclose(_wrap(h - (h0 + np.arctan(b + 2 * c * u + 3 * d * u * u))), 0.0,
                               atol=1e-7)


# --- paramPoly3 ---------------------------------------------------------------------------


def _pp3_case(p_range: str):
    """Coefficients (aU..dV), p_end and the curve's true arc length.

    For ``arcLength`` the curve is u = λp, v = κp² with κ solved so that its true arc
    length over p ∈ [0, L] is exactly L: the stated length and the p range then agree,
    as OpenDRIVE asks.
    """
    if p_range == "normalized":
        co = dict(aU=0.0, bU=20.0, cU=-2.0, dU=0.5, aV=0.3, bV=0.0, cV=3.0, dV=-1.0)
        p_end = 1.0
    else:
        L, lam = 30.0, 0.95

        def excess(kappa):
            return integrate.quad(lambda p: math.hypot(lam, 2 * kappa * p), 0.0, L,
                                  epsabs=1e-13, epsrel=1e-13)[0] - L

        kappa = optimize.brentq(excess, 0.0, 1.0, xtol=1e-15)
        co = dict(aU=0.0, bU=lam, cU=0.0, dU=0.0, aV=0.0, bV=0.0, cV=kappa, dV=0.0)
        p_end = L
    return co, p_end


def _pp3_derivs(co):
    def du(p):
        return co["bU"] + 2 * co["cU"] * p + 3 * co["dU"] * p * p

    def dv(p):
        return co["bV"] + 2 * co["cV"] * p + 3 * co["dV"] * p * p

    def arc(p):
        return integrate.quad(lambda q: math.hypot(du(q), dv(q)), 0.0, p, epsabs=1e-13,
                              epsrel=1e-13)[0]

    return du, dv, arc


def _pp3_samples(p_range: str, n: int = 41):
    """(co, s, p, evaluated x, y, h, derivative functions, local frame) of one case.

    p is recovered from each evaluated point independently: U(p) is monotone in both
    cases, so p solves U(p) = u of the point in the local frame.
    """
    co, p_end = _pp3_case(p_range)
    du, dv, arc = _pp3_derivs(co)
    length = arc(p_end)
    x0, y0, h0 = 1.0, 2.0, 2.2
    pv = PlanView([Geometry(0.0, x0, y0, h0, length, "paramPoly3", {**co, "pRange": p_range})])
    s = np.linspace(0.0, length, n)
    x, y, h, _ = pv.evaluate(s)
    dx, dy = x - x0, y - y0
    u = dx * math.cos(h0) + dy * math.sin(h0)
    v = -dx * math.sin(h0) + dy * math.cos(h0)

    def big_u(q):
        return co["aU"] + q * (co["bU"] + q * (co["cU"] + q * co["dU"]))

    p = np.array([optimize.brentq(lambda q, ui=ui: big_u(q) - ui, -0.01 * p_end, 1.01 * p_end,
                                  xtol=1e-15) for ui in u])
    return co, s, p, v, h, h0, du, dv, arc


@pytest.mark.parametrize("p_range", ["normalized", "arcLength"])
def test_param_poly3_points_on_curve_heading_and_arc_length(p_range):
    co, s, p, v, h, h0, du, dv, arc = _pp3_samples(p_range)
    big_v = co["aV"] + p * (co["bV"] + p * (co["cV"] + p * co["dV"]))
    np.testing.assert_allclose(v, big_v, atol=1e-9)  # on the curve
    np.testing.assert_allclose(_wrap(h - (h0 + np.arctan2(dv(p), du(p)))), 0.0, atol=1e-7)
    # s is the arc length from the start, to 0.1 mm (and to 1 µm: the test below).
    err = np.array([arc(pi) - si for pi, si in zip(p, s, strict=True)])
    assert np.abs(err).max() < 1e-4
    assert p[0] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("p_range", ["normalized", "arcLength"])
def test_param_poly3_arc_length_to_a_micrometre(p_range):
    *_, s, p, _v, _h, _h0, _du, _dv, arc = _pp3_samples(p_range, n=401)
    err = np.array([arc(pi) - si for pi, si in zip(p, s, strict=True)])
    assert np.abs(err).max() < POS_TOL_M


# --- several geometries, and the same curves read from OpenDRIVE text -------------------


def _chain():
    """line → arc → spiral → poly3 → paramPoly3, each starting where the last ended."""
    recs = []
    x, y, h, s = 0.0, 0.0, 0.3, 0.0
    recs.append(Geometry(s, x, y, h, 12.0, "line"))
    x, y, s = x + 12.0 * math.cos(h), y + 12.0 * math.sin(h), s + 12.0
    k = 0.04
    ex, ey, eh = _arc_closed_form(x, y, h, k, np.array([20.0]))
    recs.append(Geometry(s, x, y, h, 20.0, "arc", {"curvature": k}))
    x, y, h, s = float(ex[0]), float(ey[0]), float(eh[0]), s + 20.0
    sp = Geometry(s, x, y, h, 15.0, "spiral", {"curvStart": k, "curvEnd": 0.0})
    recs.append(sp)
    x, y, h, _ = PlanView([sp]).evaluate(s + 15.0)
    x, y, h, s = float(x[0]), float(y[0]), float(h[0]), s + 15.0
    p3 = Geometry(s, x, y, h, _poly3_length(10.0), "poly3",
                  {"a": 0.0, "b": 0.0, "c": 0.01, "d": -0.0005})
    recs.append(p3)
    x, y, h, _ = PlanView([p3]).evaluate(s + p3.length)
    x, y, h, s = float(x[0]), float(y[0]), float(h[0]), s + p3.length
    co, _ = _pp3_case("normalized")
    co = {**co, "aV": 0.0}
    length = _pp3_derivs(co)[2](1.0)
    recs.append(Geometry(s, x, y, h, length, "paramPoly3", {**co, "pRange": "normalized"}))
    return recs


def test_chained_geometries_are_continuous_at_the_joints():
    recs = _chain()
    pv = PlanView(recs)
    assert pv.length == pytest.approx(recs[-1].s + recs[-1].length)
    for g in recs[1:]:
        before = pv.evaluate(g.s - 1e-9)
        at = pv.evaluate(g.s)
        assert at[0][0] == pytest.approx(g.x, abs=1e-9)
        assert at[1][0] == pytest.approx(g.y, abs=1e-9)
        assert math.hypot(before[0][0] - g.x, before[1][0] - g.y) < POS_TOL_M
        assert abs(_wrap(before[2][0] - g.hdg)) < 1e-6
    # Dense sampling: no chord longer than its s step (arc length ≥ chord).
    s = np.linspace(0.0, pv.length, 2000)
    x, y, _, _ = pv.evaluate(s)
    assert np.hypot(np.diff(x), np.diff(y)).max() <= (s[1] - s[0]) + 1e-9


def _geometry_xml(xodr, g: Geometry) -> str:
    if g.kind == "line":
        body = "<line/>"
    else:
        attrs = " ".join(f'{k}="{v!r}"' if not isinstance(v, str) else f'{k}="{v}"'
                         for k, v in g.params.items())
        body = f"<{g.kind} {attrs}/>"
    return xodr.geometry(g.s, g.x, g.y, g.hdg, g.length, body)


def test_geometries_read_from_opendrive_text_match_planview(xodr):
    """The reader hands the plan view the same records: the road's reference line
    (midway between lanes ±1 of equal width) equals the direct evaluation."""
    recs = _chain()
    length = recs[-1].s + recs[-1].length
    text = xodr.opendrive(xodr.road(1, [_geometry_xml(xodr, g) for g in recs], length))
    m = RoadMap.from_string(text)
    assert [g.kind for g in m.roads[1].plan_view.geometries] == [g.kind for g in recs]
    s = np.linspace(0.0, length, 200)
    x, y = _reference_from_map(m, 1, s)
    ex, ey, _, _ = PlanView(recs).evaluate(s)
    np.testing.assert_allclose(x, ex, atol=POS_TOL_M)
    np.testing.assert_allclose(y, ey, atol=POS_TOL_M)


# --- Cubic profiles -----------------------------------------------------------------------


def test_cubic_pieces_and_derivative():
    cu = Cubic.from_records([(10.0, 1.0, 0.5, 0.0, 0.0), (0.0, 2.0, 0.1, 0.01, -0.001)])
    s = np.array([0.0, 5.0, 9.999, 10.0, 15.0])
    ds = np.where(s < 10.0, s, s - 10.0)
    expect = np.where(s < 10.0, 2.0 + 0.1 * ds + 0.01 * ds**2 - 0.001 * ds**3, 1.0 + 0.5 * ds)
    np.testing.assert_allclose(cu(s), expect, atol=1e-12)
    dexp = np.where(s < 10.0, 0.1 + 0.02 * ds - 0.003 * ds**2, 0.5)
    np.testing.assert_allclose(cu.derivative(s), dexp, atol=1e-12)
    assert Cubic.from_records([]).is_zero
