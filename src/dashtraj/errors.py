"""Domain errors. Each names the thing that was wrong and, where it helps, what to do."""

from __future__ import annotations


class DashtrajError(Exception):
    """Base class of every error dashtraj raises on purpose."""


class OpenDriveError(DashtrajError):
    """A file is not OpenDRIVE, or is broken beyond what a warning can cover."""


class OffRoadError(DashtrajError):
    """A location lies off every lane of the requested type."""


class NoRouteError(DashtrajError):
    """The destination cannot be reached from the origin on the lane graph."""


def read_utf8(path, error: type[Exception] = DashtrajError, encoding: str = "utf-8",
              label=None) -> str:
    """The text of the file ``path`` (a `pathlib.Path`); a file that does not decode
    raises ``error`` with one line naming it (``label``, default the path). OSError
    passes through, for the caller's own message."""
    try:
        return path.read_bytes().decode(encoding)
    except UnicodeDecodeError as exc:
        bad = exc.object[exc.start:exc.start + 1]
        raise error(f"{label or path}: not UTF-8 text ({exc.reason}: byte {bad!r})") from None


class InputFormatError(DashtrajError):
    """A row, column or value of an input file is malformed.

    The message names the file, the line and the column.
    """
