"""Fixtures of the renderer tests: a tiny synthetic town and simple vehicle models."""

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
