"""The OpenDRIVE reader refuses non-finite geometry and names every quirk it survives."""

from __future__ import annotations

import warnings

import pytest

from dashtraj.cli import main
from dashtraj.errors import OpenDriveError
from dashtraj.roads import OpenDriveWarning, RoadMap


def _line(x="0", y="0", hdg="0", length="10", s="0", body="<line/>"):
    return (f'<geometry s="{s}" x="{x}" y="{y}" hdg="{hdg}" length="{length}">{body}'
            "</geometry>")


@pytest.mark.parametrize(("make", "expected"), [
    (lambda x: x.road(1, _line(x="nan"), 10.0), "road 1: geometry <line> at s=0 (line 1) "
     "has a non-finite value (x=nan)"),
    (lambda x: x.road(2, _line(hdg="-inf"), 10.0), "road 2: geometry <line> at s=0 (line 1) "
     "has a non-finite value (hdg=-inf)"),
    (lambda x: x.road(3, _line(body='<arc curvature="NaN"/>'), 10.0),
     "road 3: geometry <arc> at s=0 (line 1) has a non-finite value (curvature=nan)"),
    (lambda x: x.road(4, _line(length="inf"), 10.0), "(length=inf)"),
    (lambda x: x.road(5, x.geometry(0.0, 0.0, 0.0, 0.0, 10.0), 10.0,
                      elevation=[(0.0, 0.0, 0.0, 0.0, 0.0), (5.0, float("nan"), 0, 0, 0)]),
     "road 5: <elevation> at s=5 has a non-finite value (a=nan)"),
    (lambda x: x.road(6, x.geometry(0.0, 0.0, 0.0, 0.0, 10.0), 10.0,
                      lane_offset=[(0.0, 0.0, float("inf"), 0, 0)]),
     "road 6: <laneOffset> at s=0 has a non-finite value (b=inf)"),
    (lambda x: x.road(7, x.geometry(0.0, 0.0, 0.0, 0.0, 10.0), 10.0,
                      [x.section(0.0, x.lane(1, (float("nan"), 0, 0, 0)), x.lane(-1))]),
     "road 7 section at s=0 lane 1: <width> at sOffset=0 has a non-finite value (a=nan)"),
    (lambda x: x.road(8, x.geometry(0.0, 0.0, 0.0, 0.0, 10.0), float("nan")),
     "road 8: <road> has a non-finite value (length=nan)"),
])
def test_non_finite_geometry_is_an_error_naming_road_and_element(xodr, make, expected):
    with pytest.raises(OpenDriveError) as exc:
        RoadMap.from_string(xodr.opendrive(make(xodr)), name="bad.xodr")
    assert str(exc.value).startswith("bad.xodr: ")
    assert expected in str(exc.value)


def test_cli_reports_a_non_finite_map_in_one_line(xodr, tmp_path, capsys):
    path = tmp_path / "nan.xodr"
    path.write_text(xodr.opendrive(xodr.road(1, _line(x="nan"), 10.0)))
    assert main(["map", "info", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "road 1" in err and "x=nan" in err


def test_negative_geometry_length_is_called_negative(xodr):
    x = xodr
    geoms = [x.geometry(0.0, 0.0, 0.0, 0.0, 10.0), _line(s="10", x="10", length="-3")]
    with pytest.warns(OpenDriveWarning, match=r"road 2 geometry <line> at s=10 has negative "
                      r"length -3 m; skipped"):
        m = RoadMap.from_string(x.opendrive(x.road(2, geoms, 10.0)))
    assert m.roads[2].length == pytest.approx(10.0)


def test_zero_geometry_length_is_still_called_zero(xodr):
    x = xodr
    geoms = [x.geometry(0.0, 0.0, 0.0, 0.0, 10.0), _line(s="10", x="10", length="0")]
    with pytest.warns(OpenDriveWarning, match="has zero length; skipped"):
        RoadMap.from_string(x.opendrive(x.road(2, geoms, 10.0)))


def _two_roads(x, *, pred_of_2: int = -1, succ_of_1: int = -1, succ_of_1_left: int | None = None):
    """Road 1 → road 2 (a road link); lane links as given."""
    r1 = x.road(1, x.geometry(0.0, 0.0, 0.0, 0.0, 50.0), 50.0,
                [x.section(0.0, x.lane(1, pred=1, succ=succ_of_1_left),
                             x.lane(-1, succ=succ_of_1))],
                succ=("road", 2, "start"))
    r2 = x.road(2, x.geometry(0.0, 50.0, 0.0, 0.0, 50.0), 50.0,
                [x.section(0.0, x.lane(1), x.lane(-1, pred=pred_of_2))],
                pred=("road", 1, "end"))
    return x.opendrive(r1, r2)


def test_road_link_lane_links_to_missing_lanes_warn_in_both_directions(xodr):
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m = RoadMap.from_string(_two_roads(xodr), name="ok.xodr")
    assert not [w for w in rec if issubclass(w.category, OpenDriveWarning)]
    assert m.lanes[(1, 0, -1)].successors == [(2, 0, -1)]
    # Downstream (the successor a forward lane drives into): warned and ignored.
    with pytest.warns(OpenDriveWarning, match=r"road 1 section 0 lane -1 links to lane -3 of "
                      r"road 2 section 0, which does not exist; link ignored"):
        m = RoadMap.from_string(_two_roads(xodr, succ_of_1=-3), name="a.xodr")
    assert m.lanes[(1, 0, -1)].successors == []
    # Upstream (a forward lane's predecessor through the road link): warned too.
    with pytest.warns(OpenDriveWarning, match=r"road 2 section 0 lane -1 predecessor links to "
                      r"lane -5 of road 1 section 0, which does not exist; link ignored"):
        m = RoadMap.from_string(_two_roads(xodr, pred_of_2=-5), name="b.xodr")
    assert m.lanes[(1, 0, -1)].successors == [(2, 0, -1)]  # road 1's own link still holds
    # A backward lane's successor link points upstream too.
    with pytest.warns(OpenDriveWarning, match=r"road 1 section 0 lane 1 successor links to "
                      r"lane 4 of road 2 section 0"):
        RoadMap.from_string(_two_roads(xodr, succ_of_1_left=4), name="c.xodr")
