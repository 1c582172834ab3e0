"""Whole-or-nothing outputs: the one discipline every command that writes a file or folder uses.

A command writes into a temporary sibling of its output (same folder, so the final move is a
``rename`` on one file system) and moves it into place only when everything was written:

    with atomic_output(out, overwrite=args.overwrite, kind="dir") as tmp:
        write_everything_into(tmp)

- An existing non-empty output is refused (`OutputExistsError`, exit code 2) unless
  ``overwrite`` is true; then it is replaced whole, never merged.
- On an exception or Ctrl-C the temporary sibling is removed and what was there before is
  untouched. With ``keep_partial=True`` (a recording interrupted mid-run) the partial output is
  kept under its own new name ``<name>.partial-<n>`` beside the output, never inside an older
  one, and stderr says where.
- Missing parent folders are created.
- A temporary sibling left by a process of this host that was killed outright (SIGKILL, power
  loss) is removed by the next write to the same output (`_sweep_stale`).

The replacement of an existing output is two renames (old → backup, new → output) followed by
removing the backup; if the second rename fails the backup is renamed back, so at every instant
the output path holds either the old output or the new one.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import shutil
import socket
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Literal

from dashtraj.errors import DashtrajError

Kind = Literal["dir", "file"]


class OutputExistsError(DashtrajError):
    """The output exists and ``--overwrite`` was not given."""


class OutputPathError(DashtrajError):
    """The output path cannot be used (a file where a folder is needed, or the reverse)."""


def add_output_args(parser: argparse.ArgumentParser) -> None:
    """Add ``--overwrite`` to a command's parser (see `atomic_output`)."""
    parser.add_argument(
        "--overwrite", action="store_true",
        help="replace an existing output whole (default: refuse to touch it)")


def _is_nonempty(path: Path) -> bool:
    if path.is_dir() and not path.is_symlink():
        return any(path.iterdir())
    return path.exists() or path.is_symlink()


def check_output(path: str | os.PathLike[str], *, overwrite: bool, kind: Kind = "dir") -> Path:
    """Check up front that ``path`` may be written (call before expensive work).

    Returns the path. Raises `OutputExistsError` when it exists (a non-empty folder or any
    file) and ``overwrite`` is false, and `OutputPathError` when it is a file where a folder
    is wanted or the reverse, when a parent is a file, or when the nearest existing parent
    folder is not writable.
    """
    p = Path(path)
    if str(path) == "" or p.name in ("", ".", ".."):
        raise OutputPathError(f"output {str(path)!r}: name a file or folder, not {str(path)!r}")
    for parent in p.parents:
        if parent.exists() and not parent.is_dir():
            raise OutputPathError(f"output {p}: {parent} is a file, not a folder")
    existing = next((q for q in p.absolute().parents if q.exists()), None)
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        raise OutputPathError(f"output {p}: cannot write in {existing} (permission denied)")
    if kind == "dir" and p.exists() and not p.is_dir():
        raise OutputPathError(f"output {p} is a file; this command writes a folder there")
    if kind == "file" and p.is_dir():
        raise OutputPathError(f"output {p} is a folder; this command writes a file there")
    if _is_nonempty(p) and not overwrite:
        raise OutputExistsError(
            f"output {p} exists; pass --overwrite to replace it whole, or choose another path")
    return p


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


_HOST = socket.gethostname().replace(os.sep, "_") or "localhost"


def _free_sibling(path: Path, tag: str, host: bool = False) -> Path:
    """``.<name>.<tag>-<pid>`` (with ``host``: ``.<name>.<tag>-<pid>@<host>``) beside
    ``path``, or the same with a counter if taken."""
    base = path.parent / f".{path.name}.{tag}-{os.getpid()}{'@' + _HOST if host else ''}"
    cand, n = base, 0
    while cand.exists() or cand.is_symlink():
        n += 1
        cand = base.with_name(f"{base.name}-{n}")
    return cand


def _alive(pid: int) -> bool:
    """Whether a process of this id exists on this machine (one we may not signal counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def _sweep_stale(path: Path) -> None:
    """Remove the temporary siblings of ``path`` that a process of this host left behind
    when it was killed outright (SIGKILL, power loss: no cleanup runs): names
    ``.<name>.tmp-<pid>@<host>[-<n>][<suffixes>][-wal|-shm|-journal]`` with this host's name
    and a process id that no longer exists. Anything else is left alone: another host's
    writer (a shared file system), a live process, older names without the host, and the
    ``.old-`` backup of a replacement (it holds the user's previous output)."""
    if os.name != "posix":
        return
    prefix = f".{path.name}.tmp-"
    sfx = re.escape("".join(path.suffixes))
    # SQLite writes its journal beside a database: <tmp>-wal, <tmp>-shm, <tmp>-journal
    pat = re.compile(rf"(\d+)@{re.escape(_HOST)}(?:-\d+)?(?:{sfx})?(?:-wal|-shm|-journal)?")
    try:
        entries = [e for e in path.parent.iterdir() if e.name.startswith(prefix)]
    except OSError:
        return
    for e in entries:
        m = pat.fullmatch(e.name[len(prefix):])
        if m and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            _remove(e)


def _partial_name(path: Path) -> Path:
    n = 1
    while True:
        cand = path.with_name(f"{path.name}.partial-{n}")
        if not (cand.exists() or cand.is_symlink()):
            return cand
        n += 1


def _keep_or_remove(tmp: Path, p: Path, keep_partial: bool, quiet: bool) -> None:
    """After a failure: keep a non-empty ``tmp`` as ``<name>.partial-<n>`` (said on stderr
    unless ``quiet``), or remove it."""
    if keep_partial and (tmp.exists() and (tmp.is_file() or any(tmp.iterdir()))):
        kept = _partial_name(p)
        tmp.rename(kept)
        if not quiet:
            print(f"dashtraj: kept the partial output in {kept} ({p} is unchanged)",
                  file=sys.stderr)
    else:
        _remove(tmp)


def replace_whole(tmp: Path, path: Path) -> None:
    """Move ``tmp`` to ``path``; an existing ``path`` is replaced whole (never merged), and at
    every instant ``path`` holds either the old output or the new one (see the module)."""
    replace_together([(tmp, path)])


def replace_together(moves: list[tuple[Path, Path]]) -> None:
    """Move each staged ``tmp`` to its ``path`` (``(tmp, path)`` pairs), replacing what is
    there, as one step: a failure or Ctrl-C on the way moves every path back to what it held
    before, so the outputs (e.g. a folder and the list that names its files) are never seen
    half old, half new by a later command. The old outputs are removed only once every new
    one is in place."""
    backups: list[tuple[Path, Path]] = []  # (path, its backup)
    placed: list[tuple[Path, Path]] = []  # (tmp, path) moved in
    try:
        for _tmp, path in moves:
            if path.exists() or path.is_symlink():
                backup = _free_sibling(path, "old")
                path.rename(backup)
                backups.append((path, backup))
        for tmp, path in moves:
            tmp.rename(path)
            placed.append((tmp, path))
    except BaseException:
        for tmp, path in reversed(placed):
            path.rename(tmp)
        for path, backup in reversed(backups):
            backup.rename(path)
        raise
    for _path, backup in backups:
        _remove(backup)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], *, overwrite: bool = False,
                  kind: Kind = "dir", keep_partial: bool = False,
                  quiet: bool = False,
                  publish: Callable[[Path, Path], object] | None = None) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write into; move it into place on success.

    Args:
        path: the output file or folder.
        overwrite: replace an existing output whole; otherwise an existing non-empty
            output raises `OutputExistsError` before anything is written.
        kind: ``"dir"`` yields a new empty folder; ``"file"`` yields a path (not created)
            with the output's suffix, to be written by the caller.
        keep_partial: on an exception or Ctrl-C keep what was written as
            ``<name>.partial-<n>`` beside the output (and say so on stderr) instead of
            removing it. Used for recordings, which stay readable when interrupted.
        quiet: do not print where a partial output was kept.
        publish: instead of moving it into place, call ``publish(tmp, path)`` (a sightings
            run appended to the one at ``path``: `dashtraj.store.append.append_file`); when
            it raises, ``tmp`` is kept or removed as on any failure.

    Raises:
        OutputExistsError, OutputPathError: before anything is written.
    """
    p = check_output(path, overwrite=overwrite, kind=kind)
    p.parent.mkdir(parents=True, exist_ok=True)
    _sweep_stale(p)
    tmp = _free_sibling(p, "tmp", host=True)
    if kind == "dir":
        tmp.mkdir()
    else:
        tmp = tmp.with_name(tmp.name + "".join(p.suffixes))
    try:
        yield tmp
    except BaseException as exc:
        _keep_or_remove(tmp, p, keep_partial, quiet)
        if isinstance(exc, OSError) and str(tmp) in str(exc.filename or ""):
            # name the output the user gave, not its temporary sibling
            raise OutputPathError(f"output {p}: cannot write there "
                                  f"({exc.strerror or exc})") from exc
        raise
    if kind == "file" and not tmp.exists():
        raise OutputPathError(f"output {p}: nothing was written")
    if publish is not None:
        try:
            publish(tmp, p)
        except BaseException:
            _keep_or_remove(tmp, p, keep_partial, quiet)
            raise
        return
    try:
        replace_whole(tmp, p)
    except BaseException:
        _remove(tmp)
        raise
