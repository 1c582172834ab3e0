"""Fixtures shared by every test folder: the real CARLA maps (when ../shared has them), a
headless GL check and one GL context for the session."""

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
def gl_available(gl_ctx):
    """Skip when no headless GL context can be created (no Mesa/EGL/moderngl)."""
    return True


@pytest.fixture(scope="session")
def gl_ctx():
    """One headless context for the session; skips every test if EGL is unavailable."""
    try:
        from dashtraj.render.gl import RenderUnavailableError, create_context
    except ImportError as e:  # pragma: no cover
        pytest.skip(f"dashtraj.render not importable: {e}")
    try:
        ctx = create_context()
    except RenderUnavailableError as e:
        pytest.skip(
            f"no headless EGL/OpenGL context (install scripts/install_render_deps.sh "
            f"and moderngl): {e}"
        )
    yield ctx
    ctx.release()
