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


@pytest.fixture(scope="session")
def pg_server(tmp_path_factory):
    """A PostgreSQL 16 server of this session (the pgserver wheel: its binaries, a data
    folder under the session's tmp, a Unix socket), stopped at the end. Skips where the
    dev extra is not installed, except under CI (`.ci/run` sets CI), where it must be."""
    import os
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # platformdirs: XDG_RUNTIME_DIR unset
        try:
            import pgserver
            import psycopg  # noqa: F401
        except ImportError as e:
            if os.environ.get("CI"):
                raise
            pytest.skip(f"PostgreSQL tests need pip install -e '.[dev]' ({e})")
        srv = pgserver.get_server(tmp_path_factory.mktemp("pg"), cleanup_mode="stop")
    yield srv
    srv.cleanup()


@pytest.fixture
def pg_url(pg_server, request) -> str:
    """A URL of the session's server naming a schema of this test's own (not created)."""
    import hashlib
    import re

    name = re.sub(r"[^a-z0-9_]", "_", request.node.name.lower())[:24]
    tag = hashlib.sha1(request.node.nodeid.encode()).hexdigest()[:6]
    uri = pg_server.get_uri()
    return f"{uri}{'&' if '?' in uri else '?'}schema=t_{name}_{tag}"
