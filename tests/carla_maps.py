"""The real CARLA maps for tests: one loader, one cache.

The maps live in ``../shared/maps/carla/`` beside the checkout (override with
``DASHTRAJ_CARLA_MAPS``). A test that needs one skips when it is missing.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import pytest

from dashtraj.roads import RoadMap

CARLA_MAPS = Path(os.environ.get(
    "DASHTRAJ_CARLA_MAPS", Path(__file__).resolve().parents[2] / "shared" / "maps" / "carla"))

_LOADED: dict[str, tuple[RoadMap, list[warnings.WarningMessage]]] = {}


def carla_map_path(town: str) -> Path:
    """The path of Town01 / Town10HD; skips the test when it is not there."""
    path = CARLA_MAPS / f"{town}.xodr"
    if not path.is_file():
        pytest.skip(f"real CARLA map {path} not available")
    return path


def load_carla_map(town: str) -> tuple[RoadMap, list[warnings.WarningMessage]]:
    """(map, warnings raised while loading it), loaded once per session."""
    path = carla_map_path(town)
    if town not in _LOADED:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            m = RoadMap.from_file(path)
        _LOADED[town] = (m, list(caught))
    return _LOADED[town]
