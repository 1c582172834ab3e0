"""CSV files of sightings and trajectories (stdlib `csv`, UTF-8, header required).

Sightings CSV columns (any order; a header row names them):

    required: t, observer_id, observer_x, observer_y, observer_yaw, x, y,
              orientation, vehicle_class
    optional: track_id, distance, bearing, z   (an empty cell means None)

Trajectory CSV columns: x, y, and optionally t.

Units and frames are those of `Sighting` and `Trajectory`: seconds, CARLA world
metres, degrees. Unknown extra columns are ignored with a warning naming them.
Blank lines are skipped. Every malformed value raises `InputFormatError` naming
the file, the 1-based line number and the column, for example
``sightings.csv line 7, column 'x': 'abc' is not a number``.

Writing is deterministic: columns in the fixed order above (the optional
sighting columns always written, empty for None, except z, written only when
some sighting has a height; a trajectory's `t` column only
when it has times), ``\\n`` line ends, and floats as ``repr(float)`` -- the
shortest text that reads back to the very same double, so a file written by
dashtraj reads back and re-writes byte-identically.
"""

from __future__ import annotations

import csv
import io
import math
import warnings
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dashtraj.errors import InputFormatError, read_utf8
from dashtraj.trajectory.records import (
    ORIENTATIONS,
    VEHICLE_CLASSES,
    InvalidTrajectoryError,
    Sighting,
    Trajectory,
)

SIGHTING_REQUIRED: tuple[str, ...] = (
    "t",
    "observer_id",
    "observer_x",
    "observer_y",
    "observer_yaw",
    "x",
    "y",
    "orientation",
    "vehicle_class",
)
SIGHTING_OPTIONAL: tuple[str, ...] = ("track_id", "distance", "bearing", "z")
TRAJECTORY_REQUIRED: tuple[str, ...] = ("x", "y")
TRAJECTORY_OPTIONAL: tuple[str, ...] = ("t",)


class _CellError(Exception):
    """A cell could not be converted; the reader adds file, line and column."""


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _CellError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise _CellError(f"{text!r} is not a finite number")
    return value


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise _CellError(f"{text!r} is not an integer") from None


def _choice(allowed: tuple[str, ...]) -> Callable[[str], str]:
    def parse(text: str) -> str:
        if text not in allowed:
            raise _CellError(f"{text!r} is not one of {', '.join(allowed)}")
        return text

    return parse


def _non_negative(text: str) -> float:
    value = _float(text)
    if value < 0:
        raise _CellError(f"{text!r} is negative; a distance is >= 0 metres")
    return value


_SIGHTING_PARSERS: dict[str, Callable[[str], Any]] = {
    "t": _float,
    "observer_id": _int,
    "observer_x": _float,
    "observer_y": _float,
    "observer_yaw": _float,
    "x": _float,
    "y": _float,
    "orientation": _choice(ORIENTATIONS),
    "vehicle_class": _choice(VEHICLE_CLASSES),
    "track_id": _int,
    "distance": _non_negative,
    "bearing": _float,
    "z": _float,
}


def _read_table(
    path: str | Path,
    required: Sequence[str],
    optional: Sequence[str],
    parsers: dict[str, Callable[[str], Any]],
    what: str,
) -> list[dict[str, Any]]:
    """Rows of a CSV as {column: parsed value or None}, with located errors."""
    path = Path(path)
    name = path.name
    try:
        text = read_utf8(path, InputFormatError, "utf-8-sig", label=name)
    except OSError as exc:
        raise InputFormatError(f"{path}: cannot open ({exc.strerror})") from exc
    with io.StringIO(text, newline="") as handle:
        reader = csv.reader(handle)
        header: list[str] | None = None
        for row in reader:
            if any(cell.strip() for cell in row):
                header = [cell.strip() for cell in row]
                break
        if header is None:
            raise InputFormatError(f"{name}: empty file, expected a header row and {what}")
        header_line = reader.line_num
        seen: set[str] = set()
        for col in header:
            if col in seen:
                raise InputFormatError(
                    f"{name} line {header_line}: column {col!r} appears twice in the header"
                )
            seen.add(col)
        missing = [c for c in required if c not in seen]
        if missing:
            raise InputFormatError(
                f"{name}: missing required column {missing[0]!r}"
                + (f" (also {', '.join(map(repr, missing[1:]))})" if missing[1:] else "")
                + f"; the header has {', '.join(map(repr, header))}"
            )
        known = set(required) | set(optional)
        unknown = [c for c in header if c not in known]
        if unknown:
            warnings.warn(
                f"{name}: ignoring unknown column(s) {', '.join(map(repr, unknown))}",
                stacklevel=3,
            )
        index = {c: i for i, c in enumerate(header) if c in known}
        rows: list[dict[str, Any]] = []
        for row in reader:
            line = reader.line_num
            if not any(cell.strip() for cell in row):
                continue
            if len(row) != len(header):
                raise InputFormatError(
                    f"{name} line {line}: {len(row)} fields, but the header has "
                    f"{len(header)}"
                    + (
                        f"; column {header[len(row)]!r} is missing"
                        if len(row) < len(header)
                        else ""
                    )
                )
            record: dict[str, Any] = {}
            for col, i in index.items():
                text = row[i].strip()
                if text == "":
                    if col in required:
                        raise InputFormatError(
                            f"{name} line {line}, column {col!r}: empty, a value is required"
                        )
                    record[col] = None
                    continue
                try:
                    record[col] = parsers[col](text)
                except _CellError as exc:
                    raise InputFormatError(f"{name} line {line}, column {col!r}: {exc}") from None
            rows.append(record)
    if not rows:
        raise InputFormatError(f"{name}: header only, no {what}")
    return rows


def read_sightings(path: str | Path) -> list[Sighting]:
    """Read a sightings CSV (columns in the module docstring).

    Args:
        path: CSV file; positions CARLA world metres, angles degrees, t seconds.

    Returns:
        The sightings in file order.

    Raises:
        InputFormatError: missing file, empty file or header only, missing
            required column, or a bad value (message names file, line, column).

    Example:
        >>> sightings = read_sightings("sightings.csv")  # doctest: +SKIP
        >>> sightings[0].orientation                       # doctest: +SKIP
        'front'
    """
    rows = _read_table(path, SIGHTING_REQUIRED, SIGHTING_OPTIONAL, _SIGHTING_PARSERS, "sightings")
    for key in SIGHTING_OPTIONAL:
        for row in rows:
            row.setdefault(key, None)
    return [Sighting(**row) for row in rows]


def read_trajectory(path: str | Path) -> Trajectory:
    """Read a trajectory CSV with columns x, y (CARLA world, metres) and optional t (s).

    Args:
        path: CSV file, one point per row in driving order.

    Returns:
        The Trajectory (with `t` when the column exists; then every row needs a t).

    Raises:
        InputFormatError: missing file, no points, missing column, or a bad
            value (message names file, line, column).

    Example:
        >>> traj = read_trajectory("truth.csv")  # doctest: +SKIP
        >>> traj.points.shape                     # doctest: +SKIP
        (120, 2)
    """
    path = Path(path)
    parsers = {"x": _float, "y": _float, "t": _float}
    rows = _read_table(path, TRAJECTORY_REQUIRED, TRAJECTORY_OPTIONAL, parsers, "points")
    points = np.array([[r["x"], r["y"]] for r in rows], dtype=np.float64)
    times = [r.get("t") for r in rows]
    has_t = any(v is not None for v in times)
    if has_t and any(v is None for v in times):
        row = times.index(None)
        raise InputFormatError(
            f"{path.name}: column 't' is empty in data row {row + 1} but set in others; "
            "give every point a time or none"
        )
    try:
        return Trajectory(points, np.array(times, dtype=np.float64) if has_t else None)
    except InvalidTrajectoryError as exc:  # pragma: no cover - cells are checked above
        raise InputFormatError(f"{path.name}: {exc}") from exc


def _fmt_float(value: float) -> str:
    return repr(float(value))


def _fmt_optional(value: Any, fmt: Callable[[Any], str]) -> str:
    return "" if value is None else fmt(value)


def write_sightings(path: str | Path, sightings: Iterable[Sighting]) -> None:
    """Write sightings to CSV, deterministic bytes (see the module docstring).

    Args:
        path: output file (overwritten).
        sightings: records to write, in order.

    Example:
        >>> write_sightings("out.csv", sightings)  # doctest: +SKIP
    """
    with Path(path).open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        sightings = list(sightings)
        with_z = any(s.z is not None for s in sightings)
        writer.writerow(SIGHTING_REQUIRED + SIGHTING_OPTIONAL[:None if with_z else -1])
        for s in sightings:
            writer.writerow(
                [
                    _fmt_float(s.t),
                    str(int(s.observer_id)),
                    _fmt_float(s.observer_x),
                    _fmt_float(s.observer_y),
                    _fmt_float(s.observer_yaw),
                    _fmt_float(s.x),
                    _fmt_float(s.y),
                    s.orientation,
                    s.vehicle_class,
                    _fmt_optional(s.track_id, lambda v: str(int(v))),
                    _fmt_optional(s.distance, _fmt_float),
                    _fmt_optional(s.bearing, _fmt_float),
                    *([_fmt_optional(s.z, _fmt_float)] if with_z else []),
                ]
            )


def write_trajectory(path: str | Path, traj: Trajectory) -> None:
    """Write a trajectory to CSV: columns x, y (metres) and t (seconds) if it has times.

    Args:
        path: output file (overwritten).
        traj: the trajectory.

    Example:
        >>> write_trajectory("truth.csv", Trajectory(np.zeros((1, 2))))  # doctest: +SKIP
    """
    with Path(path).open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        has_t = traj.t is not None
        writer.writerow(["x", "y", "t"] if has_t else ["x", "y"])
        for i, (x, y) in enumerate(traj.points.tolist()):
            row = [_fmt_float(x), _fmt_float(y)]
            if has_t:
                row.append(_fmt_float(traj.t[i]))  # type: ignore[index]
            writer.writerow(row)
