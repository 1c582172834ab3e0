"""Fixtures shared by every test folder: the real CARLA maps (when ../shared has them) and a
headless GL check."""

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


@pytest.fixture(scope="session")
def gl_available():
    """Skip when no headless GL context can be created (no Mesa/EGL/moderngl)."""
    from dashtraj.render.gl import RenderUnavailableError, create_context

    try:
        ctx = create_context(threads=0)
    except RenderUnavailableError as e:
        pytest.skip(f"no headless OpenGL context: {e}")
    ctx.release()
    return True
