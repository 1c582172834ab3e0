"""dashtraj's cache folder: files it can always rebuild, kept to skip the rebuilding.

What lives there: the built-in towns' OpenDRIVE files (`dashtraj.world.towns.town_path`)
and the towns' static scenes for the renderer (`dashtraj.render.meshes.scene_meshes`).
Deleting the folder, or any file in it, is always safe: what is missing is built again.

The folder is ``$DASHTRAJ_CACHE/<kind>``, else ``$XDG_CACHE_HOME/dashtraj/<kind>`` (when
that is an absolute path, as the XDG base directory spec asks), else
``~/.cache/dashtraj/<kind>``.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

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


def write_whole(path: Path, write: Callable[[BinaryIO], None]) -> bool:
    """Write a cache file whole: `write` fills a temporary sibling, which is then renamed
    over ``path``. Returns False, leaving no file, where the folder cannot be written (a
    cache is an optimisation: that is no error); Ctrl-C removes the temporary file too."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)
        return False
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return True


def touch(path: Path) -> None:
    """Mark a cache file used now (`prune` keeps the last used); nothing where it cannot."""
    try:
        os.utime(path)
    except OSError:  # a cache folder we may read but not write
        pass


def prune(folder: Path, pattern: str, keep: int) -> None:
    """Delete all but the ``keep`` most recently used files of ``folder`` matching
    ``pattern`` (and each one's ``.lock`` file); nothing where another process is at it."""
    try:
        files = sorted(folder.glob(pattern), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in files[keep:]:
            old.unlink(missing_ok=True)
            old.with_name(old.name + ".lock").unlink(missing_ok=True)
    except OSError:
        pass


@contextlib.contextmanager
def building(path: Path) -> Iterator[bool]:
    """Hold an exclusive lock on ``path``'s ``.lock`` file while building it, so that
    processes that need one cache file at once build it once (the others wait, then read
    it). Yields False where the lock file cannot be made (a folder that cannot be
    written: build, but do not write); a file system without locks builds in each."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path.with_name(path.name + ".lock"), "a+b")
    except OSError:
        fh = None
    if fh is None:
        yield False
        return
    with fh:
        try:
            import fcntl

            fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        except (ImportError, OSError):  # Windows, or no locks on this file system
            pass
        yield True
