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
import sys
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


def main(argv: list[str] | None = None) -> int:
    """Run one `dashtraj` command; returns the exit code (0, 2 for bad input, 130 on Ctrl-C).

    A usage error found by argparse raises ``SystemExit(2)`` after printing its one line,
    as argparse does.
    """
    with clean_warnings():
        parser = build_parser()
        args = parser.parse_args(argv)  # SystemExit(2) after a one-line usage error
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
        except KeyboardInterrupt:
            print("dashtraj: interrupted", file=sys.stderr)
            return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
