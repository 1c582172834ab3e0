"""The batched evaluations of a map's build answer as the per-record ones they replace."""

from __future__ import annotations

import itertools
import math

import numpy as np

from dashtraj.roads.map import RoadMap, _linspace
from dashtraj.roads.planview import Geometry, PlanView


def _chain(kinds: list[tuple[str, float]], length: float = 7.3) -> PlanView:
    """Consecutive records, each starting where the previous one ends."""
    geoms, s, x, y, h = [], 0.0, 1.0, -2.0, 0.4
    for kind, k in kinds:
        g = Geometry(s, x, y, h, length, kind, {"curvature": k} if kind == "arc" else {})
        geoms.append(g)
        x1, y1, h1, _ = PlanView([g]).evaluate(np.array([s + length]))
        s, x, y, h = s + length, float(x1[0]), float(y1[0]), float(h1[0])
    return PlanView(geoms)


def test_lines_and_arcs_in_one_pass_match_record_by_record():
    pv = _chain([("line", 0.0), ("arc", 0.05), ("arc", -0.2), ("line", 0.0),
                 ("arc", 1e-13), ("arc", 0.013)])
    assert pv._lines_arcs
    s = np.sort(np.concatenate([np.linspace(0.0, pv.length, 301), pv.starts, [pv.length]]))
    got = pv.evaluate_sorted(s)
    idx = np.clip(np.searchsorted(pv.starts, s, side="right") - 1, 0, len(pv.geometries) - 1)
    for i in range(len(pv.geometries)):  # the general path, one record at a time
        m = idx == i
        want = pv._eval_one(i, s[m] - pv.starts[i])
        for a, b in zip(got, want, strict=True):
            np.testing.assert_allclose(a[m], b, rtol=0, atol=1e-12)
    # A plan view with another kind keeps the record-by-record path.
    spiral = Geometry(pv.length, 0.0, 0.0, 0.0, 5.0, "spiral",
                      {"curvStart": 0.0, "curvEnd": 0.1})
    assert not PlanView([*pv.geometries, spiral])._lines_arcs


def test_section_samples_between_knots_are_linspace_pieces(xodr):
    x = xodr
    widths = [(0.0, 3.0, 0, 0, 0), (2.5, 3.1, 0.01, 0, 0), (2.5000001, 3.2, 0, 0, 0),
              (17.25, 3.0, 0, 0, 0)]
    geoms = [x.geometry(0.0, 0.0, 0.0, 0.0, 11.1), x.geometry(11.1, 11.1, 0.0, 0.0, 31.9)]
    m = RoadMap.from_string(x.opendrive(x.road(
        1, geoms, 43.0, [x.section(0.0, x.lane(1), x.lane(-1, widths))],
        lane_offset=[(0.0, 0, 0, 0, 0), (30.0, 0.1, 0, 0, 0)])))
    road = m.roads[1]
    for step in (1.0, 0.37, 5.0):
        got = m._section_samples(road, 0, 0.0, 43.0, step)
        knots = sorted({0.0, 43.0, 11.1, 30.0, 2.5, 2.5000001, 17.25})
        want = np.concatenate(
            [_linspace(a, c, max(2, math.ceil((c - a) / step) + 1))[:-1]
             for a, c in itertools.pairwise(knots)] + [np.array([43.0])])
        np.testing.assert_array_equal(got, want)
