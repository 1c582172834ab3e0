"""Negative evidence (`dashtraj.trajectory.watch`) on the real Town01 and Town10HD.

Road 12 of Town01 runs straight along +x at y ≈ 199 (lane -1 drives +x). The target
is seen on it from s 20 to 40 (t 0-2 s); a look-alike 50 m on at t 7 s, which the
target could have reached at 10 m/s. A camera parked on the lane at s 35, looking along
it, watches the road between: whether it saw the road empty decides whether the two
can be one car. Skipped when ``../shared/maps/carla`` is missing.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from dashtraj.trajectory.gating import GateConfig, _Lanes, gate_tracks
from dashtraj.trajectory.watch import CameraViews, Watch, WatchConfig, WatchError, box_bearings
from gating_helpers import drive

FRAMES = np.round(np.arange(0.0, 10.0, 0.2), 6)
WIDE = WatchConfig(range_m=60.0)  # one camera sees the whole stretch


def parked(m, s: float, yaw_offset: float = 0.0, lateral_m: float = 0.0,
           boxes=None) -> CameraViews:
    """A camera standing on road 12's lane -1 at s (moved `lateral_m` to the left of the
    lane), looking `yaw_offset` degrees off the lane's way, every 0.2 s for 10 s."""
    tr = m.waypoint(12, 0, -1, s).transform
    yaw = tr.rotation.yaw + yaw_offset
    left = math.radians(tr.rotation.yaw - 90.0)
    x = tr.location.x + lateral_m * math.cos(left)
    y = tr.location.y + lateral_m * math.sin(left)
    n = len(FRAMES)
    bx = boxes if boxes is not None else [np.zeros((0, 2))] * n
    return CameraViews(t=FRAMES.copy(), x=np.full(n, x), y=np.full(n, y),
                       yaw_deg=np.full(n, yaw), fov_deg=90.0, boxes=bx)


def target_and_twin(m):
    return drive(m, 0.0, 2.0, 12, 20.0, obs=1), drive(m, 7.0, 9.0, 12, 90.0, obs=2)


def unseen(m, views, config=WIDE) -> bool:
    a, b = target_and_twin(m)
    lanes = _Lanes(m, GateConfig())
    w = Watch(m, views, config)
    return w.drive_unseen(a[-1].t, lanes.points(a[-1]), b[0].t, lanes.points(b[0]), 15.0, 20.0)


def test_an_empty_watched_road_splits_the_drive(town01):
    assert not unseen(town01, [parked(town01, 35.0)])


def test_a_box_where_the_car_could_be_keeps_it_possible(town01):
    n = len(FRAMES)
    ahead = np.array([[-3.0, 3.0]])  # a box straight ahead in every frame
    assert unseen(town01, [parked(town01, 35.0, boxes=[ahead] * n)])
    # the box missed in one frame (the default allows one miss), or in every other one
    one = [np.zeros((0, 2)) if i == 30 else ahead for i in range(n)]
    assert unseen(town01, [parked(town01, 35.0, boxes=one)])
    alt = [ahead if i % 2 else np.zeros((0, 2)) for i in range(n)]
    assert not unseen(town01, [parked(town01, 35.0, boxes=alt)])
    # a box well to the side covers nothing the car could be at
    side = np.array([[30.0, 40.0]])
    assert not unseen(town01, [parked(town01, 35.0, boxes=[side] * n)])


def test_a_camera_that_looks_away_or_too_short_sees_nothing(town01):
    assert unseen(town01, [parked(town01, 35.0, yaw_offset=180.0)])
    assert unseen(town01, [parked(town01, 35.0)], WatchConfig())  # 15 m: not all of it


def test_a_building_blocks_the_sight_line(town01):
    # 40 m into the block beside road 12, looking at the road across the buildings
    cam = parked(town01, 60.0, yaw_offset=-90.0, lateral_m=40.0)
    w = Watch(town01, [cam], WIDE)
    road = np.array([[town01.waypoint(12, 0, -1, s).transform.location.x,
                      town01.waypoint(12, 0, -1, s).transform.location.y] for s in (55, 60, 65)])
    assert not w._clear(float(cam.x[0]), float(cam.y[0]), road).any()
    along = parked(town01, 35.0)
    assert w._clear(float(along.x[0]), float(along.y[0]), road).all()
    assert unseen(town01, [cam])


def test_misses_and_too_few_frames(town01):
    a, b = target_and_twin(town01)
    lanes = _Lanes(town01, GateConfig())
    pa, pb = lanes.points(a[-1]), lanes.points(b[0])

    def unseen_with(misses, t0=a[-1].t, t1=b[0].t):
        w = Watch(town01, [parked(town01, 35.0)], WatchConfig(range_m=60.0, misses=misses))
        return w.drive_unseen(t0, pa, t1, pb, 15.0, 20.0)

    # from the watched stretch's start (s 39) to within slack + step (22 m) of b (s 68),
    # at two 2 m hops a frame (the 15 m/s of 0.2 s, rounded up): 29 m, eight frames in
    # watched places
    assert not unseen_with(0) and not unseen_with(7)
    assert unseen_with(8)
    # 0.3 s apart: one frame strictly between, no more than one miss: nothing ruled out
    assert unseen_with(1, 2.0, 2.3)


def test_one_car_standing_still_in_view_would_have_been_seen(town01):
    # a passes s 40 at t 2 and is not seen again; b is seen 3 m behind that, going the
    # same way, 6 s later: the gate calls it localization jitter (one car, standing). A
    # camera 20 m back watching the spot all along saw it empty: two vehicles. Without
    # it, or with a box on the spot, one car could have stood there.
    a = drive(town01, 0.0, 2.0, 12, 20.0, obs=1)
    b = drive(town01, 8.0, 9.0, 12, 37.0, obs=2)
    lanes = _Lanes(town01, GateConfig(slack_m=5.0))
    pa, pb = lanes.points(a[-1]), lanes.points(b[0])
    w = Watch(town01, [parked(town01, 20.0)], WatchConfig(range_m=30.0))
    assert not w.drive_unseen(a[-1].t, pa, b[0].t, pb, 15.0, 5.0)
    n = len(FRAMES)
    boxed = Watch(town01, [parked(town01, 20.0, boxes=[np.array([[-3.0, 3.0]])] * n)],
                  WatchConfig(range_m=30.0))
    assert boxed.drive_unseen(a[-1].t, pa, b[0].t, pb, 15.0, 5.0)
    away = Watch(town01, [parked(town01, 20.0, yaw_offset=180.0)], WatchConfig(range_m=30.0))
    assert away.drive_unseen(a[-1].t, pa, b[0].t, pb, 15.0, 5.0)


def test_no_way_at_all_is_not_the_cameras_evidence(town01):
    # 300 m in 1 s: no way on the lanes whatever the cameras saw; the watch leaves that
    # to the gate's reachability instead of calling it evidence
    a = drive(town01, 0.0, 2.0, 12, 20.0, obs=1)
    far = drive(town01, 3.0, 4.0, 6, 100.0, obs=2)
    lanes = _Lanes(town01, GateConfig())
    w = Watch(town01, [parked(town01, 35.0)], WIDE)
    assert w.drive_unseen(a[-1].t, lanes.points(a[-1]), far[0].t, lanes.points(far[0]),
                          15.0, 20.0)


def test_the_gate_drops_a_look_alike_the_cameras_rule_out(town01):
    a, twin = target_and_twin(town01)
    assert gate_tracks(town01, [a, twin], anchor=0).accepted == (0, 1)
    w = Watch(town01, [parked(town01, 35.0)], WIDE)
    r = gate_tracks(town01, [a, twin], anchor=0, watch=w)
    assert r.accepted == (0,) and r.rejected == (1,)
    # seen: the road was not empty, and the two stay one car
    n = len(FRAMES)
    seen = Watch(town01, [parked(town01, 35.0, boxes=[np.array([[-2.0, 2.0]])] * n)], WIDE)
    assert gate_tracks(town01, [a, twin], anchor=0, watch=seen).accepted == (0, 1)


@pytest.mark.parametrize("name", ["town01", "town10"])
def test_route_costs_are_lower_bounds_of_the_lane_graphs(name, request):
    m = request.getfixturevalue(name)
    w = Watch(m, [])
    g = w.graph
    rng = random.Random(3)
    keys = sorted(g._length)
    gaps = []
    for _ in range(25):
        ka, kb = rng.choice(keys), rng.choice(keys)
        ia = rng.randrange(*w._lane_index[ka])
        ib = rng.randrange(*w._lane_index[kb])
        wa = m.waypoint(*ka, g.s_at_progress(ka, float(w._prog[ia])))
        wb = m.waypoint(*kb, g.s_at_progress(kb, float(w._prog[ib])))
        exact = g.route_cost(wa, wb)
        fwd = w._dijkstra([(ka, float(w._prog[ia]))], reverse=False)[ib]
        back = w._dijkstra([(kb, float(w._prog[ib]))], reverse=True)[ia]
        assert fwd == pytest.approx(back, abs=1e-6)
        if math.isinf(exact):
            continue
        assert fwd <= exact + 1e-6
        gaps.append(exact - fwd)
    if name == "town01":  # one driving lane each way: no lane change to discount
        assert max(gaps) < 1e-6
    else:  # Town10HD's lane changes cost the lane graph their gap, the watch nothing
        assert np.median(gaps) < 10.0


def test_bad_settings_and_views_are_refused(town01):
    with pytest.raises(WatchError, match="range_m"):
        WatchConfig(range_m=2.0, near_m=4.0)
    with pytest.raises(WatchError, match="misses"):
        WatchConfig(misses=-1)
    with pytest.raises(WatchError, match="end_m"):
        WatchConfig(end_m=-1.0)
    with pytest.raises(WatchError, match="fov_margin_deg"):
        WatchConfig(fov_margin_deg=float("nan"))
    cam = parked(town01, 35.0)
    bad = CameraViews(cam.t, cam.x, cam.y, cam.yaw_deg, 90.0, cam.boxes[:-1])
    with pytest.raises(WatchError, match="camera view 0"):
        Watch(town01, [bad])


def test_box_bearings():
    b = box_bearings([0.0, 320.0, 600.0], [640.0, 640.0, 640.0], 640.0, 90.0)
    assert b[0] == pytest.approx([-45.0, 45.0])
    assert b[1] == pytest.approx([0.0, 45.0])
    assert b[2, 0] == pytest.approx(math.degrees(math.atan(280.0 / 320.0)))
