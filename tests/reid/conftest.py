"""Fixtures of the ReID tests: a GL check for the rendered sets."""

from __future__ import annotations

import pytest


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
