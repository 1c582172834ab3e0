"""Fixtures every test folder shares: the real CARLA maps (skipped when absent)."""

from __future__ import annotations

import pytest

from carla_maps import load_carla_map
from dashtraj.roads import RoadMap


@pytest.fixture(scope="session")
def town01() -> RoadMap:
    return load_carla_map("Town01")[0]


@pytest.fixture(scope="session")
def town10() -> RoadMap:
    return load_carla_map("Town10HD")[0]


@pytest.fixture(scope="session", params=["Town01", "Town10HD"])
def carla_map(request) -> RoadMap:
    return load_carla_map(request.param)[0]
