"""The camera's pitch, self-calibrated from the vehicles it sees (``--calibrate-pitch``).

Far positions hang on the camera's pitch: the ``ground`` cue reads a vehicle's distance
from the depression angle of its box's bottom row, a degree or two at 40 m, so an error
of 1° in the pitch (a dashcam's mount, an INS's attitude) moves a car seen 40 m away by
tens of metres (`dashtraj.perception.posenoise` measures it). A real drive's pitch is
known only that well.

The vehicles themselves say where the horizon is. A point at height z above the road,
at depth Z, is seen (f/Z)(h − z) pixels below the horizon, h the camera's height. A
vehicle's lowest pixel is on the road (its nearest wheels), and its top is its roof
about as far away, so while one vehicle comes nearer or drives away, its box's bottom
row and its height in pixels move together on a line:

    β = δ + k α,     β: depression of the bottom row below the pose's horizon,
                     α: the box's height (both as angles), k = h / H (H the vehicle's
                     height, unknown and never needed), δ: the horizon's error,

and the line's intercept (α → 0: the vehicle at infinity) is the pose's pitch error δ:
the true pitch is the pose's plus δ. Every track gives δ by its own least-squares line;
a track seen at one distance only gives nothing (its "leverage" n − (Σα)²/Σα², the
number of its boxes times the share of its α² that is spread, is 0). `PitchCalibrator`
keeps the boxes' (track, t, α, β), weighs them by age (exp(−|Δt| / ``tau_s``)), fits
each track's line and takes the leverage-weighted median of the tracks' intercepts over
the tracks of leverage at least ``min_leverage``, once their leverage adds up to
``min_total`` (until then: no correction; afterwards, when evidence fades, the last
estimate holds).

Only clean boxes count (`box_evidence` 0: not cut by the image border, not partly hidden
by a nearer detection), at least ``min_px`` high (at 720 rows) and at most
``max_alpha_deg`` (nearer, the bottom is the body's lower edge or a wheel well ahead of
the roof). The tracks are the calibrator's own (a box continues the previous frame's box
of its class that it overlaps most, IoU ≥ 0.3), so it needs no tracker and runs before
one: the tracker, the localizers and the stored poses all get the corrected pose (the
stored poses and the tracks the causal one).

`correct` is causal: a frame's correction comes from its own boxes and earlier ones.
`offsets` (offline) uses every frame, before and after, so the first seconds of a
sequence, before enough tracks were seen, get the estimate too (``smoothed`` and
``mapped`` localize once more with those when their sequence ends:
`dashtraj.perception.localize.SmoothedLocalizer`).

Measured on six development recordings (README, "How good must a drive's poses be?"):
with exact poses it costs 0.03–0.05° of pitch; a camera mounted 0.3–1° off is found to a
few hundredths of a degree once a few approaching or receding vehicles were seen.

Assumptions: the road is flat between the camera and the vehicles (the ``ground`` cue's
assumption too), and a vehicle's height does not change while it is tracked.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field, replace

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.perception.detections import iou_matrix
from dashtraj.perception.localize import CameraPose, box_evidence
from dashtraj.world.camera import CameraSpec

_HORIZON_TAUS = 10.0
"""Observations more than this many ``tau_s`` away (weight e^-10) are left out."""


class SelfCalibrationError(DashtrajError):
    """A self-calibration setting out of range, or frames out of time order."""


@dataclass
class PitchCalibrator:
    """The pitch error of one camera's poses (module docstring). One per observer, fed
    its frames in time order.

    Attributes:
        tau_s: age over which an observation's weight falls by e, seconds (a mount's
            error stays; an INS's wanders over tens of seconds).
        min_leverage: a track's least leverage to count.
        min_total: the least leverage of all counted tracks together before the pose
            is corrected.
        min_px: the least box height, pixels at 720 image rows (scaled with the image).
        max_alpha_deg: the greatest box height, degrees.
        max_offset_deg: the greatest correction, degrees.
        link_iou: a box continues the previous frame's box of its class it overlaps
            by at least this IoU.
    """

    tau_s: float = 60.0
    min_leverage: float = 0.5
    min_total: float = 3.0
    min_px: float = 12.0
    max_alpha_deg: float = 6.0
    max_offset_deg: float = 6.0
    link_iou: float = 0.3
    _obs: list = field(default_factory=list, repr=False)
    """Per frame with usable boxes: (t, track ids, α, β) arrays."""
    _prev: tuple | None = field(default=None, repr=False)
    _next_id: int = field(default=0, repr=False)
    _t: float | None = field(default=None, repr=False)
    _last: float = field(default=0.0, repr=False)
    applied: list = field(default_factory=list, repr=False)
    """The correction (degrees) of every frame `correct` returned, in order."""

    def __post_init__(self) -> None:
        for name in ("tau_s", "min_leverage", "min_total", "min_px", "max_alpha_deg",
                     "max_offset_deg", "link_iou"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise SelfCalibrationError(f"PitchCalibrator.{name} must be a finite number "
                                           f"> 0, got {v!r}")

    def observe(self, boxes, class_ids, spec: CameraSpec, pose: CameraPose, t: float) -> None:
        """Take one frame's boxes, seen from ``pose`` at time ``t`` (seconds; frames in
        time order)."""
        if self._t is not None and t < self._t - 1e-9:
            raise SelfCalibrationError(f"PitchCalibrator: a frame at t={t:g} s after one at "
                                       f"t={self._t:g} s (feed frames in time order)")
        self._t = float(t)
        b = np.asarray(boxes, np.float64).reshape(-1, 4)
        cls = np.asarray(class_ids, np.int64).reshape(-1)
        ids = np.full(len(b), -1, np.int64)
        if self._prev is not None and len(self._prev[0]) and len(b):
            m = iou_matrix(b, self._prev[0])
            m[cls[:, None] != self._prev[1][None, :]] = 0.0
            for _ in range(min(m.shape)):
                i, j = np.unravel_index(int(np.argmax(m)), m.shape)
                if m[i, j] < self.link_iou:
                    break
                ids[i] = self._prev[2][j]
                m[i, :] = 0.0
                m[:, j] = 0.0
        new = ids < 0
        ids[new] = self._next_id + np.arange(int(new.sum()))
        self._next_id += int(new.sum())
        self._prev = (b, cls, ids)
        if not len(b):
            return
        f, cy = spec.focal_px, spec.height_px / 2.0
        bottom = np.degrees(np.arctan((b[:, 3] - cy) / f))
        alpha = bottom - np.degrees(np.arctan((b[:, 1] - cy) / f))
        ok = box_evidence(b, spec) == 0
        ok &= (b[:, 3] - b[:, 1]) >= self.min_px * spec.height_px / 720.0
        ok &= alpha <= self.max_alpha_deg
        if ok.any():
            self._obs.append((float(t), ids[ok], alpha[ok], bottom[ok] - pose.pitch_deg))

    def estimate(self, t: float, causal: bool = True) -> float | None:
        """The pitch error at time ``t`` (degrees, to add to the pose's pitch) from the
        observations up to ``t`` (``causal``) or all of them; None while they are too
        few (`min_total`)."""
        times = [o[0] for o in self._obs]
        lo = bisect.bisect_left(times, t - _HORIZON_TAUS * self.tau_s)
        hi = (bisect.bisect_right(times, t + 1e-9) if causal
              else bisect.bisect_right(times, t + _HORIZON_TAUS * self.tau_s))
        obs = self._obs[lo:hi]
        if not obs:
            return None
        ts = np.concatenate([np.full(len(o[1]), o[0]) for o in obs])
        ids = np.concatenate([o[1] for o in obs])
        a = np.concatenate([o[2] for o in obs])
        beta = np.concatenate([o[3] for o in obs])
        w = np.exp(-np.abs(t - ts) / self.tau_s)
        _, k = np.unique(ids, return_inverse=True)
        n, sa, sb = (np.bincount(k, weights=v) for v in (w, w * a, w * beta))
        saa, sab = np.bincount(k, weights=w * a * a), np.bincount(k, weights=w * a * beta)
        lev = n - sa * sa / np.maximum(saa, 1e-12)
        use = lev >= self.min_leverage
        if lev[use].sum() < self.min_total:
            return None
        icpt = (sb[use] - sa[use] * sab[use] / saa[use]) / lev[use]
        order = np.argsort(icpt, kind="stable")
        cw = np.cumsum(lev[use][order])
        med = float(icpt[order][np.searchsorted(cw, 0.5 * cw[-1])])
        return min(max(med, -self.max_offset_deg), self.max_offset_deg)

    def correct(self, boxes, class_ids, spec: CameraSpec, pose: CameraPose, t: float
                ) -> CameraPose:
        """`observe` one frame and return its pose with the pitch corrected by the causal
        estimate (the last one while there is none; none at first)."""
        self.observe(boxes, class_ids, spec, pose, t)
        d = self.estimate(t)
        if d is not None:
            self._last = d
        self.applied.append(self._last)
        return replace(pose, pitch_deg=min(max(pose.pitch_deg + self._last, -89.0), 89.0))

    def offsets(self, times) -> np.ndarray:
        """Offline: the pitch error at each time of ``times`` (seconds, in order) from
        every observation, before and after (the estimate nearest in time where there is
        none; 0 where there is none at all), degrees."""
        times = np.asarray(times, np.float64)
        est = [self.estimate(float(t), causal=False) for t in times]
        have = np.array([e is not None for e in est])
        if not have.any():
            return np.zeros(len(times))
        val = np.array([0.0 if e is None else e for e in est])
        t_have, v_have = times[have], val[have]
        after = np.clip(np.searchsorted(t_have, times), 0, len(t_have) - 1)
        before = np.clip(after - 1, 0, len(t_have) - 1)
        nearest = np.where(np.abs(t_have[after] - times) <= np.abs(t_have[before] - times),
                           v_have[after], v_have[before])
        return np.where(have, val, nearest)
