"""Headless OpenGL context for the CPU renderer (EGL + Mesa llvmpipe).

The renderer needs no display and no GPU: ``moderngl`` opens a standalone EGL
context on Mesa's software rasterizer (llvmpipe). Requirements (Debian 12):
``apt-get install libegl1 libgl1 libgl1-mesa-dri`` (``scripts/install_render_deps.sh``)
and ``pip install moderngl``.

Environment set here (only when ``create_context`` is called, never on import, and
never overriding a value the user already set):

- ``EGL_PLATFORM=surfaceless``: no X11/Wayland display is looked for.
- ``LIBGL_ALWAYS_SOFTWARE=1``: Mesa picks llvmpipe even where a GPU driver exists, so
  images are byte-identical on every machine (a GPU driver would rasterize slightly
  differently).
- ``LP_NUM_THREADS``: llvmpipe's rasterizer threads; pass ``threads`` to pin it (it must
  be set before the first context of the process is created; 0 = rasterize on the
  calling thread only). Output bytes do not depend on it.
"""

from __future__ import annotations

import os

from dashtraj.errors import DashtrajError


class RenderUnavailableError(DashtrajError):
    """No headless OpenGL context could be created (moderngl, EGL or Mesa missing)."""


def create_context(threads: int | None = None):
    """Create a standalone headless OpenGL ≥ 3.3 context (moderngl, EGL backend).

    Args:
        threads: llvmpipe rasterizer threads (``LP_NUM_THREADS``); None keeps the
            environment's value or Mesa's default (one per core).

    Returns:
        a ``moderngl.Context``.

    Raises:
        RenderUnavailableError: moderngl is not installed or EGL/Mesa cannot open a
            context; the message says what to install.
    """
    os.environ.setdefault("EGL_PLATFORM", "surfaceless")
    os.environ.setdefault("LIBGL_ALWAYS_SOFTWARE", "1")
    if threads is not None:
        os.environ["LP_NUM_THREADS"] = str(int(threads))
    try:
        import moderngl
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise RenderUnavailableError(
            "dashtraj.render needs moderngl: pip install 'moderngl>=5.10'"
        ) from e
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as e:  # moderngl raises plain Exception for EGL failures
        raise RenderUnavailableError(
            f"cannot create a headless EGL OpenGL context ({e}); install Mesa's EGL and "
            "software rasterizer: scripts/install_render_deps.sh "
            "(apt-get install libegl1 libgl1 libgl1-mesa-dri)"
        ) from e
    return ctx


def context_info(ctx) -> dict[str, str]:
    """Renderer, version and vendor strings of a context (for logs and benchmarks)."""
    return {k: str(ctx.info.get(k, "")) for k in ("GL_RENDERER", "GL_VERSION", "GL_VENDOR")}


_GL_FUNCS: dict[str, object] = {}


def gl_function(name: str, *argtypes):
    """A raw GL entry point (via ``eglGetProcAddress``) for what moderngl does not expose
    (logic ops, per-attachment clears). Call it only while a context is current."""
    fn = _GL_FUNCS.get(name)
    if fn is None:
        import ctypes

        egl = ctypes.CDLL("libEGL.so.1")
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        addr = egl.eglGetProcAddress(name.encode())
        if not addr:
            raise RenderUnavailableError(f"OpenGL entry point {name} not found")
        fn = ctypes.CFUNCTYPE(None, *argtypes)(addr)
        _GL_FUNCS[name] = fn
    return fn
