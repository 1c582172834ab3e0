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
  On a machine without Mesa, EGL opens the GPU driver's context instead (seen: NVIDIA's,
  OpenGL 3.3, on a lent H200, where ``detection-dataset --workers 15`` rendered 8,280
  frames in 36 s); its pixels differ from llvmpipe's.
- ``__EGL_VENDOR_LIBRARY_FILENAMES``: set to the private Mesa's vendor file when one
  is there (below) and the variable is unset.
- ``LP_NUM_THREADS``: llvmpipe's rasterizer threads; pass ``threads`` to pin it (0 =
  rasterize on the calling thread only). Output bytes do not depend on it (checked:
  identical frames with 0 and 2 threads).

The private Mesa: ``scripts/fetch_mesa.sh`` (run by ``make setup`` on Debian 12) unpacks
Mesa 25's llvmpipe from bookworm-backports into ``<venv>/mesa``; the first context of a
process then preloads its libraries and points EGL's vendor loader at it, so the renderer
uses it and the rest of the system keeps its own Mesa. A frame of the default look costs
15–24 % less CPU than with Debian 12's Mesa 22 (1.18–1.31× in ``bench/bench_render.py``
runs, which time both) and the images are the same but for a few pixels off by one level (labels
identical). ``DASHTRAJ_MESA=system`` uses the system's Mesa; ``DASHTRAJ_MESA=DIR`` another
such directory. ``private_mesa()`` says which one a process uses.

Threads, and why setting them often seems to do nothing:

- llvmpipe reads ``LP_NUM_THREADS`` once per process, when its screen is created, i.e.
  with the first EGL context. Later contexts share that screen (and its rasterizer
  threads): ``create_context(threads=2)`` after a first context with 0 threads still
  runs on one thread, and setting the variable after the first context does nothing.
  ``create_context`` warns when asked for a different count than the one in effect.
- The threads only split rasterization (tiles of 64×64 px). Vertex shading and
  triangle setup run on the calling thread, and so does everything in numpy (labels),
  so with 2 cores the gain is at most that of the rasterization share.
- On a machine whose cores are busy with other processes, extra rasterizer threads
  get no core to run on. (Here, 2 shared cores at load ~4: 0, 1 and 2 threads gave the
  same wall-clock and CPU times per frame.)
- Time with ``time.process_time()`` (all threads' CPU), not only wall-clock: with
  ``threads=0`` a frame's CPU time is its one-core cost even on a loaded machine.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import warnings
from pathlib import Path

from dashtraj.errors import DashtrajError

_THREADS_IN_EFFECT: str | None = None  # LP_NUM_THREADS when the first context was made
_MESA_IN_EFFECT: Path | None = None  # the private Mesa this process loaded, if any
MESA_ENV = "DASHTRAJ_MESA"
_VENDOR_ENV = "__EGL_VENDOR_LIBRARY_FILENAMES"
# load order: each library's own dependencies first (none of them has a RUNPATH)
_MESA_LIBS = ("libdrm.so.2", "libdrm_amdgpu.so.1", "libdrm_intel.so.1", "libgallium-*.so",
              "libgbm.so.1", "libEGL_mesa.so.0")


class RenderUnavailableError(DashtrajError):
    """No headless OpenGL context could be created (moderngl, EGL or Mesa missing)."""


def check_samples(ctx, samples: int, name: str = "msaa") -> None:
    """Raise DashtrajError (naming ``name``) unless ``ctx`` can render with ``samples``
    colour samples: 0 or 1 (none), or a power of two up to the context's maximum."""
    most = int(ctx.max_samples)
    if samples > 1 and (samples > most or samples & (samples - 1)):
        raise DashtrajError(f"{name} {samples}: this OpenGL renderer takes 0 or a power of "
                            f"two up to {most} samples")


def _load_triton_first() -> None:
    """Import triton before Mesa's llvmpipe loads, where triton is installed.

    torch's CUDA wheels (the training extra without the CPU wheel) bring triton, whose own
    LLVM crashes the process (SIGSEGV in ``import triton``) when it is loaded after
    llvmpipe's: a GL context first, then ``torch.optim`` (which imports torch._dynamo,
    then triton) dies, in a notebook as in a pytest worker. Loaded first, both work
    (checked: context, a draw and read-back, then AdamW). Without triton this does nothing.
    """
    if _THREADS_IN_EFFECT is None and "triton" not in sys.modules:
        try:
            if importlib.util.find_spec("triton") is not None:
                import triton  # noqa: F401
        except Exception:  # a broken triton install must not stop rendering
            pass


def private_mesa_dir() -> Path | None:
    """The private Mesa directory a new process would use (``DASHTRAJ_MESA``, else
    ``<sys.prefix>/mesa``, holding ``egl_vendor.json``), or None: ``DASHTRAJ_MESA=system``,
    none there, or EGL's vendor list already chosen by the user."""
    value = os.environ.get(MESA_ENV, "")
    if value == "system":
        return None
    d = (Path(value) if value else Path(sys.prefix) / "mesa").resolve()
    vendor = d / "egl_vendor.json"
    if not vendor.is_file():
        return None
    chosen = os.environ.get(_VENDOR_ENV)
    if chosen is not None and chosen != str(vendor):  # the user's own choice (e.g. NVIDIA)
        return None
    return d


def private_mesa() -> Path | None:
    """The private Mesa directory this process's contexts use (None: the system's)."""
    return _MESA_IN_EFFECT


def _load_private_mesa() -> None:
    """Before the first context: preload the private Mesa's libraries (the vendor file
    names only libEGL_mesa, whose dependencies are not on the library path) and point
    EGL at it. Spawned workers inherit the variable and preload them again here."""
    global _MESA_IN_EFFECT
    d = private_mesa_dir()
    if d is None:
        return
    import ctypes

    vendor = d / "egl_vendor.json"
    try:
        for pattern in _MESA_LIBS:
            paths = sorted((d / "lib").glob(pattern))
            if not paths:
                raise OSError(f"{d / 'lib' / pattern} missing")
            ctypes.CDLL(str(paths[-1]), mode=ctypes.RTLD_GLOBAL)
        _point_vendor_file_at(vendor, d / "lib" / "libEGL_mesa.so.0")
    except OSError as e:
        warnings.warn(f"the private Mesa in {d} does not load ({e}); using the system's "
                      f"(set {MESA_ENV}=system to silence this)", RuntimeWarning, stacklevel=3)
        return
    os.environ[_VENDOR_ENV] = str(vendor)
    _MESA_IN_EFFECT = d


def _point_vendor_file_at(vendor: Path, library: Path) -> None:
    """Rewrite the vendor file when it names another path (the checkout was moved or
    copied): EGL would find no driver at all."""
    import json

    try:
        if json.loads(vendor.read_text())["ICD"]["library_path"] == str(library):
            return
    except (OSError, ValueError, KeyError, TypeError):
        pass
    tmp = vendor.with_name(f".{vendor.name}.{os.getpid()}")
    tmp.write_text(json.dumps({"file_format_version": "1.0.0",
                               "ICD": {"library_path": str(library)}}) + "\n")
    os.replace(tmp, vendor)


def prepare_process(threads: int | None = None) -> None:
    """The process-wide part of `create_context`, done once per process: the environment
    variables EGL and Mesa read (``EGL_PLATFORM``, ``LIBGL_ALWAYS_SOFTWARE``,
    ``LP_NUM_THREADS``, the private Mesa's vendor file), triton before llvmpipe, the
    private Mesa's libraries preloaded. Later calls change nothing (a different
    ``threads`` warns).

    It writes ``os.environ`` (C ``setenv``), which may move the process's environment
    while another thread reads it (``getenv``: Mesa, onnxruntime, the C library), a
    crash seen as a segfault in ``getenv`` when a render thread made the first context
    while the main thread started onnxruntime. Call it on the main thread before
    starting threads that will render (`dashtraj.datasets.frames.RenderAhead` does)."""
    global _THREADS_IN_EFFECT
    if _THREADS_IN_EFFECT is not None:
        if threads is not None and str(int(threads)) != _THREADS_IN_EFFECT:
            warnings.warn(
                f"llvmpipe already runs with LP_NUM_THREADS={_THREADS_IN_EFFECT or 'default'} "
                f"in this process; threads={threads} has no effect (set it before the "
                "first context)",
                RuntimeWarning,
                stacklevel=3,
            )
        return
    os.environ.setdefault("EGL_PLATFORM", "surfaceless")
    os.environ.setdefault("LIBGL_ALWAYS_SOFTWARE", "1")
    if threads is not None:
        os.environ["LP_NUM_THREADS"] = str(int(threads))
    _load_triton_first()
    _load_private_mesa()
    _THREADS_IN_EFFECT = os.environ.get("LP_NUM_THREADS", "")


def create_context(threads: int | None = None):
    """Create a standalone headless OpenGL ≥ 3.3 context (moderngl, EGL backend).

    Args:
        threads: llvmpipe rasterizer threads (``LP_NUM_THREADS``); None keeps the
            environment's value or Mesa's default (one per core). Read once per process
            (`prepare_process`).

    Returns:
        a ``moderngl.Context``.

    Raises:
        RenderUnavailableError: moderngl is not installed or EGL/Mesa cannot open a
            context; the message says what to install.
    """
    prepare_process(threads)
    try:
        import moderngl
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise RenderUnavailableError(
            "dashtraj.render needs moderngl: pip install 'moderngl>=5.10'"
        ) from e
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as e:  # moderngl raises plain Exception for EGL failures
        hint = (f"; the private Mesa in {_MESA_IN_EFFECT} was used: {MESA_ENV}=system uses "
                "the system's" if _MESA_IN_EFFECT is not None else "")
        raise RenderUnavailableError(
            f"cannot create a headless EGL OpenGL context ({e}); install Mesa's EGL and "
            "software rasterizer: scripts/install_render_deps.sh "
            f"(apt-get install libegl1 libgl1 libgl1-mesa-dri){hint}"
        ) from e
    return ctx


def threads_in_effect() -> str | None:
    """``LP_NUM_THREADS`` as read by llvmpipe in this process ("" = Mesa's default, one
    per core), or None before the first context."""
    return _THREADS_IN_EFFECT


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
