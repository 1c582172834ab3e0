"""Multi-object trackers of one observer's video, chosen by name (`TRACKERS`).

Every tracker is fed frame by frame, in time order, with `update(det, t, pose)`:
the frame's `Detections` (boxes xyxy in image pixels, class ids), its time t
(seconds) and the camera's `CameraPose` (CARLA world). It returns, for each
detection, the id of the confirmed track it belongs to, or −1 (not yet confirmed or
unassigned). Ids start at 1 and are never reused within a tracker.

- ``sort``: SORT (Bewley et al. 2016, the paper's tracker) with the vehicle class in
  the state (Eq. 1: Ψ = [ε, a, r, ε̇, ȧ, η]): a constant-velocity Kalman filter on the
  box centre, area and aspect ratio, Hungarian assignment on IoU (≥ `iou_threshold`,
  boxes of another vehicle class count `class_penalty` less), a track is reported
  once it has `min_hits` consecutive hits (or during the first `min_hits` frames) and
  dies after `max_age` frames without a detection. The Kalman filter runs over all
  tracks at once (arrays), as in the reference implementation's equations.
- ``ego``: uses what a 2-D tracker does not know, the observer's own odometry (its
  camera pose every frame; on a real drive GPS/IMU). Each track is a constant-velocity
  Kalman filter of the vehicle's ground position (CARLA world metres), measured by the
  ``fused`` localizer with an anisotropic covariance: the localizer's range error along
  the viewing ray, a few pixels of bearing across it (a far box is well placed across
  the ray and poorly along it; a box whose hidden bottom edge made ``fused`` take a
  rule's distance counts with the σ of the cues it replaced, `Localized.gate_sigma_m`,
  unless `rule_sigma`). Every frame the predicted ground position is projected
  into the *current* camera: its bearing gives the predicted box column, and the ratio
  of the old to the new distance scales the last box about the principal point (points
  at fixed heights move as 1/depth), so a turning or braking observer moves the
  predicted boxes with the image. Association: Hungarian on 1 − IoU(predicted box,
  detection) plus the squared Mahalanobis distance of the detection's position to the
  track's over a χ² gate; a pair is allowed when IoU ≥ `iou_min` or it is inside the
  gate. Three options are off in the tracker that reports ids and on in the smoothed
  localizers' own filters: a detection at the left or right border meets a prediction
  crossing that border clipped to the image, and may match it when it lies mostly within
  its columns (`clip_iou`: a vehicle leaving or entering the image); a cut or hidden box
  matched although its range lies beyond the gate, or a box too wide for its range
  (`TOO_WIDE`, measured with `width_cap`), updates a track that had a clean box with its
  bearing alone (`robust_range`: a box whose lower part a hedge hides reads tens of
  metres too far). A track ages only while its prediction lies inside the image: a
  vehicle the camera has turned away from is remembered (up to `out_of_view_s`) and picked
  up again where the odometry says it should reappear. Tracks unseen for more than
  `coast_s` are matched in a second stage, to the detections the recent tracks left, on
  the ground-plane Mahalanobis distance alone and the same vehicle class (not on their
  predicted box).
  A track is reported once it has `min_hits` hits, one of them a confident detection
  (score ≥ `confirm_score`, ByteTrack's rule): weak boxes extend tracks but never make one.

Offline, after a whole video: `backfill` gives a confirmed track's first boxes its id, and
`Relink` cuts a track where its look changes and joins the tracks of one vehicle that a gap
split, by their appearance (ReID embeddings). Online: `LiveRelink` does the same cut and join
frame by frame (``perceive --live-relink``). `dashtraj tracker eval` scores all three.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from dashtraj.errors import DashtrajError
from dashtraj.perception.detections import (
    CONFIRM_SCORE,
    VEHICLE_CLASS_INDEX,
    Detections,
    iou_matrix,
)
from dashtraj.perception.localize import PAPER_MU_H, TOO_WIDE, CameraPose, FusedLocalizer
from dashtraj.world.camera import CameraSpec


class TrackerError(DashtrajError):
    """Unknown tracker name or bad tracker settings."""


def _assign(cost: np.ndarray, allowed: np.ndarray):
    """Hungarian assignment on cost (N dets, M tracks) restricted to allowed pairs.

    Returns (matches (K, 2) int: det, track; unmatched dets; unmatched tracks)."""
    n, m = cost.shape
    if n == 0 or m == 0:
        return np.zeros((0, 2), np.int64), np.arange(n), np.arange(m)
    big = 1e6
    c = np.where(allowed, cost, big)
    r, k = linear_sum_assignment(c)
    ok = allowed[r, k]
    matches = np.column_stack([r[ok], k[ok]]).astype(np.int64)
    free_d = np.ones(n, bool)
    free_d[matches[:, 0]] = False
    free_t = np.ones(m, bool)
    free_t[matches[:, 1]] = False
    return matches, np.flatnonzero(free_d), np.flatnonzero(free_t)


# ----------------------------------------------------------------------------- SORT
def _xyxy_to_z(b: np.ndarray) -> np.ndarray:
    """(N, 4) xyxy → (N, 4) [cx, cy, area, ratio] (SORT's measurement)."""
    w = b[:, 2] - b[:, 0]
    h = b[:, 3] - b[:, 1]
    return np.column_stack([b[:, 0] + w / 2, b[:, 1] + h / 2, w * h, w / np.maximum(h, 1e-9)])


def _x_to_xyxy(x: np.ndarray) -> np.ndarray:
    """(N, ≥4) SORT states → (N, 4) xyxy boxes."""
    s = np.maximum(x[:, 2], 1e-9)
    w = np.sqrt(s * np.maximum(x[:, 3], 1e-9))
    h = s / np.maximum(w, 1e-9)
    return np.column_stack([x[:, 0] - w / 2, x[:, 1] - h / 2, x[:, 0] + w / 2, x[:, 1] + h / 2])


_F = np.eye(7)
_F[0, 4] = _F[1, 5] = _F[2, 6] = 1.0
_H = np.eye(4, 7)
_R = np.diag([1.0, 1.0, 10.0, 10.0])
_Q = np.eye(7)
_Q[-1, -1] *= 0.01
_Q[4:, 4:] *= 0.01
_P0 = np.eye(7) * 10.0
_P0[4:, 4:] *= 1000.0  # unobservable initial velocities


@dataclass
class SortTracker:
    """SORT with the class in the state (module docstring). Defaults are SORT's."""

    max_age: int = 1
    min_hits: int = 3
    iou_threshold: float = 0.3
    class_penalty: float = 0.5
    name: str = "sort"
    _x: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)), repr=False)
    _p: np.ndarray = field(default_factory=lambda: np.zeros((0, 7, 7)), repr=False)
    _ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    _votes: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)), repr=False)
    _since: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    _streak: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    _frames: int = 0
    _next_id: int = 1

    def update(self, det: Detections, t: float = 0.0, pose: CameraPose | None = None
               ) -> np.ndarray:
        """Feed one frame; returns (N,) confirmed track id per detection or −1."""
        self._frames += 1
        # predict (SORT keeps the area positive)
        neg = (self._x[:, 6] + self._x[:, 2]) <= 0
        self._x[neg, 6] = 0.0
        self._x = self._x @ _F.T
        self._p = _F @ self._p @ _F.T + _Q
        self._since += 1
        self._streak[self._since > 1] = 0
        pred = _x_to_xyxy(self._x)
        bad = ~np.isfinite(pred).all(1)
        if bad.any():
            self._keep(~bad)
            pred = pred[~bad]
        n = len(det)
        iou = iou_matrix(det.boxes, pred)
        eta = VEHICLE_CLASS_INDEX[det.class_ids] if n else np.zeros(0, np.int64)
        if len(self._ids) and n:  # Eq. 1: the class η is part of the state
            same = eta[:, None] == np.argmax(self._votes, 1)[None, :]
            iou = iou - np.where(same, 0.0, self.class_penalty)
        matches, ud, _ = _assign(-iou, iou >= self.iou_threshold)
        if len(matches):
            d, k = matches[:, 0], matches[:, 1]
            z = _xyxy_to_z(det.boxes[d])
            x, p = self._x[k], self._p[k]
            y = z - x[:, :4]
            s = p[:, :4, :4] + _R
            gain = p[:, :, :4] @ np.linalg.inv(s)
            self._x[k] = x + np.einsum("nij,nj->ni", gain, y)
            self._p[k] = (np.eye(7) - gain @ _H) @ p
            self._since[k] = 0
            self._streak[k] += 1
            self._votes[k, eta[d]] += 1
        if len(ud):
            z = _xyxy_to_z(det.boxes[ud])
            x = np.zeros((len(ud), 7))
            x[:, :4] = z
            votes = np.zeros((len(ud), 5))
            votes[np.arange(len(ud)), eta[ud]] = 1
            new_ids = np.arange(self._next_id, self._next_id + len(ud))
            self._next_id += len(ud)
            self._x = np.vstack([self._x, x])
            self._p = np.concatenate([self._p, np.repeat(_P0[None], len(ud), 0)])
            self._ids = np.concatenate([self._ids, new_ids])
            self._votes = np.vstack([self._votes, votes])
            self._since = np.concatenate([self._since, np.zeros(len(ud), np.int64)])
            self._streak = np.concatenate([self._streak, np.zeros(len(ud), np.int64)])
        out = np.full(n, -1, np.int64)
        if len(matches):
            d, k = matches[:, 0], matches[:, 1]
            show = (self._streak[k] >= self.min_hits) | (self._frames <= self.min_hits)
            out[d[show]] = self._ids[k[show]]
        if len(ud) and self._frames <= self.min_hits:
            m0 = len(self._ids) - len(ud)
            out[ud] = self._ids[m0:]
        self._keep(self._since <= self.max_age)
        return out

    def _keep(self, mask: np.ndarray) -> None:
        for a in ("_x", "_p", "_ids", "_votes", "_since", "_streak"):
            setattr(self, a, getattr(self, a)[mask])


# ------------------------------------------------------------------------------ ego
BEARING_ONLY_SIGMA_REL = 10.0
"""Range σ, as a share of the range, of a detection that updates a track with its bearing
alone (`EgoTracker.robust_range`: a cut or hidden box beyond the gate, a box too wide for
its range)."""


def _border_iou(boxes, pred, spec: CameraSpec, iou_min: float,
                inside_min: float = 0.5) -> np.ndarray:
    """(N, M) IoU of detections with predicted boxes, where a detection touching the left
    or right border meets a prediction crossing that border: then the prediction is
    clipped to the image first (the detection ends at the border; the prediction of a
    vehicle half out of view does not), and the pair counts ``iou_min`` at least when at
    least ``inside_min`` of the detection's columns lie inside the prediction and they
    have rows in common: the part of a vehicle still in view as it leaves or enters the
    image, whose box narrows against the border (and whose lower part a hedge or a
    parked car may hide) while the prediction keeps the whole vehicle's shape. Other
    pairs keep their plain IoU (a prediction clipped to a sliver at the border would
    overlap any small box near it)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    p = np.asarray(pred, np.float64).reshape(-1, 4)
    w = spec.width_px
    iou = iou_matrix(b, p)
    border = (((b[:, 0] <= 1.0)[:, None] & (p[:, 0] < 0.0)[None, :])
              | ((b[:, 2] >= w - 1.0)[:, None] & (p[:, 2] > w)[None, :]))
    if not border.any():
        return iou
    clipped = iou_matrix(b, np.clip(p, 0.0, [w, spec.height_px, w, spec.height_px]))
    cols = np.clip(np.minimum(b[:, None, 2], p[None, :, 2])
                   - np.maximum(b[:, None, 0], p[None, :, 0]), 0.0, None)
    inside = cols / np.maximum(b[:, 2] - b[:, 0], 1e-9)[:, None]
    rows = (b[:, None, 1] < p[None, :, 3]) & (p[None, :, 1] < b[:, None, 3])
    clipped = np.where(rows & (inside >= inside_min), np.maximum(clipped, iou_min), clipped)
    return np.where(border, clipped, iou)


@dataclass
class EgoTracker:
    """Ground-plane tracker using the observer's odometry (module docstring).

    Attributes:
        spec: the camera of the images (size, FOV, mount).
        max_age_s: seconds a track survives without a detection while predicted inside
            the image (its ground-plane prediction keeps it matchable through occlusions).
        min_hits: hits before a track is reported.
        iou_min: a pair with at least this IoU of predicted and detected box may match.
        gate_chi2: gate on the squared Mahalanobis distance (2 degrees of freedom).
        cross_px: bearing error of a detection's centre, pixels (across-ray σ).
        out_of_view_s: seconds a track predicted outside the image is kept.
        view_margin_px: a prediction this far inside the image border counts as in view.
        accel_mps2: process noise, the vehicles' acceleration (m/s², 1 σ).
        mu_h: Eq. 3's constant of the ``fused`` localizer that measures positions.
        coast_s: tracks unseen for longer than this (seconds) coast: they are matched
            after the recent ones, to the detections left, on the Mahalanobis distance of
            the ground positions alone (≤ ``coast_chi2``, the same vehicle class; their
            covariance has grown with the time unseen), not on the predicted box's IoU.
            None: one association for all.
        confirm_score: a track is reported once it has ``min_hits`` hits *and* one of
            them scored at least this much (ByteTrack's rule that only a confident
            detection starts a track; weaker ones only extend it). A run of weak boxes
            (a detector's guess at a wheel, a shadow or a part of a car beside a better
            box) is followed but never reported. 0: every track with ``min_hits`` hits.
            The default, 0.5, is ByteTrack's high-score threshold; the oracle's boxes
            score 1. Measured on the development runs of the experiments from pixels
            (seeds 5-9, the shipped detector; README, "Results"): the target's tracks
            within 15 m 85 → 63, ReID recall 0.66 → 0.81 at the same precision, 9 of 684
            true sightings fewer, hmm SSPD unchanged.
        rule_sigma: update the filter with ``fused``'s σ of a box whose distance a
            hidden-bottom rule set (`HIDDEN_SIGMA_REL` of it), while the gate keeps the
            σ of the cues it replaced. The smoothed localizers' filters do (a misread
            box then moves a track's position less); the tracker that reports ids does
            not (on e11-e15 its IDF1 fell 0.782 -> 0.777 with it).
        width_cap: measure with ``fused``'s width bound (`FusedLocalizer.width_cap`).
            This and the next two are off in the tracker that reports ids (its ids and
            `tracked` stay as they were measured) and on in the smoothed localizers' own
            filters (`SmoothedLocalizer`), which their positions come from.
        clip_iou: a detection at the left or right border meets a prediction crossing
            that border clipped to the image, and may match it whatever their IoU when
            it lies mostly within its columns (`_border_iou`): a vehicle leaving or
            entering the image keeps its track while its box shrinks against the border.
        robust_range: a detection whose box is cut or hidden (`box_evidence`), matched on
            its overlap with a track although its range lies beyond the gate (squared
            Mahalanobis distance > ``gate_chi2``), or whose box is too wide for its range
            (`TOO_WIDE`: the range is only a bound), updates a track that had a clean box
            (whose range it can trust more) with its bearing alone (range σ
            `BEARING_ONLY_SIGMA_REL` of it); and a track's last box is scaled to later
            frames from the filter's range when it was seen, not the detection's.
    """

    spec: CameraSpec = field(default_factory=CameraSpec)
    max_age_s: float = 3.0
    min_hits: int = 3
    iou_min: float = 0.1
    accel_mps2: float = 3.0
    class_penalty: float = 0.5
    gate_chi2: float = 36.0
    cross_px: float = 4.0
    out_of_view_s: float = 6.0
    view_margin_px: float = 0.0
    mu_h: float = PAPER_MU_H
    coast_s: float | None = 0.5
    coast_chi2: float = 16.0
    confirm_score: float = CONFIRM_SCORE
    rule_sigma: bool = False
    width_cap: bool = False
    clip_iou: bool = False
    robust_range: bool = False
    name: str = "ego"
    _x: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)), repr=False)
    _p: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)), repr=False)
    _box: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)), repr=False)
    _dist: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    _ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    _votes: np.ndarray = field(default_factory=lambda: np.zeros((0, 5)), repr=False)
    _since: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    _hits: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    _strong: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), repr=False)
    _clean: np.ndarray = field(default_factory=lambda: np.zeros(0, bool), repr=False)
    _last: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    _hidden: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    _t: float | None = None
    _next_id: int = 1
    positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    """After each `update`, (N, 2): every detection's ground position filtered by its
    track (the track's state after this frame's measurement; a new track's is the
    measurement itself), CARLA world metres."""
    innovation_d2: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    """After each `update`, (N,): squared Mahalanobis distance of each detection's measured
    position to its track's prediction (inf for a detection that started a track)."""
    track_of: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64), repr=False)
    """After each `update`, (N,): the track of every detection, confirmed or not (the id
    `update` reports once the track has ``min_hits`` hits; see `backfill`)."""
    position_cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 2)), repr=False)
    """After each `update`, (N, 2, 2): the covariance of `positions` (m²; a new track's is
    its measurement's)."""
    measured: object = field(default=None, repr=False)
    """After each `update`: the ``fused`` localizer's `Localized` of the frame's detections."""

    def predicted_boxes(self, pose: CameraPose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predicted boxes (M, 4) in the current camera, their ranges (M,) metres and
        whether each lies in front of the camera (M,) bool."""
        spec = self.spec
        f, cu, cv = spec.focal_px, spec.width_px / 2.0, spec.height_px / 2.0
        dx = self._x[:, 0] - pose.x
        dy = self._x[:, 1] - pose.y
        h = math.radians(pose.yaw_deg)
        fwd = dx * math.cos(h) + dy * math.sin(h)
        right = -dx * math.sin(h) + dy * math.cos(h)
        dist = np.hypot(dx, dy)
        front = fwd > 0.5
        u = cu + f * right / np.where(front, fwd, 1.0)
        scale = self._dist / np.maximum(dist, 0.5)
        b = self._box
        half_w = 0.5 * (b[:, 2] - b[:, 0]) * scale
        v0 = cv + (b[:, 1] - cv) * scale
        v1 = cv + (b[:, 3] - cv) * scale
        box = np.column_stack([u - half_w, v0, u + half_w, v1])
        return box, dist, front

    SETTINGS = ("spec", "max_age_s", "min_hits", "iou_min", "accel_mps2", "class_penalty",
                "gate_chi2", "cross_px", "out_of_view_s", "view_margin_px", "mu_h", "coast_s",
                "coast_chi2", "confirm_score", "rule_sigma", "width_cap",
                "clip_iou", "robust_range")
    """The fields that set its behaviour (the rest is state)."""

    def same_settings(self, other: EgoTracker) -> bool:
        """Whether ``other`` has the same `SETTINGS` (fed the same frames, both give the
        same ids and positions)."""
        return all(getattr(self, a) == getattr(other, a) for a in self.SETTINGS)

    def update(self, det: Detections, t: float, pose: CameraPose) -> np.ndarray:
        """Feed one frame; returns (N,) confirmed track id per detection or −1."""
        n = len(det)
        loc = FusedLocalizer(self.mu_h, width_cap=self.width_cap).localize(
            det.boxes, det.class_ids, self.spec, pose)
        zx = np.column_stack([loc.x, loc.y])
        dt = 0.0 if self._t is None else max(float(t) - self._t, 0.0)
        self._t = float(t)
        # predict: constant velocity in the ground plane
        F = np.eye(4)
        F[0, 2] = F[1, 3] = dt
        q = self.accel_mps2**2
        g = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
        Q = q * g @ g.T + np.eye(4) * 1e-4
        self._x = self._x @ F.T
        self._p = F @ self._p @ F.T + Q
        self._since += 1
        m = len(self._ids)
        if m:  # time unseen counts only while the prediction is inside the image
            self._hidden += dt * self._in_view(pose)
        eta = VEHICLE_CLASS_INDEX[det.class_ids] if n else np.zeros(0, np.int64)
        strong = np.asarray(det.scores, np.float64) >= self.confirm_score
        lost = self._hidden > self.max_age_s + 1e-9
        evidence = np.asarray(loc.evidence)
        own = self.rule_sigma and loc.gate_sigma_m is not None  # the update's σ: the rules'
        sig_upd = loc.sigma_m if own or loc.gate_sigma_m is None else loc.gate_sigma_m
        r_det = self._meas_cov(loc, pose, loc.gate_sigma_m)  # the gate's; the update's:
        r_upd = self._meas_cov(loc, pose) if own else r_det
        if n and m:
            pbox, _, front = self.predicted_boxes(pose)
            if self.clip_iou:
                iou = _border_iou(det.boxes, pbox, self.spec, self.iou_min)
            else:
                iou = iou_matrix(det.boxes, pbox)
            iou = np.where(front[None, :], iou, 0.0)
            v = zx[:, None, :] - self._x[None, :, :2]
            S = self._p[None, :, :2, :2] + r_det[:, None]
            d2 = np.einsum("nmi,nmij,nmj->nm", v, np.linalg.inv(S), v)  # Mahalanobis²
            same = eta[:, None] == np.argmax(self._votes, 1)[None, :]
            cost = (1.0 - iou) + d2 / self.gate_chi2 + np.where(same, 0.0, self.class_penalty)
            allowed = ((iou >= self.iou_min) | (d2 <= self.gate_chi2)) & ~lost[None, :]
            if self.coast_s is None:
                matches, ud, _ = _assign(cost, allowed)
            else:  # recent tracks first; then tracks coasting longer, by ground position
                recent = (self._t - self._last) <= self.coast_s + 1e-9
                matches, ud, _ = _assign(cost, allowed & recent[None, :])
                old = np.flatnonzero(~recent)
                if len(ud) and len(old):
                    a2 = (d2[np.ix_(ud, old)] <= self.coast_chi2) & same[np.ix_(ud, old)]
                    m2, ud2, _ = _assign(d2[np.ix_(ud, old)], a2)
                    if len(m2):
                        matches = np.vstack([matches, np.column_stack([ud[m2[:, 0]],
                                                                       old[m2[:, 1]]])])
                    ud = ud[ud2]
        else:
            matches, ud = np.zeros((0, 2), np.int64), np.arange(n)
        if len(matches) and self.robust_range:
            # a box cut or hidden (`box_evidence`) matched on its overlap although its range
            # lies beyond the gate (its bottom or height misleads), or too wide for its
            # range (`TOO_WIDE`: the range is only a bound): its bearing alone updates the
            # track (a clean box's range stands: the track may be the one that is wrong)
            d, k = matches[:, 0], matches[:, 1]
            ev = evidence[d]
            blind = np.zeros(n, bool)
            blind[d] = (((d2[d, k] > self.gate_chi2) & (ev != 0)) | ((ev & TOO_WIDE) != 0)) \
                & self._clean[k]  # a track that never had a clean box knows no better
            if blind.any():
                r_upd = self._meas_cov(loc, pose, np.where(
                    blind, BEARING_ONLY_SIGMA_REL * loc.distance_m, sig_upd))
        if len(matches):
            d, k = matches[:, 0], matches[:, 1]
            x, p = self._x[k], self._p[k]
            s = p[:, :2, :2] + r_upd[d]
            gain = p[:, :, :2] @ np.linalg.inv(s)
            self._x[k] = x + np.einsum("nij,nj->ni", gain, zx[d] - x[:, :2])
            self._p[k] = (np.eye(4) - gain @ np.eye(2, 4)) @ p
            self._box[k] = det.boxes[d]
            # the range the box was seen at, to scale it by later: the filter's (an
            # outlying range would scale the predicted box off the vehicle)
            self._dist[k] = (np.hypot(self._x[k, 0] - pose.x, self._x[k, 1] - pose.y)
                             if self.robust_range else loc.distance_m[d])
            self._since[k] = 0
            self._hits[k] += 1
            self._strong[k] |= strong[d]
            self._clean[k] |= evidence[d] == 0
            self._votes[k, eta[d]] += 1
        if len(ud):
            k = len(ud)
            x = np.zeros((k, 4))
            x[:, :2] = zx[ud]
            p = np.zeros((k, 4, 4))
            p[:, :2, :2] = r_upd[ud]
            p[:, 2, 2] = p[:, 3, 3] = 10.0**2  # unknown velocity, up to ~10 m/s
            votes = np.zeros((k, 5))
            votes[np.arange(k), eta[ud]] = 1
            self._x = np.vstack([self._x, x])
            self._p = np.concatenate([self._p, p])
            self._box = np.vstack([self._box, det.boxes[ud]])
            self._dist = np.concatenate([self._dist, loc.distance_m[ud]])
            self._ids = np.concatenate([self._ids, np.arange(self._next_id, self._next_id + k)])
            self._next_id += k
            self._votes = np.vstack([self._votes, votes])
            self._since = np.concatenate([self._since, np.zeros(k, np.int64)])
            self._hits = np.concatenate([self._hits, np.ones(k, np.int64)])
            self._strong = np.concatenate([self._strong, strong[ud]])
            self._clean = np.concatenate([self._clean, evidence[ud] == 0])
            self._last = np.concatenate([self._last, np.full(k, self._t)])
            self._hidden = np.concatenate([self._hidden, np.zeros(k)])
        self.measured = loc
        self.positions = zx.copy()
        self.track_of = np.full(n, -1, np.int64)
        if len(matches):
            self.track_of[matches[:, 0]] = self._ids[matches[:, 1]]
        if len(ud):
            self.track_of[ud] = self._ids[len(self._ids) - len(ud):]
        self.position_cov = r_upd.copy()
        self.innovation_d2 = np.full(n, np.inf)
        if len(matches):
            self.positions[matches[:, 0]] = self._x[matches[:, 1], :2]
            self.position_cov[matches[:, 0]] = self._p[matches[:, 1], :2, :2]
            self.innovation_d2[matches[:, 0]] = d2[matches[:, 0], matches[:, 1]]
        out = np.full(n, -1, np.int64)
        if len(matches):
            d, k = matches[:, 0], matches[:, 1]
            show = (self._hits[k] >= self.min_hits) & self._strong[k]
            out[d[show]] = self._ids[k[show]]
        self._last[self._since == 0] = self._t
        self._hidden[self._since == 0] = 0.0
        keep = ((self._hidden <= self.max_age_s + 1e-9)
                & ((self._t - self._last) <= max(self.max_age_s, self.out_of_view_s) + 1e-9))
        for a in ("_x", "_p", "_box", "_dist", "_ids", "_votes", "_since", "_hits", "_strong",
                  "_clean", "_last", "_hidden"):
            setattr(self, a, getattr(self, a)[keep])
        return out


    def _in_view(self, pose: CameraPose) -> np.ndarray:
        """(M,) bool: the predicted box of each track lies (partly) inside the image."""
        box, _, front = self.predicted_boxes(pose)
        mg = self.view_margin_px
        return (front & (box[:, 2] > mg) & (box[:, 0] < self.spec.width_px - mg))

    def _meas_cov(self, loc, pose, sigma_m=None) -> np.ndarray:
        """(N, 2, 2) covariance of each localized position (CARLA world, m²): the
        localizer's range error along the ray (``sigma_m``; None: ``loc.sigma_m``),
        ``cross_px`` pixels of bearing across it."""
        ang = np.radians(pose.yaw_deg + loc.bearing_deg)
        u = np.stack([np.cos(ang), np.sin(ang)], -1)
        w = np.stack([-u[:, 1], u[:, 0]], -1)
        sr = np.maximum(loc.sigma_m if sigma_m is None else sigma_m, 0.3) ** 2
        sc = np.maximum(loc.distance_m * self.cross_px / self.spec.focal_px, 0.3) ** 2
        return (sr[:, None, None] * u[:, :, None] * u[:, None, :]
                + sc[:, None, None] * w[:, :, None] * w[:, None, :])

class Backfill:
    """Offline confirmation for a tracker that reports each detection's track
    (``track_of``, `EgoTracker`): a track's first boxes, reported −1 while it had fewer
    than ``min_hits`` hits, get its id once it is confirmed. Feed `add` every frame after
    the tracker's update; it returns, for the boxes of earlier frames that now get an id,
    (frame key, index in that frame, id). Tracks never confirmed stay −1 (what min_hits
    is for: one-off false detections)."""

    def __init__(self):
        self._pending: dict[int, list] = {}

    def add(self, key, ids: np.ndarray, track_of: np.ndarray) -> list[tuple]:
        out = []
        for i, (tid, raw) in enumerate(zip(ids.tolist(), track_of.tolist(), strict=True)):
            if raw <= 0:
                continue
            if tid > 0:
                out.extend((k, j, tid) for k, j in self._pending.pop(raw, ()))
            else:
                self._pending.setdefault(raw, []).append((key, i))
        return out


def backfill(ids_per_frame, track_of_per_frame) -> list[np.ndarray]:
    """Every frame's reported ids with `Backfill` applied (a whole sequence at once)."""
    out = [np.array(ids, np.int64, copy=True) for ids in ids_per_frame]
    bf = Backfill()
    for k, (ids, raw) in enumerate(zip(ids_per_frame, track_of_per_frame, strict=True)):
        for f, j, tid in bf.add(k, np.asarray(ids), np.asarray(raw)):
            out[f][j] = tid
    return out


def _may_follow(rules, gap: float, same_class: bool, end: np.ndarray,
                start: np.ndarray) -> bool:
    """The join rules of `Relink` and `LiveRelink` (``rules``: either) but the look: a
    track that starts ``gap`` seconds after another's last box, at ``start`` (m), may
    continue it when the gap is positive and at most ``max_gap_s``, both are one vehicle
    class, and ``start`` is within ``max_speed_mps`` × the gap + ``slack_m`` of the other's
    last position ``end``."""
    return (0 < gap <= rules.max_gap_s and same_class
            and np.hypot(*(start - end)) <= rules.max_speed_mps * gap + rules.slack_m)


@dataclass
class Relink:
    """Offline re-linking of one observer's tracks by appearance: a track that took another
    vehicle's boxes is cut where its look changes, and the tracks of one vehicle that a gap
    split (the vehicle hidden, or out of the image, for longer than the tracker remembers
    it) are joined into one identity.

    Feed `add` every frame after the tracker's update with the detections' classes, their
    ground positions as the tracks filtered them (`EgoTracker.positions`) and an appearance
    embedding per detection (the ReID model's, L2-normalised; a NaN row for a box not
    embedded: `ReidEmbedder.embed_boxes` embeds the boxes at least `min_box_px` high). Then
    `apply` takes the ids reported for those frames (a tracker's online ids, or `backfill`'s)
    and returns them re-linked:

    1. **Cut.** A track's embeddings in time order are cut in two where the means of the two
       parts (at least `split_min_crops` each) are farthest apart, if that is more than
       `split_distance`; the later part gets a new id.
    2. **Join.** A track's look is the mean of its embeddings. Track B may follow track A
       when B's first box comes after A's last (one camera never sees a vehicle twice at
       once), within `max_gap_s`, of the same vehicle class, no farther from A's last
       position than `max_speed_mps` × the gap + `slack_m` (the ground positions of far
       boxes are poor along the ray), and with an appearance distance (L2 of the unit
       means) ≤ `max_distance`. The allowed pairs are taken greedily, nearest look first,
       each track with at most one successor and one predecessor; a chain takes the id of
       its first track. (The two parts of a cut are more than ``split_distance`` apart, so
       they are never joined to each other.)

    Settings chosen on development recordings with the shipped ReID model (README,
    "Re-linking tracks by appearance"): the tracks of one vehicle are a median 0.39 apart
    there, those of two vehicles of one class 0.97 (boxes ≥ 12 px high). `tracker eval`
    embeds for it with the shipped track-join model (`dashtraj.reid.embed.JOIN_MODEL`,
    trained on with shrunk images), which joins better with the same settings.
    """

    max_distance: float = 0.6
    max_gap_s: float = 30.0
    min_box_px: float = 10.0
    max_speed_mps: float = 25.0
    slack_m: float = 10.0
    split_distance: float | None = 0.8
    split_min_crops: int = 5
    _frames: list = field(default_factory=list, repr=False)

    def add(self, t: float, class_ids: np.ndarray, positions: np.ndarray,
            embeddings: np.ndarray | None) -> None:
        """One frame: (N,) class ids, (N, 2) ground positions, (N, D) embeddings (NaN
        rows: none; None: none at all)."""
        cls = np.asarray(class_ids, np.int64)
        self._frames.append((float(t), VEHICLE_CLASS_INDEX[cls],
                             np.asarray(positions, np.float64).reshape(-1, 2),
                             None if embeddings is None else np.asarray(embeddings, np.float32)))

    def apply(self, ids_per_frame) -> list[np.ndarray]:
        """The ids reported for the added frames (−1: none), re-linked (the module
        docstring of `Relink`): a chain of tracks carries the id of its first one, the
        later part of a cut track a new id above every id given."""
        if len(ids_per_frame) != len(self._frames):
            raise ValueError(f"{len(ids_per_frame)} frames of ids for {len(self._frames)} added")
        out = [np.array(ids, np.int64, copy=True) for ids in ids_per_frame]
        occ: dict[int, list] = {}
        for fi, ids in enumerate(out):
            for j, i in enumerate(ids.tolist()):
                if i > 0:
                    occ.setdefault(i, []).append((fi, j))
        nxt = max(occ, default=0) + 1
        if self.split_distance is not None:
            for i in sorted(occ):
                cut = self._cut(occ[i])
                if cut is not None:
                    for fi, j in occ[i][cut:]:
                        out[fi][j] = nxt
                    occ[nxt] = occ[i][cut:]
                    occ[i] = occ[i][:cut]
                    nxt += 1
        head = self._join(occ)
        return [np.array([head.get(i, i) if i > 0 else i for i in ids.tolist()], np.int64)
                for ids in out]

    def _emb(self, fi: int, j: int) -> np.ndarray | None:
        e = self._frames[fi][3]
        return None if e is None or np.isnan(e[j, 0]) else e[j].astype(np.float64)

    def _cut(self, boxes: list) -> int | None:
        """Where to cut one track (index into its boxes), or None."""
        k = self.split_min_crops
        seen = [(n, e) for n, (fi, j) in enumerate(boxes)
                if (e := self._emb(fi, j)) is not None]
        if len(seen) < 2 * max(k, 1):
            return None
        c = np.cumsum([e for _, e in seen], 0)
        m = np.arange(max(k, 1), len(seen) - max(k, 1) + 1)
        a, b = c[m - 1], c[-1] - c[m - 1]
        d = np.linalg.norm(a / np.linalg.norm(a, axis=1, keepdims=True)
                           - b / np.linalg.norm(b, axis=1, keepdims=True), axis=1)
        best = int(np.argmax(d))
        return seen[m[best]][0] if d[best] > self.split_distance else None

    def _join(self, occ: dict) -> dict[int, int]:
        """{track id: id of the first track of its chain}."""
        tr = {}
        for i, boxes in occ.items():
            (f0, j0), (f1, j1) = boxes[0], boxes[-1]
            votes = np.zeros(5)
            s, n = None, 0
            for fi, j in boxes:
                votes[self._frames[fi][1][j]] += 1
                e = self._emb(fi, j)
                if e is not None:
                    s, n = (e if s is None else s + e), n + 1
            if n and np.linalg.norm(s) > 0:
                tr[i] = (self._frames[f0][0], self._frames[f1][0], self._frames[f0][2][j0],
                         self._frames[f1][2][j1], int(np.argmax(votes)), s / np.linalg.norm(s))
        pairs = []
        for a, (_, ta1, _, pa1, ca, ua) in tr.items():
            for b, (tb0, _, pb0, _, cb, ub) in tr.items():
                if not _may_follow(self, tb0 - ta1, ca == cb, pa1, pb0):
                    continue
                d = float(np.linalg.norm(ua - ub))
                if d <= self.max_distance:
                    pairs.append((d, a, b))
        pairs.sort()
        succ: dict[int, int] = {}
        pred: dict[int, int] = {}
        for _, a, b in pairs:
            if a not in succ and b not in pred:
                succ[a], pred[b] = b, a
        head: dict[int, int] = {}
        for i in sorted(occ, key=lambda i: (self._frames[occ[i][0][0]][0], i)):
            head[i] = head[pred[i]] if i in pred else i
        return head


@dataclass
class LiveRelink:
    """`Relink` done online, frame by frame, for a tracker that must report an id the
    moment it sees a box (a live dashcam; `dashtraj tracker eval` scores it as
    ``"<name>+live-relink"``). Feed `update` every frame after the tracker's: the
    tracker's ``track_of`` (every detection's track, confirmed or not), the ids it
    reported, the classes, the filtered ground positions and the embeddings (NaN rows:
    none; `Relink.add`'s). It returns the ids to report instead. Each tracker track is an
    identity of its own, unless:

    1. **Join.** For `join_window_s` after an identity appeared, once it holds
       `join_min_crops` embedded boxes, it takes over an identity that is out of sight
       now, with `Relink`'s join rules against the mean of the boxes seen so far: it
       started after the other's last box, within `max_gap_s`, the same vehicle class,
       no farther than `max_speed_mps` × the gap + `slack_m`, mean looks ≤
       `max_distance` apart (nearest first). The boxes reported before the join keep the
       identity they had.
    2. **Cut.** When the mean of a track's last `split_crops` embedded boxes is more than
       `split_distance` from the mean of its earlier ones (at least as many) since its
       identity began, the track goes on as a new identity (which may join in turn).

    What it cannot do that `Relink` does: look at a track's later boxes when it decides
    on a join, or cut a track where the look changed rather than `split_crops` boxes
    later. Settings: `Relink`'s defaults but the longest gap, 45 s instead of 30 (an
    observer that meets a vehicle again 30-45 s later; `Relink` keeps 30 s, as 45 s
    cost its offline joins 0.005 IDF1); the gap, the window and the crops to join chosen
    on the development recordings (README, "Re-linking online").
    """

    max_distance: float = Relink.max_distance
    max_gap_s: float = 45.0
    max_speed_mps: float = Relink.max_speed_mps
    slack_m: float = Relink.slack_m
    split_distance: float | None = Relink.split_distance
    split_crops: int = Relink.split_min_crops
    join_window_s: float = 3.0
    join_min_crops: int = 3
    _of: dict = field(default_factory=dict, repr=False)   # tracker track -> identity
    _seg: dict = field(default_factory=dict, repr=False)  # track -> its looks' sum, count, last
    _ids: dict = field(default_factory=dict, repr=False)  # identity -> _Identity
    _next: int = 1

    def update(self, t: float, track_of: np.ndarray, ids: np.ndarray,
               class_ids: np.ndarray, positions: np.ndarray,
               embeddings: np.ndarray | None) -> np.ndarray:
        """One frame; returns (N,) the identity of every detection the tracker reported
        (``ids`` > 0), −1 elsewhere."""
        t = float(t)
        track_of = np.asarray(track_of, np.int64)
        eta = VEHICLE_CLASS_INDEX[np.asarray(class_ids, np.int64)]
        positions = np.asarray(positions, np.float64).reshape(-1, 2)
        here: set[int] = set()
        for j, k in enumerate(track_of.tolist()):
            if k < 0:
                continue
            if k not in self._of:
                self._of[k] = self._new(t, positions[j])
                self._seg[k] = (0.0, 0, deque(maxlen=max(self.split_crops, 1)))
            e = None
            if embeddings is not None and not np.isnan(embeddings[j, 0]):
                e = np.asarray(embeddings[j], np.float64)
                if self.split_distance is not None:
                    e = self._cut(k, e, t, positions[j])
            ident = self._ids[self._of[k]]
            ident.t1, ident.p1 = t, positions[j]
            ident.votes[eta[j]] += 1
            if e is not None:
                ident.add(e)
            here.add(self._of[k])
        self._join(t, here)
        out = np.full(len(track_of), -1, np.int64)
        for j in np.flatnonzero(np.asarray(ids) > 0):
            out[j] = self._of[int(track_of[j])]
        return out

    def _new(self, t: float, p: np.ndarray) -> int:
        i = self._next
        self._next += 1
        self._ids[i] = _Identity(t, p)
        return i

    def _cut(self, k: int, e: np.ndarray, t: float, p: np.ndarray) -> np.ndarray | None:
        """Add ``e`` to track ``k``'s looks; on a cut, start its new identity with the
        last `split_crops` looks and return None (``e`` is among them), else ``e``."""
        n = max(self.split_crops, 1)
        total, count, last = self._seg[k]
        last.append(e)
        total, count = total + e, count + 1
        self._seg[k] = (total, count, last)
        if count < 2 * n:
            return e
        b = np.sum(last, 0)
        a = total - b
        if np.linalg.norm(a / np.linalg.norm(a) - b / np.linalg.norm(b)) <= self.split_distance:
            return e
        self._of[k] = i = self._new(t, p)
        self._seg[k] = (b, n, last)
        self._ids[i].s, self._ids[i].n = b, n
        return None

    def _join(self, t: float, here: set[int]) -> None:
        gone = {i for i, d in self._ids.items()  # forget what can no longer be joined
                if i not in here and t - d.t1 > self.max_gap_s + self.join_window_s}
        if gone:  # and the tracker's tracks that fed it: none was seen since
            for i in gone:
                del self._ids[i]
            for k in [k for k, i in self._of.items() if i in gone]:
                del self._of[k], self._seg[k]
        pairs = []
        for y in here:
            Y = self._ids[y]
            if not Y.young or t - Y.t0 > self.join_window_s:
                Y.young = False
                continue
            if Y.n < self.join_min_crops:
                continue
            uy, cy = Y.look(), int(np.argmax(Y.votes))
            for a, A in self._ids.items():
                if a in here or A.n == 0:
                    continue
                if not _may_follow(self, Y.t0 - A.t1, int(np.argmax(A.votes)) == cy, A.p1,
                                   Y.p0):
                    continue
                d = float(np.linalg.norm(uy - A.look()))
                if d <= self.max_distance:
                    pairs.append((d, y, a))
        pairs.sort()
        done: set[int] = set()
        for _, y, a in pairs:
            if y in done or a in done:
                continue
            done |= {y, a}
            Y, A = self._ids.pop(y), self._ids[a]
            for k, i in self._of.items():
                if i == y:
                    self._of[k] = a
            A.s, A.n, A.votes = A.s + Y.s, A.n + Y.n, A.votes + Y.votes
            A.t1, A.p1, A.young = Y.t1, Y.p1, False


class _Identity:
    """One identity of `LiveRelink`: its first and last sighting, class votes and the
    sum of its looks."""

    __slots__ = ("n", "p0", "p1", "s", "t0", "t1", "votes", "young")

    def __init__(self, t: float, p: np.ndarray):
        self.t0 = self.t1 = t
        self.p0 = self.p1 = np.asarray(p, np.float64)
        self.votes = np.zeros(5)
        self.s, self.n = 0.0, 0
        self.young = True

    def add(self, e: np.ndarray) -> None:
        self.s, self.n = self.s + e, self.n + 1

    def look(self) -> np.ndarray:
        return self.s / np.linalg.norm(self.s)


TRACKERS: tuple[str, ...] = ("sort", "ego")
"""Tracker names (module docstring)."""


def build_tracker(name: str, spec: CameraSpec | None = None,
                  confirm_score: float = CONFIRM_SCORE):
    """A new tracker by name; ``spec`` is the camera of the images (needed by ``ego``),
    ``confirm_score`` `EgoTracker`'s (``sort`` has no such rule).

    Raises TrackerError listing the valid names."""
    if name == "sort":
        return SortTracker()
    if name == "ego":
        return EgoTracker(spec=spec if spec is not None else CameraSpec(),
                          confirm_score=confirm_score)
    raise TrackerError(f"unknown tracker {name!r}; valid: {', '.join(TRACKERS)}")


def mot_rows(frame: int, det: Detections, track_ids: np.ndarray) -> list[str]:
    """MOTChallenge txt lines (frame, id, left, top, width, height, conf, −1, −1, −1) of
    one frame's tracked detections (frame is 1-based in the file; boxes in pixels)."""
    out = []
    for b, s, tid in zip(det.boxes, det.scores, track_ids, strict=True):
        if tid < 0:
            continue
        out.append(f"{frame},{int(tid)},{b[0]:.2f},{b[1]:.2f},{b[2] - b[0]:.2f},"
                   f"{b[3] - b[1]:.2f},{s:.3f},-1,-1,-1")
    return out
