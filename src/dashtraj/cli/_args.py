"""Argument types and checks shared by the commands: every value is checked at the boundary.

The ``type=`` functions raise `argparse.ArgumentTypeError`, which argparse turns into one
line naming the argument (``argument --step: expected a number > 0, got '0'``). The checks
that need more than the text (a point must lie near a driving lane of the map it is used
on) raise `ArgumentError`, a `DashtrajError`: the CLI prints one line and exits 2.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Callable, Iterator

from dashtraj.errors import DashtrajError

MAX_OFF_ROAD_M = 50.0
"""Default of ``--max-off-road``: points farther than this from every driving lane
centre line (metres, plan view) are refused (map route) or dropped (reconstruct)."""


class ArgumentError(DashtrajError):
    """A command-line value that is well-formed but unusable; the message names the argument."""


@contextlib.contextmanager
def progress_bar(quiet: bool, **tqdm_args) -> Iterator[Callable[..., object] | None]:
    """A tqdm bar on stderr (``tqdm_args``: unit, total, ...) when stderr is a terminal and
    not ``quiet``: yields its ``update`` (or None without a bar) and closes it on exit."""
    if quiet or not sys.stderr.isatty():
        yield None
        return
    from tqdm import tqdm

    bar = tqdm(file=sys.stderr, **tqdm_args)
    try:
        yield bar.update
    finally:
        bar.close()


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """A finite float (no nan, no inf)."""
    return _number(text)


def require_file(flag: str, path: str | None) -> None:
    """ArgumentError naming ``flag`` when ``path`` is given and is not a file."""
    from pathlib import Path

    if path is not None and not Path(path).is_file():
        raise ArgumentError(f"{flag} {path!r}: no such file")


def positive_float(text: str) -> float:
    """A finite float > 0 (durations, steps, periods, distances that must not vanish)."""
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


MAX_DURATION_S = 86400.0
"""Longest simulated run, seconds (a day); longer is surely a typo."""


def duration(text: str) -> float:
    """Simulated seconds: finite, > 0 and at most `MAX_DURATION_S`."""
    value = positive_float(text)
    if value > MAX_DURATION_S:
        raise argparse.ArgumentTypeError(
            f"expected at most {MAX_DURATION_S:g} s (a day), got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """A finite float >= 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def fraction(text: str) -> float:
    """A finite float in [0, 1]."""
    value = _number(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return value


def int_at_least(low: int) -> Callable[[str], int]:
    """A ``type=`` for integers >= ``low`` (counts, seeds)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {text!r}")
        return value

    parse.__name__ = f"int_at_least_{low}"
    return parse


count = int_at_least(0)
"""A count that may be zero (observers, agents)."""
positive_int = int_at_least(1)
"""A count of at least one (seeds per town, identities, workers, trips)."""
seed = int_at_least(0)
"""A random seed (numpy's SeedSequence takes integers >= 0)."""


def seed_list(text: str) -> tuple[int, ...]:
    """Seeds as ``A-B`` (inclusive range), ``a,b,c`` (a list) or ``N`` (the first N: 0..N-1).

    ``"0-4"`` → (0, 1, 2, 3, 4); ``"3,8,11"`` → (3, 8, 11); ``"5"`` → (0, 1, 2, 3, 4).
    Seeds are integers >= 0, given once each; a count is >= 1.
    """
    t = text.strip()
    try:
        if "," in t:
            seeds = tuple(int(v) for v in t.split(","))
        elif "-" in t.lstrip("-"):
            lo, hi = (int(v) for v in t.split("-"))
            if hi < lo:
                raise argparse.ArgumentTypeError(
                    f"expected a range A-B with A <= B, got {text!r}")
            seeds = tuple(range(lo, hi + 1))
        else:
            n = int(t)
            if n < 1:
                raise argparse.ArgumentTypeError(
                    f"expected an integer >= 1 (a count), a range A-B or a list a,b,c, "
                    f"got {text!r}")
            seeds = tuple(range(n))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a count N, a range A-B or a list a,b,c of seeds, got {text!r}") from None
    if any(s < 0 for s in seeds):
        raise argparse.ArgumentTypeError(f"expected seeds >= 0, got {text!r}")
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"expected each seed once, got {text!r}")
    return seeds


def xy(text: str) -> tuple[float, float]:
    """``"X,Y"`` → (x, y), CARLA world metres, both finite."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"expected finite X,Y in metres, got {text!r}")
    return x, y


def check_near_road(road_map, point: tuple[float, float], what: str,
                    max_off_road_m: float = MAX_OFF_ROAD_M) -> None:
    """Refuse a point farther than ``max_off_road_m`` (plan view, metres) from every
    driving lane centre line of ``road_map``.

    Raises:
        ArgumentError: naming ``what`` (the argument), the point, its distance and the limit.
    """
    import numpy as np

    proj = road_map.project(np.array([point], dtype=float))
    d = float(proj.distance_m[0])
    if d > max_off_road_m:
        raise ArgumentError(
            f"{what} ({point[0]:g}, {point[1]:g}) is {d:.0f} m from the nearest driving lane "
            f"of {road_map.name} (more than {max_off_road_m:g} m; see --max-off-road); "
            f"'dashtraj map info' prints the map's extent")


def load_map(arg: str, what: str = "map"):
    """The `RoadMap` a user named: an .xodr path, or a built-in town name.

    A built-in town is named as the user wrote it (``town01``), not by its cache file;
    a file keeps its path as name. Warnings of the reader print as ``warning: ...``.

    Raises:
        ArgumentError: neither a file nor a built-in town (naming ``what``).
        OpenDriveError: the file is not OpenDRIVE (naming the file and element).
    """
    from pathlib import Path

    from dashtraj.errors import OpenDriveError
    from dashtraj.roads import RoadMap
    from dashtraj.world.towns import UnknownTownError, resolve_map

    try:
        path = resolve_map(arg)
    except UnknownTownError as exc:
        raise ArgumentError(f"{what} {arg!r} is neither a file nor a built-in town "
                            f"({' '.join(str(exc).split())})") from None
    except OpenDriveError as exc:
        raise ArgumentError(f"{what} {arg!r}: {exc}") from None
    road_map = RoadMap.from_file(path)
    if path != Path(arg):
        road_map.name = str(arg).lower()
    return road_map


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """``--help`` with the description's paragraphs kept and every default shown.

    A default already stated in the help text, a flag's False and a None (no default)
    are not repeated.
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if "default" in text or action.default in (None, False, argparse.SUPPRESS):
            return text
        return super()._get_help_string(action)


PICTURE_SUFFIXES = ("png", "svg", "pdf", "jpg", "jpeg")


def picture_path(text: str) -> str:
    """A path for a matplotlib figure: .png, .svg, .pdf or .jpg."""
    if text.rsplit(".", 1)[-1].lower() not in PICTURE_SUFFIXES or "." not in text:
        raise argparse.ArgumentTypeError(f"name a .png, .svg, .pdf or .jpg file, got {text!r}")
    return text


def image_size(text: str) -> str:
    """``WxH`` in pixels, each side `MIN_IMAGE_SIDE_PX` to `MAX_IMAGE_SIDE_PX` (returned as
    given, for `dashtraj.datasets.frames.parse_size`)."""
    from dashtraj.world.camera import MAX_IMAGE_SIDE_PX, MIN_IMAGE_SIDE_PX

    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH in pixels, e.g. 640x360, got {text!r}") \
            from None
    lo, hi = MIN_IMAGE_SIDE_PX, MAX_IMAGE_SIDE_PX
    if not (lo <= w <= hi and lo <= h <= hi):
        raise argparse.ArgumentTypeError(
            f"expected each side of WxH in {lo}..{hi} pixels, got {text!r}")
    return text


def nms_iou(text: str) -> float | None:
    """``none`` (None) or an IoU in (0, 1]."""
    if text.strip().lower() == "none":
        return None
    value = _number(text)
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected an IoU in (0, 1] or none, got {text!r}")
    return value


def add_detector_filter_args(parser: argparse.ArgumentParser) -> None:
    """``--agnostic-nms IOU|none`` and ``--min-score S``: the detector model's box filters;
    ``--confirm-score S``: the score a track needs once (the ``ego`` tracker)."""
    from dashtraj.perception.detect import DEFAULT_MIN_SCORE
    from dashtraj.perception.detections import AGNOSTIC_NMS_IOU, CONFIRM_SCORE

    parser.add_argument(
        "--agnostic-nms", type=nms_iou, default=AGNOSTIC_NMS_IOU, metavar="IOU|none",
        help="with a detector model, also suppress boxes of other classes overlapping a "
             "better one by this IoU, and boxes lying mostly inside a better one: the 15 "
             "classes are one vehicle seen from the front, back or side (default "
             f"{AGNOSTIC_NMS_IOU:g}; none: the model's class-aware NMS only)")
    parser.add_argument(
        "--min-score", type=fraction, default=DEFAULT_MIN_SCORE, metavar="S",
        help=f"with a detector model, the smallest kept box score (default {DEFAULT_MIN_SCORE:g})")
    parser.add_argument(
        "--confirm-score", type=fraction, default=CONFIRM_SCORE, metavar="S",
        help="the ego tracker reports a track once one of its boxes scored at least S; "
             "weaker boxes only extend tracks (ByteTrack's rule; default "
             f"{CONFIRM_SCORE:g}; 0: every track; the oracle's boxes score 1)")


def detector_filters_used(args: argparse.Namespace) -> dict:
    """The box filters that applied, for a command's JSON: ``agnostic_nms`` (the IoU; None for
    ``none``) and ``min_score``, both None with the oracle (its boxes are exact), and
    ``confirm_score``."""
    model = args.detector != "oracle"
    return {"agnostic_nms": args.agnostic_nms if model else None,
            "min_score": args.min_score if model else None,
            "confirm_score": args.confirm_score}


def pose_noise(text: str) -> tuple[float, float, float, float]:
    """``XY_M,YAW_DEG[,PITCH_DEG[,TAU_S]]``: the observers' GNSS/INS errors
    (`dashtraj.perception.posenoise.PoseNoise`), as a tuple."""
    from dashtraj.perception.posenoise import PoseNoise, PoseNoiseError

    try:
        return tuple(PoseNoise.parse(text).to_list())
    except PoseNoiseError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix(f"--pose-noise {text!r}: ")
                                         + f", got {text!r}") from None


def pose_sigma(text: str) -> tuple[float, float]:
    """``XY_M,YAW_DEG``: the observers' known pose errors (σ per horizontal axis, metres;
    heading σ, degrees), finite and >= 0."""
    parts = text.split(",")
    try:
        vals = tuple(float(v) for v in parts)
    except ValueError:
        vals = ()
    if len(vals) != 2 or not all(math.isfinite(v) and v >= 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected XY_M,YAW_DEG (two numbers >= 0), got "
                                         f"{text!r}")
    return vals


POSE_NOISE_HELP = ("perturb every observer's camera pose as a real drive's GNSS/INS would: "
                   "standard deviations of the east and north errors (m), of the heading and "
                   "the pitch (degrees), slowly wandering with correlation time TAU_S "
                   "(default 30 s); e.g. 1.5,1 (consumer GNSS), 0.5,0.3 (automotive GNSS/INS); "
                   "the truth stays exact (dashtraj.perception.posenoise)")


def add_pose_noise_args(parser: argparse.ArgumentParser, with_seed: bool = True) -> None:
    """``--pose-noise XY,YAW[,PITCH[,TAU]]`` (and ``--pose-noise-seed N``), and
    ``--calibrate-pitch``."""
    parser.add_argument("--pose-noise", type=pose_noise, default=None,
                        metavar="XY_M,YAW_DEG[,PITCH_DEG[,TAU_S]]", help=POSE_NOISE_HELP)
    if with_seed:
        parser.add_argument("--pose-noise-seed", type=seed, default=0, metavar="N",
                            help="seed of the pose errors (default 0)")
    parser.add_argument("--calibrate-pitch", action="store_true",
                        help="correct each observer's camera pitch by the horizon that the "
                             "vehicles it sees drive toward (for a dashcam whose mount or "
                             "INS pitch is known only to a degree; "
                             "dashtraj.perception.selfcal)")


def add_frame_source_args(parser: argparse.ArgumentParser, every_s: float) -> None:
    """The inputs every evaluation on rendered frames takes: recordings, the detector (and
    its box filters), the frame period (seconds) and the image size."""
    parser.add_argument("recordings", nargs="+", metavar="RUN", help="recording directories")
    parser.add_argument("--detector", default="oracle", metavar="oracle|M.onnx",
                        help="detector (default oracle: the renderer's exact visible boxes)")
    add_detector_filter_args(parser)
    parser.add_argument("--every", type=positive_float, default=every_s, metavar="S",
                        help=f"frame period, seconds (default {every_s:g})")
    parser.add_argument("--size", type=image_size, metavar="WxH",
                        help="image size (default: the recording's camera)")
