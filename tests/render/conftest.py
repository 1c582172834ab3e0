"""Fixtures of the renderer tests: a tiny synthetic town (gl_ctx is in tests/conftest.py)."""

from __future__ import annotations

import pytest

from dashtraj.roads import RoadMap
from render_scene import STRAIGHT_XODR


# One straight road along CARLA +x, 200 m: two driving lanes each way (3.5 m),
# 3 m sidewalks, a double yellow centre line, broken white lane dividers and solid
# white edge lines.
@pytest.fixture(scope="session")
def straight_map() -> RoadMap:
    return RoadMap.from_string(STRAIGHT_XODR, name="straight")

