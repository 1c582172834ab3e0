"""The OpenDRIVE reader on quirky and bad input: quirks warn (naming road and
element) and the map still loads; files that are not OpenDRIVE raise
`OpenDriveError` naming the file."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from dashtraj.errors import OpenDriveError
from dashtraj.roads import OpenDriveWarning, RoadMap, read_opendrive


def _load(text: str, name: str = "quirks.xodr") -> tuple[RoadMap, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = RoadMap.from_string(text, name=name)
    msgs = [str(w.message) for w in caught if issubclass(w.category, OpenDriveWarning)]
    return m, msgs


def _two_roads(xodr, lane_succ: int = -1, road_succ=("road", 2, "start")):
    x = xodr
    r1 = x.road(1, x.geometry(0.0, 0.0, 0.0, 0.0, 20.0), 20.0,
                [x.section(0.0, x.lane(1, succ=1), x.lane(-1, succ=lane_succ))], succ=road_succ)
    r2 = x.road(2, x.geometry(0.0, 20.0, 0.0, 0.0, 20.0), 20.0,
                [x.section(0.0, x.lane(1, pred=1), x.lane(-1, pred=-1))], pred=("road", 1, "end"))
    return x.opendrive(r1, r2)


def test_clean_synthetic_map_loads_without_warnings(xodr):
    m, msgs = _load(_two_roads(xodr))
    assert msgs == []
    assert m.lanes[(1, 0, -1)].successors == [(2, 0, -1)]
    assert m.lanes[(2, 0, 1)].successors == [(1, 0, 1)]


def test_link_to_missing_lane_warns_and_loads(xodr):
    m, msgs = _load(_two_roads(xodr, lane_succ=-3))
    [msg] = [s for s in msgs if "does not exist" in s]
    assert msg.startswith("quirks.xodr: ")
    assert "road 1 section 0 lane -1" in msg
    assert "lane -3 of road 2" in msg
    assert m.lanes[(1, 0, -1)].successors == []
    assert len(m.roads) == 2 and m.get_waypoint((10.0, 1.75)).key == (1, 0, -1)


def test_road_link_to_missing_road_warns(xodr):
    m, msgs = _load(_two_roads(xodr, road_succ=("road", 99, "start")))
    [msg] = msgs
    assert "road 1 successor links to missing road 99" in msg
    assert m.roads[1].successor is None
    assert m.lanes[(1, 0, -1)].successors == []


def test_zero_length_geometry_is_skipped_with_a_warning(xodr):
    x = xodr
    geoms = [x.geometry(0.0, 0.0, 0.0, 0.0, 10.0), x.geometry(10.0, 10.0, 0.0, 1.0, 0.0),
             x.geometry(10.0, 10.0, 0.0, 0.0, 15.0)]
    m, msgs = _load(x.opendrive(x.road(5, geoms, 25.0)))
    [msg] = msgs
    assert "road 5" in msg and "s=10" in msg and "zero length" in msg and "skipped" in msg
    assert len(m.roads[5].plan_view.geometries) == 2
    xs, ys, hs, _ = m.roads[5].plan_view.evaluate(np.array([10.0, 20.0]))
    np.testing.assert_allclose([xs, ys, hs], [[10.0, 20.0], [0.0, 0.0], [0.0, 0.0]], atol=1e-12)


def test_unknown_geometry_element_is_read_as_a_line(xodr):
    x = xodr
    g = x.geometry(0.0, 1.0, 2.0, 0.5, 30.0, '<clothoid curvStart="0" curvEnd="0.1"/>')
    m, msgs = _load(x.opendrive(x.road(6, g, 30.0)))
    [msg] = msgs
    assert "road 6" in msg and "<clothoid>" in msg and "read as a line" in msg
    xs, ys, hs, _ = m.roads[6].plan_view.evaluate(np.array([0.0, 30.0]))
    np.testing.assert_allclose(xs, [1.0, 1.0 + 30.0 * np.cos(0.5)], atol=1e-12)
    np.testing.assert_allclose(ys, [2.0, 2.0 + 30.0 * np.sin(0.5)], atol=1e-12)
    np.testing.assert_allclose(hs, 0.5)


@pytest.mark.parametrize("rid", ["A1", "1.5", "road_3"])
def test_non_integer_road_id_raises(xodr, rid):
    text = xodr.opendrive(xodr.road(1, xodr.geometry(0.0, 0.0, 0.0, 0.0, 10.0), 10.0))
    text = text.replace('id="1" junction', f'id="{rid}" junction')
    with pytest.raises(OpenDriveError) as exc:
        RoadMap.from_string(text, name="ids.xodr")
    msg = str(exc.value)
    assert "ids.xodr" in msg and f"{rid!r}" in msg and "not an integer" in msg


def test_file_that_is_not_xml_raises_naming_the_file(tmp_path):
    p = tmp_path / "notes.xodr"
    p.write_text("this is not XML at all\n")
    with pytest.raises(OpenDriveError) as exc:
        RoadMap.from_file(p)
    assert str(p) in str(exc.value)
    assert "is not OpenDRIVE" in str(exc.value)


def test_xml_with_another_root_raises_naming_file_and_root(tmp_path):
    p = tmp_path / "drawing.xodr"
    p.write_text('<svg xmlns="http://www.w3.org/2000/svg"/>')
    with pytest.raises(OpenDriveError) as exc:
        read_opendrive(p)
    msg = str(exc.value)
    assert str(p) in msg and "svg" in msg and "<OpenDRIVE>" in msg


def test_namespaced_root_is_named_by_its_local_name(tmp_path):
    p = tmp_path / "drawing.xodr"
    p.write_text('<svg xmlns="http://www.w3.org/2000/svg"/>')
    with pytest.raises(OpenDriveError) as exc:
        read_opendrive(p)
    assert "<svg>" in str(exc.value)


def test_namespaced_opendrive_reads_like_a_plain_one():
    xodr = (
        '<OpenDRIVE xmlns="http://code.asam.net/simulation/standard/opendrive_schema">'
        '<header revMajor="1" revMinor="8"/>'
        '<road id="1" length="10" junction="-1"><planView>'
        '<geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry></planView>'
        '<lanes><laneSection s="0"><center><lane id="0" type="none"/></center>'
        '<right><lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/>'
        "</lane></right></laneSection></lanes></road></OpenDRIVE>"
    )
    m = RoadMap.from_string(xodr)
    wp = m.get_waypoint((5.0, 1.75))
    assert (wp.road_id, wp.lane_id) == (1, -1)
    assert wp.s == pytest.approx(5.0, abs=1e-6)


def test_plain_svg_root_is_named(tmp_path):
    p = tmp_path / "plain.xodr"
    p.write_text("<svg/>")
    with pytest.raises(OpenDriveError) as exc:
        RoadMap.from_file(p)
    msg = str(exc.value)
    assert str(p) in msg and "<svg>" in msg and "expected <OpenDRIVE>" in msg


def test_missing_file_raises_naming_it(tmp_path):
    p = tmp_path / "nowhere" / "Town99.xodr"
    with pytest.raises(OpenDriveError) as exc:
        RoadMap.from_file(p)
    assert str(p) in str(exc.value)


def test_opendrive_without_roads_raises():
    with pytest.raises(OpenDriveError, match="no <road> elements"):
        RoadMap.from_string("<OpenDRIVE><header/></OpenDRIVE>", name="empty.xodr")


def test_opendrive_whose_roads_all_lack_lanes_says_so():
    """Roads present but every one skipped: the error says none is usable, not that none exist."""
    text = ('<OpenDRIVE><header/><road id="1" length="10" junction="-1"><planView>'
            '<geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>'
            '</planView></road></OpenDRIVE>')
    with pytest.warns(OpenDriveWarning, match="no <lanes>"), \
            pytest.raises(OpenDriveError, match="none of the OpenDRIVE file's <road> elements"):
        RoadMap.from_string(text, name="nolanes.xodr")


def test_junction_lane_link_to_missing_lane_warns(xodr):
    """A junction's laneLink to a lane the connecting road lacks: warning, map loads."""
    x = xodr
    r1 = x.road(1, x.geometry(0.0, 0.0, 0.0, 0.0, 20.0), 20.0, succ=("junction", 10, None))
    r2 = x.road(2, x.geometry(0.0, 20.0, 0.0, 0.0, 10.0), 10.0, junction=10,
                sections=[x.section(0.0, x.lane(-1, pred=-1))], pred=("road", 1, "end"))
    j = ('<junction id="10" name="j"><connection id="0" incomingRoad="1" connectingRoad="2" '
         'contactPoint="start"><laneLink from="-1" to="-1"/><laneLink from="-1" to="-4"/>'
         "</connection></junction>")
    m, msgs = _load(x.opendrive(r1, r2, j))
    [msg] = msgs
    assert "junction 10 connection 0" in msg and "lane -4 of road 2" in msg
    assert m.lanes[(1, 0, -1)].successors == [(2, 0, -1)]
