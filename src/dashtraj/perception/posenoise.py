"""Errors in the observer's own pose, as a real drive's GNSS/INS makes them
(``--pose-noise`` of ``perceive``, ``experiments``, ``tracker eval``, ``localization eval``).

A simulated recording and a rendered or CARLA drive give every camera's exact pose; a real
vehicle knows its own only as well as its GNSS receiver and inertial unit tell it. What
that costs every later stage (the positions of the vehicles it sees, the ``ego``
tracker's odometry, the map-matching, the rebuilt route) is measured by perceiving the
exact frames (their truth boxes stay exact) from a perturbed pose.

The errors follow first-order Gauss-Markov processes, the usual model of GNSS position
error and of an INS's attitude error (slowly wandering, not white: consecutive fixes of a
receiver are strongly correlated): per observer and per axis, stationary with standard
deviation σ and correlation ``exp(-Δt / τ)`` between two frames Δt apart,

    e(t_k) = a e(t_{k-1}) + sqrt(1 - a²) σ n_k,   a = exp(-(t_k - t_{k-1}) / τ),  n_k ~ N(0, 1)

with e(t_0) ~ N(0, σ²): east and north (σ = ``xy_m`` each, so the horizontal error's
RMS is √2 ``xy_m``), heading (``yaw_deg``) and pitch (``pitch_deg``: the INS's pitch and
the camera mount's calibration together). The road elevation under the vehicle (from the
map) and the camera's height are kept. Seeded by (seed, observer id): the same seed gives
the same errors whatever the order in which observers are processed.

Reference levels (horizontal RMS per axis, heading): RTK GNSS with an INS 0.02–0.05 m,
0.1°; automotive GNSS/INS 0.5–1 m, 0.3–0.5°; consumer GNSS (a phone, a dashcam's
receiver) 2–5 m, 1–3°.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.perception.localize import CameraPose

DEFAULT_TAU_S = 30.0
"""Correlation time of the errors, seconds (GNSS position errors wander over tens of
seconds)."""


class PoseNoiseError(DashtrajError):
    """A pose-noise setting that is not a finite, non-negative number."""


@dataclass(frozen=True)
class PoseNoise:
    """Standard deviations of the pose errors: ``xy_m`` per horizontal axis (metres),
    ``yaw_deg`` and ``pitch_deg`` (degrees), and their correlation time ``tau_s``."""

    xy_m: float
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    tau_s: float = DEFAULT_TAU_S

    def __post_init__(self):
        for name in ("xy_m", "yaw_deg", "pitch_deg", "tau_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise PoseNoiseError(f"pose noise {name} must be a finite number >= 0, got {v!r}")
        if self.tau_s <= 0:
            raise PoseNoiseError(f"pose noise tau_s must be > 0, got {self.tau_s!r}")

    @classmethod
    def parse(cls, text: str) -> PoseNoise:
        """``XY_M,YAW_DEG[,PITCH_DEG[,TAU_S]]`` (e.g. ``1.5,1`` or ``0.5,0.3,0.2,30``)."""
        parts = text.split(",")
        if not 2 <= len(parts) <= 4:
            raise PoseNoiseError(f"--pose-noise {text!r}: give XY_M,YAW_DEG[,PITCH_DEG[,TAU_S]]")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise PoseNoiseError(f"--pose-noise {text!r}: not numbers") from None
        try:
            return cls(*vals)
        except PoseNoiseError as exc:
            raise PoseNoiseError(f"--pose-noise {text!r}: {exc}") from None

    def to_list(self) -> list[float]:
        return [self.xy_m, self.yaw_deg, self.pitch_deg, self.tau_s]


class PoseNoiseProcess:
    """The pose errors of one observer over its frames (call `apply` in time order)."""

    def __init__(self, noise: PoseNoise, seed: int, observer_id: int):
        self.noise = noise
        self.rng = np.random.default_rng([int(seed), int(observer_id)])
        self.sigma = np.array([noise.xy_m, noise.xy_m, noise.yaw_deg, noise.pitch_deg])
        self.err: np.ndarray | None = None
        self.t: float | None = None

    def error_at(self, t: float) -> np.ndarray:
        """(east m, north m, yaw °, pitch °) at time ``t`` (not before the previous call)."""
        n = self.rng.standard_normal(4)
        if self.err is None:
            self.err = self.sigma * n
        else:
            if t < self.t:
                raise ValueError(f"pose noise asked at t={t} after t={self.t}")
            a = math.exp(-(t - self.t) / self.noise.tau_s)
            self.err = a * self.err + math.sqrt(max(1.0 - a * a, 0.0)) * self.sigma * n
        self.t = t
        return self.err

    def apply(self, pose: CameraPose, t: float) -> CameraPose:
        """``pose`` as the observer's GNSS/INS would report it at ``t``."""
        e = self.error_at(t)
        pitch = min(max(pose.pitch_deg + float(e[3]), -89.0), 89.0)
        return replace(pose, x=pose.x + float(e[0]), y=pose.y + float(e[1]),
                       yaw_deg=pose.yaw_deg + float(e[2]), pitch_deg=pitch)


def noise_process(noise, seed: int, observer_id: int) -> PoseNoiseProcess | None:
    """A process for ``noise`` (a `PoseNoise`, its `to_list`, or None for exact poses)."""
    if noise is None:
        return None
    if not isinstance(noise, PoseNoise):
        noise = PoseNoise(*noise)
    if noise.xy_m == noise.yaw_deg == noise.pitch_deg == 0:
        return None
    return PoseNoiseProcess(noise, seed, observer_id)
