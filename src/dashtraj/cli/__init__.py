"""The `dashtraj` command line.

Each sub-command lives in a module `dashtraj.cli.cmd_<name>` that defines
``register(subparsers)``; this module discovers them, so adding a command never
touches this file. Heavy imports happen inside the command functions, so
``dashtraj --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from dashtraj import __version__
from dashtraj.errors import DashtrajError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except DashtrajError as exc:
        print(f"dashtraj: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("dashtraj: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
