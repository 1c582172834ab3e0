"""The paper's method keeps one position per pass of an observer."""

from __future__ import annotations

import pytest

from dashtraj.trajectory.reconstruct import one_per_pass, reconstruct_shortest_path
from dashtraj.trajectory.records import Sighting


def _s(t, obs, d=None, track=None, x=0.0):
    return Sighting(t=t, observer_id=obs, observer_x=0.0, observer_y=0.0, observer_yaw=0.0,
                    x=x, y=0.0, orientation="front", vehicle_class="car", track_id=track,
                    distance=d)


def test_closest_sighting_of_each_run_is_kept():
    sightings = [_s(0.0, 1, 14.0), _s(0.5, 1, 6.0), _s(1.0, 1, 9.0),   # pass 1 of observer 1
                 _s(30.0, 1, 12.0), _s(30.5, 1, 11.0),                 # pass 2, after a 29 s gap
                 _s(10.0, 2, 8.0), _s(10.5, 2, 3.0)]                   # observer 2
    kept = one_per_pass(sightings)
    assert [(s.observer_id, s.t) for s in kept] == [(1, 0.5), (2, 10.5), (1, 30.5)]


def test_track_ids_define_passes_and_unknown_distance_keeps_the_middle():
    sightings = [_s(0.0, 1, track=4), _s(0.5, 1, track=4), _s(1.0, 1, track=4),
                 _s(1.2, 1, track=5)]
    kept = one_per_pass(sightings)
    assert [(s.t, s.track_id) for s in kept] == [(0.5, 4), (1.2, 5)]


def test_unknown_per_pass_is_rejected():
    from dashtraj.errors import DashtrajError

    with pytest.raises(DashtrajError, match="per_pass"):
        reconstruct_shortest_path(None, [_s(0.0, 1)], per_pass="best")
