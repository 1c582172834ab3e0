"""Sightings may carry a height z (metres); the CSV column is optional and round-trips."""

from __future__ import annotations

import pytest

from dashtraj.errors import InputFormatError
from dashtraj.trajectory import Sighting, read_sightings, write_sightings


def _s(t: float, z: float | None) -> Sighting:
    return Sighting(t=t, observer_id=1, observer_x=0.0, observer_y=0.0, observer_yaw=0.0,
                    x=5.0, y=1.0, orientation="back", vehicle_class="car", z=z)


def test_z_round_trips_and_is_written_only_when_some_sighting_has_one(tmp_path):
    with_z = tmp_path / "z.csv"
    write_sightings(with_z, [_s(0.0, 10.25), _s(1.0, None)])
    header = with_z.read_text().splitlines()[0].split(",")
    assert header[-1] == "z"
    back = read_sightings(with_z)
    assert [s.z for s in back] == [10.25, None]
    without = tmp_path / "plain.csv"
    write_sightings(without, [_s(0.0, None)])
    assert "z" not in without.read_text().splitlines()[0].split(",")  # old files unchanged
    assert read_sightings(without)[0].z is None


def test_a_non_finite_z_is_refused(tmp_path):
    with pytest.raises(InputFormatError, match=r"Sighting\.z must be a finite number"):
        _s(0.0, float("nan"))
    bad = tmp_path / "bad.csv"
    write_sightings(bad, [_s(0.0, 1.0)])
    bad.write_text(bad.read_text().replace(",1.0\n", ",inf\n"))
    with pytest.raises(InputFormatError, match=r"bad.csv line 2, column 'z'"):
        read_sightings(bad)
