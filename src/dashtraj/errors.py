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


def not_utf8(path, exc: UnicodeDecodeError) -> str:
    """The one-line message for a text input that does not decode as UTF-8."""
    return f"{path}: not UTF-8 text ({exc.reason}: byte {exc.object[exc.start:exc.start + 1]!r})"


class InputFormatError(DashtrajError):
    """A row, column or value of an input file is malformed.

    The message names the file, the line and the column.
    """
