"""The `dashtraj` command line.

Each sub-command lives in a module `dashtraj.cli.cmd_<name>` that defines
``register(subparsers)``; this module discovers them, so adding a command never
touches this file. Heavy imports happen inside the command functions, so
``dashtraj --help`` stays fast.

Errors reach the user as ONE line on stderr and exit code 2: argparse's own
usage errors (`DashtrajArgumentParser.error`) and every `DashtrajError` a command
raises (bad argument values, bad input files, an existing output without
``--overwrite``). Warnings print as ``warning: <message>``, without Python's
file and line.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import signal
import sys
import threading
import warnings
from collections.abc import Iterator

from dashtraj import __version__
from dashtraj.errors import DashtrajError


class DashtrajArgumentParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line (``<prog>: error: ...``), exit 2.

    Sub-parsers made by `add_subparsers` inherit the class, so every command's
    argument errors look the same; ``--help`` still prints the full usage.
    """

    def error(self, message: str) -> None:  # type: ignore[override]
        message = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = DashtrajArgumentParser(
        prog="dashtraj",
        description="Reconstruct vehicle routes from what many moving dashcams saw.",
    )
    parser.add_argument("--version", action="version", version=f"dashtraj {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    package = importlib.import_module(__name__)
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name):
        if info.name.startswith("cmd_"):
            importlib.import_module(f"{__name__}.{info.name}").register(sub)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """`warnings.showwarning` for the CLI: ``warning: <message>``, one line, no source."""
    text = " ".join(str(message).split())
    try:
        print(f"warning: {text}", file=file if file is not None else sys.stderr)
    except (OSError, ValueError):  # stderr closed: nowhere to warn
        pass


@contextlib.contextmanager
def clean_warnings() -> Iterator[None]:
    """Print warnings as ``warning: ...`` while the block runs (restored afterwards)."""
    old = warnings.showwarning
    warnings.showwarning = _show_warning
    try:
        yield
    finally:
        warnings.showwarning = old


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a job scheduler's time limit), handled as Ctrl-C: the
    output being written is removed (or kept as ``.partial-N`` where a command keeps partial
    output) and what was there before is untouched."""


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """While inside, SIGTERM raises `Terminated` in this process's main thread.

    Child processes forked meanwhile (perception workers) inherit the handler; in them it
    falls back to the default action (the process ends), so a pool's ``terminate`` still
    stops them. Outside the main thread (signals cannot be set there) it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pid = os.getpid()

    def handler(signum, frame):
        if os.getpid() != pid:  # a forked child: die as SIGTERM's default would
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated()

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def main(argv: list[str] | None = None) -> int:
    """Run one `dashtraj` command; returns the exit code (0, 2 for bad input, 130 on Ctrl-C,
    143 on SIGTERM).

    A usage error found by argparse returns 2 after printing its one line (``--help`` and
    ``--version`` return 0), so in-process callers see the same code as the shell.
    """
    with clean_warnings(), sigterm_as_interrupt():
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # --help / --version (0) or a one-line usage error (2)
            return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
        try:
            return int(args.func(args) or 0)
        except DashtrajError as exc:
            print(f"dashtraj: error: {' '.join(str(exc).split())}", file=sys.stderr)
            return 2
        except BrokenPipeError:  # `dashtraj ... | head`: the reader left; say nothing more
            with contextlib.suppress(OSError):
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 1
        except OSError as exc:  # a path the user named cannot be read or written
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"dashtraj: error: {where}{exc.strerror or exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt as exc:
            how = "terminated" if isinstance(exc, Terminated) else "interrupted"
            print(f"dashtraj: {how}; outputs are written whole or not at all, so an "
                  "existing output is unchanged", file=sys.stderr)
            return 143 if isinstance(exc, Terminated) else 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
