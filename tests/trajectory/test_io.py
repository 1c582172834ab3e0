"""CSV reading and writing of sightings and trajectories."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from dashtraj.errors import InputFormatError
from dashtraj.trajectory.io import (
    read_sightings,
    read_trajectory,
    write_sightings,
    write_trajectory,
)
from dashtraj.trajectory.records import Sighting, Trajectory

HEADER = "t,observer_id,observer_x,observer_y,observer_yaw,x,y,orientation,vehicle_class"
GOOD_ROW = "0.5,3,1.0,2.0,90.0,1.5,14.0,back,car"


def _write(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _sightings() -> list[Sighting]:
    return [
        Sighting(0.1, 1, -12.25, 300.0000001, -179.5, 1e-7, -0.0, "front", "car"),
        Sighting(
            1.0 / 3.0,
            2,
            5.0,
            6.0,
            45.0,
            7.123456789012345,
            8.0,
            "side",
            "truck",
            track_id=17,
            distance=12.5,
            bearing=-23.75,
        ),
        Sighting(2.0, 2, 5.0, 6.0, 45.0, 7.0, 8.0, "back", "bicycle", distance=0.0),
    ]


def test_sightings_round_trip_is_byte_identical(tmp_path):
    first = tmp_path / "a.csv"
    second = tmp_path / "b.csv"
    original = _sightings()
    write_sightings(first, original)
    back = read_sightings(first)
    assert back == original
    write_sightings(second, back)
    assert first.read_bytes() == second.read_bytes()
    lines = first.read_text().splitlines()
    assert lines[0] == HEADER + ",track_id,distance,bearing"
    assert lines[1] == "0.1,1,-12.25,300.0000001,-179.5,1e-07,-0.0,front,car,,,"


@pytest.mark.parametrize("with_t", [True, False])
def test_trajectory_round_trip_is_byte_identical(tmp_path, with_t):
    rng = np.random.default_rng(3)
    pts = rng.normal(scale=100.0, size=(25, 2))
    traj = Trajectory(pts, np.cumsum(rng.random(25)) if with_t else None)
    first, second = tmp_path / "a.csv", tmp_path / "b.csv"
    write_trajectory(first, traj)
    back = read_trajectory(first)
    assert back == traj
    write_trajectory(second, back)
    assert first.read_bytes() == second.read_bytes()
    assert first.read_text().splitlines()[0] == ("x,y,t" if with_t else "x,y")


def test_column_order_free_optional_columns_and_blank_lines(tmp_path):
    text = (
        "vehicle_class,orientation,y,x,observer_yaw,observer_y,observer_x,observer_id,t,"
        "bearing,track_id\n"
        "\n"
        "bus,side,2,1,0,0,0,7,1.5,-10,4\n"
        "car,front,3,4,0,0,0,7,2.5,,\n"
    )
    got = read_sightings(_write(tmp_path, "s.csv", text))
    assert got[0] == Sighting(1.5, 7, 0.0, 0.0, 0.0, 1.0, 2.0, "side", "bus", 4, None, -10.0)
    assert got[1].bearing is None and got[1].track_id is None and got[1].distance is None


def test_unknown_columns_warn_and_are_ignored(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + ",colour,speed\n" + GOOD_ROW + ",red,3\n")
    with pytest.warns(UserWarning, match="s.csv: ignoring unknown column.*'colour', 'speed'"):
        got = read_sightings(path)
    assert len(got) == 1


def test_known_columns_do_not_warn(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + "\n" + GOOD_ROW + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_sightings(path)[0].y == 14.0


@pytest.mark.parametrize(
    ("row", "column", "message"),
    [
        ("0.5,3,1.0,2.0,90.0,abc,14.0,back,car", "x", "'abc' is not a number"),
        ("0.5,3.5,1.0,2.0,90.0,1.5,14.0,back,car", "observer_id", "'3.5' is not an integer"),
        ("0.5,3,1.0,2.0,90.0,1.5,14.0,rear,car", "orientation", "'rear' is not one of front"),
        ("0.5,3,1.0,2.0,90.0,1.5,14.0,back,van", "vehicle_class", "'van' is not one of car"),
        ("nan,3,1.0,2.0,90.0,1.5,14.0,back,car", "t", "'nan' is not a finite number"),
        ("0.5,3,1.0,,90.0,1.5,14.0,back,car", "observer_y", "empty, a value is required"),
        ("0.5,3,1.0,2.0,90.0,1.5,14.0,back,car,x1", "track_id", "'x1' is not an integer"),
    ],
)
def test_bad_sighting_cell_names_file_line_column(tmp_path, row, column, message):
    header = HEADER + (",track_id" if row.count(",") == 9 else "")
    text = header + "\n" + GOOD_ROW + ("," if "track_id" in header else "") + "\n\n" + row + "\n"
    path = _write(tmp_path, "sightings.csv", text)
    with pytest.raises(InputFormatError) as info:
        read_sightings(path)
    # Line 4: header, a good row, a blank line, then the bad row.
    assert str(info.value).startswith(f"sightings.csv line 4, column {column!r}: {message}")


def test_negative_distance_is_rejected(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + ",distance\n" + GOOD_ROW + ",-2\n")
    with pytest.raises(InputFormatError, match=r"s\.csv line 2, column 'distance': '-2' is neg"):
        read_sightings(path)


def test_exact_message_for_a_bad_number(tmp_path):
    rows = [GOOD_ROW] * 5 + ["0.5,3,1.0,2.0,90.0,abc,14.0,back,car"]
    path = _write(tmp_path, "sightings.csv", HEADER + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputFormatError) as info:
        read_sightings(path)
    assert str(info.value) == "sightings.csv line 7, column 'x': 'abc' is not a number"


def test_short_row_names_line_and_missing_column(tmp_path):
    path = _write(tmp_path, "s.csv", HEADER + "\n0.5,3,1.0,2.0,90.0,1.5,14.0,back\n")
    with pytest.raises(InputFormatError, match=r"s\.csv line 2: 8 fields.*'vehicle_class'"):
        read_sightings(path)


def test_missing_required_column_names_file_and_column(tmp_path):
    header = HEADER.replace(",observer_yaw", "")
    path = _write(tmp_path, "s.csv", header + "\n0.5,3,1.0,2.0,1.5,14.0,back,car\n")
    with pytest.raises(InputFormatError, match=r"s\.csv: missing required column 'observer_yaw'"):
        read_sightings(path)


@pytest.mark.parametrize(("text", "message"), [("", "empty file"), (HEADER + "\n", "no sight")])
def test_empty_or_header_only_file(tmp_path, text, message):
    path = _write(tmp_path, "s.csv", text)
    with pytest.raises(InputFormatError, match=f"s.csv: .*{message}"):
        read_sightings(path)


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputFormatError, match="cannot open"):
        read_sightings(tmp_path / "nope.csv")


def test_duplicate_header_column(tmp_path):
    path = _write(tmp_path, "s.csv", "x,y,x\n1,2,3\n")
    with pytest.raises(InputFormatError, match=r"s\.csv line 1: column 'x' appears twice"):
        read_trajectory(path)


def test_trajectory_errors(tmp_path):
    path = _write(tmp_path, "traj.csv", "y,x\n1,2\n3,oops\n")
    with pytest.raises(InputFormatError) as info:
        read_trajectory(path)
    assert str(info.value) == "traj.csv line 3, column 'x': 'oops' is not a number"
    with pytest.raises(InputFormatError, match=r"traj\.csv: missing required column 'y'"):
        read_trajectory(_write(tmp_path, "traj.csv", "x,t\n1,2\n"))
    with pytest.raises(InputFormatError, match=r"traj\.csv: header only, no points"):
        read_trajectory(_write(tmp_path, "traj.csv", "x,y\n"))
    with pytest.raises(InputFormatError, match="column 't' is empty in data row 2"):
        read_trajectory(_write(tmp_path, "traj.csv", "x,y,t\n0,0,0\n1,1,\n"))


def test_trajectory_column_order_and_bom(tmp_path):
    path = tmp_path / "traj.csv"
    path.write_bytes("\ufefft,y,x\n0,1,2\n1,3,4\n".encode())
    traj = read_trajectory(path)
    np.testing.assert_array_equal(traj.points, [[2.0, 1.0], [4.0, 3.0]])
    np.testing.assert_array_equal(traj.t, [0.0, 1.0])


def test_sighting_validation():
    with pytest.raises(InputFormatError, match="orientation must be one of front, back, side"):
        Sighting(0.0, 1, 0.0, 0.0, 0.0, 1.0, 1.0, "rear", "car")
    with pytest.raises(InputFormatError, match="vehicle_class"):
        Sighting(0.0, 1, 0.0, 0.0, 0.0, 1.0, 1.0, "front", "tank")
    with pytest.raises(InputFormatError, match=r"Sighting\.x must be a finite"):
        Sighting(0.0, 1, 0.0, 0.0, 0.0, float("inf"), 1.0, "front", "car")
    with pytest.raises(InputFormatError, match="distance must be >= 0"):
        Sighting(0.0, 1, 0.0, 0.0, 0.0, 1.0, 1.0, "front", "car", distance=-1.0)
