"""dashtraj's cache folder: files it can always rebuild, kept to skip the rebuilding.

What lives there: the built-in towns' OpenDRIVE files (`dashtraj.world.towns.town_path`)
and the towns' static scenes for the renderer (`dashtraj.render.meshes.scene_meshes`).
Deleting the folder, or any file in it, is always safe: what is missing is built again.

The folder is ``$DASHTRAJ_CACHE/<kind>``, else ``$XDG_CACHE_HOME/dashtraj/<kind>`` (when
that is an absolute path, as the XDG base directory spec asks), else
``~/.cache/dashtraj/<kind>``.
"""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path

_CODE_LOCK = threading.Lock()
_CODE_SHA256: list[str] = []


def cache_root(kind: str) -> Path:
    """The cache folder of one kind of file (``"towns"``, ``"scenes"``); not created here."""
    env = os.environ.get("DASHTRAJ_CACHE")
    if env:
        return Path(env) / kind
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg and Path(xdg).is_absolute():
        return Path(xdg) / "dashtraj" / kind
    return Path.home() / ".cache" / "dashtraj" / kind


def code_sha256() -> str:
    """Hex sha256 of this dashtraj's code: every ``.py`` file of the package (its path in
    the package and its bytes, in path order) and numpy's version. A cached file built by
    the code carries it in its name, so any change of the code builds it again rather
    than read what other code built. Computed once per process (tens of milliseconds)."""
    with _CODE_LOCK:
        if not _CODE_SHA256:
            import numpy as np

            root = Path(__file__).resolve().parent
            h = hashlib.sha256(f"numpy {np.__version__}\n".encode())
            for p in sorted(root.rglob("*.py")):
                h.update(p.relative_to(root).as_posix().encode() + b"\0")
                h.update(hashlib.sha256(p.read_bytes()).digest())
            _CODE_SHA256.append(h.hexdigest())
        return _CODE_SHA256[0]
