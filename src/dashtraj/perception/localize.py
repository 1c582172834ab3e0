"""Localization of detections: distance, signed bearing and world position of each box.

Every estimator takes boxes (N, 4) xyxy in image pixels, class ids (index into
`DETECTION_CLASSES`), the camera (`CameraSpec` of the image that was detected) and the
camera's pose in that frame (`CameraPose`: centre, yaw, pitch; the road elevation
under the observer), and returns `Localized`: the ground-plane distance from the
camera to the vehicle's centre (metres), the signed bearing of the box off the camera
axis (degrees, positive to the right, i.e. toward +y when yaw = 0) and the world
position (CARLA world, metres):

    x = cam_x + D cos(cam_yaw + bearing),  y = cam_y + D sin(cam_yaw + bearing)

— the paper's Eq. 9 with the observer's yaw added and the signed bearing, where its
Eq. 8 (arccos) loses the sign (see DESIGN.md).

Estimators (`LOCALIZERS`, chosen by name with `build_localizer`):

- ``paper``: Eq. 3, D = H_real f I_H / (μ_h h_px), with the paper's per-class heights
  (1.6 m car, 3.5 m truck and bus, 1.45 m motorcycle and bicycle), h_px the box
  height, f = W / (2 tan(FOV/2)) (Eq. 4) and μ_h the sensor constant calibrated the
  paper's way: the mean of H_real f I_H / (D_true h_px) over N detections with known
  distances (`calibrate_paper_constant`; the paper used 51 and got 599.46 for its
  camera; `PAPER_MU_H` = 583.96 is ours, from 51, for the default camera).
- ``ground``: the box's bottom edge is where the vehicle touches the road: the ray
  through (box centre column, bottom row) is intersected with the road plane (camera
  height and pitch from the mount; road elevation = the observer's ground z), and the
  offset of its nearest wheel contact from its centre along the ray is added
  (class-typical half wheelbase and half width, combined by the angle between the ray
  and the vehicle's heading, taken from the orientation class: front/back = along the
  ray, side = across it); near the camera the lowest pixel is the lower edge of the
  body instead (class ground clearance above the road, half a length from the centre),
  and the hypothesis placing the centre farther is the one that holds. Where the bottom
  edge is unusable (cut by the image border, at or above the horizon) the box gets
  Eq. 3's estimate and ``valid`` is False.
- ``fused``: both, combined with their error models (Eq. 3's value divided by the
  cosine of the bearing, since a box's height measures depth along the optical axis;
  inverse-variance weights: σ_paper = 20 % of D, the spread of real heights around
  the class height; σ_ground =
  D² / (f h_cam) × 1 px + 0.3 m), falling back to the other estimate where one is
  unusable (bottom edge cut by the image border or above the horizon; top edge cut);
  where nearer detections hide a box's bottom edge (cover 60 % of its columns), the
  distance from the box width replaces both, and where the box is also cut sideways and
  its lowest row is a nearer box's top (a strip of a vehicle above a nearer one), the
  log-uniform median of the occluder's range and the far reading (see
  `FusedLocalizer._occluded_bottoms`); a distance beyond the farthest at which any
  vehicle of the box's class looks as wide as the box (`width_bound`) is cut to it,
  flagged `TOO_WIDE` (its lower part is hidden by something no detector reports: a
  hedge, a wall); a distance any of these rules moved has σ = 30 % of it
  (`HIDDEN_SIGMA_REL`).
  Its output carries each box's truncation/occlusion evidence (`box_evidence`).
- ``tracked``: track-level (`TrackedLocalizer`, sequential: one per camera, fed every
  frame with its time): ``fused`` where the box is clean and consistent with its track,
  else the ``ego`` tracker's ground-plane filter of the track (observer odometry).
- ``smoothed``: ``tracked`` run forward *and backward* in time over one camera's whole
  sequence (`SmoothedLocalizer`; offline: fed every frame like ``tracked``, the
  smoothed positions come from `SmoothedLocalizer.smoothed` once the sequence ended).
  A detection keeps its ``fused`` position only where the box is clean and consistent
  with its track in both directions; else it takes the two filters' inverse-covariance
  fusion (the other direction alone where one has no history: a track *born* truncated
  or occluded gets its later, clean boxes' evidence carried back).
- ``mapped``: ``smoothed``, then the road map's word (`MappedLocalizer`, needs the map):
  a position that lies more than ``trigger_m`` outside every driving, parking and
  shoulder lane moves along its own ray (the bearing is what a camera measures well) to
  the nearest distance that lies on one (`snap_to_lanes`). A box whose bottom edge is
  hidden by something no detector reports (a kerb, a raised sidewalk, a hedge seen from
  1.6 m) or by a part of another vehicle reads too far with every cue at once (the
  bottom edge is too high and the box too short), and such a position usually lands
  beside the road; a vehicle is on one. Then each box cut by the left or right image
  border is re-placed where a class-typical vehicle on a nearby lane centre, heading
  along its lane, would show that box (`fit_cut_boxes`): a cut box's centre column and
  lowest pixel are not the vehicle's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from dashtraj.errors import DashtrajError
from dashtraj.perception.detections import ORIENTATION_OF_CLASS, VEHICLE_CLASS_INDEX
from dashtraj.roads.types import LaneType
from dashtraj.world.camera import CameraSpec

CLASS_HEIGHT_M: tuple[float, ...] = (1.6, 3.5, 3.5, 1.45, 1.45)
"""Eq. 3's real heights per vehicle class (car, truck, bus, motorcycle, bicycle), metres."""

CLASS_WHEELBASE_M: tuple[float, ...] = (2.85, 4.15, 5.72, 1.43, 1.06)
CLASS_LENGTH_M: tuple[float, ...] = (4.76, 7.32, 11.2, 2.07, 1.77)
CLASS_WIDTH_M: tuple[float, ...] = (1.87, 2.38, 2.52, 0.77, 0.56)
CLASS_CLEARANCE_M: tuple[float, ...] = (0.16, 0.28, 0.30, 0.14, 0.30)
CLASS_DIAGONAL_MAX_M: tuple[float, ...] = (7.08, 9.05, 12.37, 2.53, 1.95)
"""Typical wheelbase and width per vehicle class, metres (means of the vehicle catalog):
the lowest pixel of a vehicle is where its nearest wheels touch the road, half a
wheelbase from its centre along its length and half a width across it, or, seen from
nearer than about 11 m (a car), the lower edge of its body (the ground clearance above
the road, half a length from the centre). `CLASS_DIAGONAL_MAX_M`: the longest diagonal
of the class's footprint in the catalog (its largest model; a test keeps them in step), the
widest any vehicle of the class can look from any side (`width_bound`)."""

PAPER_MU_H: float = 583.96
"""μ_h of Eq. 3 for our 1280 x 720 camera (scaled with the image height), calibrated the
paper's way from 51 known distances (the paper got 599.46 for its camera):
``dashtraj simulate --town town01 --seed 1 --duration 60 -o cal`` then
``dashtraj localization calibrate cal -n 51 --seed 0`` (seed 1 is a calibration seed,
never an evaluation one)."""

VEHICLE_LANES = LaneType.Driving | LaneType.Parking | LaneType.Shoulder
"""Lanes a vehicle can stand on (parked cars stand on the shoulder in CARLA's towns)."""

PAPER_SIGMA_REL = 0.20
GROUND_SIGMA_PX = 1.0
GROUND_SIGMA_M = 0.3
HIDDEN_SIGMA_REL = 0.30
"""σ of a distance that `FusedLocalizer._occluded_bottoms` put in place of both cues (from
the box width, or a strip's range between two bounds), as a share of it: the RMS relative
error of those distances on 25 development recordings (896 boxes: 0.22 front, 0.33 back,
0.32 side views), where the cues' own σ, which such a box used to keep, was a median 5-14 %
of it. The smoothed localizers' filters update with it (`EgoTracker.rule_sigma`) and gate
their association with the cues' σ (`Localized.gate_sigma_m`; with the rules' σ, the 6-σ
gate lets such a box join another vehicle's track tens of metres along its ray); the tracker
that reports the ids keeps the cues' σ for both."""


class LocalizationError(DashtrajError):
    """Unknown estimator or impossible calibration input."""


@dataclass(frozen=True, slots=True)
class CameraPose:
    """A camera in one frame: centre (x, y, z), yaw and pitch (degrees), CARLA world,
    and the road elevation ``ground_z`` (metres) under its vehicle."""

    x: float
    y: float
    z: float
    yaw_deg: float
    pitch_deg: float = 0.0
    ground_z: float = 0.0


@dataclass(frozen=True, slots=True, eq=False)
class Localized:
    """Per-box estimates, arrays (N,): distance_m, bearing_deg, x, y (CARLA world, m),
    sigma_m (the estimator's 1-σ distance error model, metres), valid (bool); evidence
    (`box_evidence`) and gate_sigma_m (the σ a tracker gates its association with,
    where it differs from sigma_m; None: sigma_m) where the estimator gives them."""

    distance_m: np.ndarray
    bearing_deg: np.ndarray
    x: np.ndarray
    y: np.ndarray
    sigma_m: np.ndarray
    valid: np.ndarray
    evidence: np.ndarray | None = None
    gate_sigma_m: np.ndarray | None = None


CUT_LEFT, CUT_RIGHT, CUT_TOP, CUT_BOTTOM = 1, 2, 4, 8
HIDDEN_BOTTOM, HIDDEN_SIDE = 16, 32
"""Bits of `box_evidence`: the box touches the image's left / right / top / bottom
border (truncated: the vehicle goes on outside the image); a nearer detection covers
part of its bottom edge; a nearer detection overlaps one of its side edges (then its
centre column and width are not the vehicle's either)."""
TOO_WIDE = 64
"""Bit of ``fused``'s evidence (not `box_evidence`'s: it needs the distance): the box is
wider than any vehicle of its class could look at the distance its cues read
(`width_bound`), so its lower part is hidden by something no detector reports (a hedge,
a wall, a kerb) and the distance was cut to the bound."""


def box_evidence(boxes, spec: CameraSpec, border_px: float = 1.0,
                 tol_px: float = 2.0) -> np.ndarray:
    """Truncation and occlusion evidence of each box of one frame, (N,) int bit flags
    (`CUT_LEFT` … `HIDDEN_SIDE`; 0 = a clean box). Depth order without any estimate: of
    two overlapping boxes, the one whose bottom edge is lower in the image (by more than
    ``tol_px``) is the nearer (both stand on the road). A nearer box j hides part of box
    i's bottom edge when it spans some of i's columns and its top is above i's bottom
    row; it hides a side of i when it overlaps i and contains i's left or right edge
    column."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    ev = np.zeros(len(b), np.int64)
    ev |= np.where(b[:, 0] <= border_px, CUT_LEFT, 0)
    ev |= np.where(b[:, 2] >= spec.width_px - border_px, CUT_RIGHT, 0)
    ev |= np.where(b[:, 1] <= border_px, CUT_TOP, 0)
    ev |= np.where(b[:, 3] >= spec.height_px - border_px, CUT_BOTTOM, 0)
    if len(b) < 2:
        return ev
    nearer = b[None, :, 3] > b[:, None, 3] + tol_px  # [i, j]: j is nearer than i
    np.fill_diagonal(nearer, False)
    cols = (b[None, :, 0] < b[:, None, 2]) & (b[None, :, 2] > b[:, None, 0])
    ev |= np.where((nearer & cols & (b[None, :, 1] <= b[:, None, 3] + tol_px)).any(1),
                   HIDDEN_BOTTOM, 0)
    rows = (b[None, :, 1] < b[:, None, 3]) & (b[None, :, 3] > b[:, None, 1])
    has_l = (b[None, :, 0] <= b[:, None, 0] + tol_px) & (b[None, :, 2] > b[:, None, 0])
    has_r = (b[None, :, 2] >= b[:, None, 2] - tol_px) & (b[None, :, 0] < b[:, None, 2])
    ev |= np.where((nearer & cols & rows & (has_l | has_r)).any(1), HIDDEN_SIDE, 0)
    return ev


def width_bound(boxes, class_ids, spec: CameraSpec, bearing_deg) -> np.ndarray:
    """The farthest ground distance (metres) at which a vehicle of each box's class can
    show a box that wide: no vehicle looks wider than its footprint's diagonal D
    (`CLASS_DIAGONAL_MAX_M`), whose nearest point lies at most D/2 before its centre, so
    the centre's depth is at most f·D/w + D/2 (w the box width in pixels; a box cut by
    the border or an occluder is narrower than the vehicle, and the bound still holds),
    over the cosine of the bearing for the ground distance."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    diag = np.asarray(CLASS_DIAGONAL_MAX_M)[VEHICLE_CLASS_INDEX[np.asarray(class_ids)]]
    w = np.maximum(b[:, 2] - b[:, 0], 1.0)
    return (spec.focal_px * diag / w + diag / 2.0) / np.cos(np.radians(bearing_deg))


def pixel_rays(spec: CameraSpec, pose: CameraPose, u, v):
    """Horizontal bearing (deg, + right) and (forward, up) per unit horizontal length of the
    rays through pixels (u, v); arrays (N,)."""
    f = spec.focal_px
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    right = (u - spec.width_px / 2.0) / f
    up_c = -(v - spec.height_px / 2.0) / f
    p = math.radians(pose.pitch_deg)
    fwd_h = math.cos(p) - up_c * math.sin(p)
    up = math.sin(p) + up_c * math.cos(p)
    horiz = np.hypot(fwd_h, right)
    return np.degrees(np.arctan2(right, fwd_h)), up / horiz


def place(pose: CameraPose, distance_m, bearing_deg):
    """World (x, y) at ground distance D along cam_yaw + signed bearing (not Eq. 8/9)."""
    ang = np.radians(pose.yaw_deg + np.asarray(bearing_deg))  # observer yaw + signed bearing
    d = np.asarray(distance_m)
    return pose.x + d * np.cos(ang), pose.y + d * np.sin(ang)


def localized_at(pose: CameraPose, x, y, sigma_m, valid, evidence) -> Localized:
    """`Localized` of world positions (x, y): the inverse of `place` (ground distance from
    the camera and signed bearing from its yaw, in (-180, 180])."""
    dx, dy = x - pose.x, y - pose.y
    bearing = (np.degrees(np.arctan2(dy, dx)) - pose.yaw_deg + 180.0) % 360.0 - 180.0
    return Localized(np.hypot(dx, dy), bearing, x, y, sigma_m, valid, evidence)


def paper_distance(spec: CameraSpec, boxes, class_ids, mu_h: float) -> np.ndarray:
    """Eq. 3: D = H_real f I_H / (μ_h h_px), metres, per box (h_px = box height)."""
    h_real = np.asarray(CLASS_HEIGHT_M)[VEHICLE_CLASS_INDEX[np.asarray(class_ids)]]
    h_px = np.maximum(np.asarray(boxes, np.float64)[:, 3] - np.asarray(boxes)[:, 1], 1e-6)
    return h_real * spec.focal_px * spec.height_px / (mu_h * h_px)  # Eq. 3


def calibrate_paper_constant(spec: CameraSpec, boxes, class_ids, true_distance_m) -> float:
    """μ_h of Eq. 3 fitted the paper's way: the mean over N detections of
    H_real f I_H / (D_true h_px). Raises LocalizationError for N = 0 or bad distances."""
    d = np.asarray(true_distance_m, np.float64)
    if len(d) == 0 or not np.all(np.isfinite(d)) or np.any(d <= 0):
        raise LocalizationError("calibration needs at least one finite positive distance")
    return float(np.mean(paper_distance(spec, boxes, class_ids, 1.0) / d))


def _half_extent_along_ray(class_ids, rel_deg=None, body: bool = False) -> np.ndarray:
    """Distance from the vehicle centre to its nearest wheel contact (``body``: to the
    nearest lower edge of its body) along the viewing ray, metres."""
    vc = VEHICLE_CLASS_INDEX[np.asarray(class_ids)]
    L = np.asarray(CLASS_LENGTH_M if body else CLASS_WHEELBASE_M)[vc] / 2
    W = np.asarray(CLASS_WIDTH_M)[vc] / 2
    if rel_deg is None:
        side = np.array([ORIENTATION_OF_CLASS[c] == "side" for c in np.asarray(class_ids)],
                        dtype=bool)
        rel = np.where(side, 90.0, 0.0)
    else:
        rel = np.asarray(rel_deg)
    r = np.radians(rel)
    # the box bottom is the nearest wheel contact: B/2 |cos| + W/2 |sin| nearer than the centre
    return L * np.abs(np.cos(r)) + W * np.abs(np.sin(r))


@dataclass
class PaperLocalizer:
    """Eq. 3 distance with the calibrated constant; signed bearing of the box centre."""

    mu_h: float = PAPER_MU_H
    name: str = "paper"

    def localize(self, boxes, class_ids, spec: CameraSpec, pose: CameraPose) -> Localized:
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        mu = self.mu_h * spec.height_px / 720.0
        d = paper_distance(spec, boxes, class_ids, mu)
        bearing, _ = pixel_rays(spec, pose, 0.5 * (boxes[:, 0] + boxes[:, 2]),
                                0.5 * (boxes[:, 1] + boxes[:, 3]))
        x, y = place(pose, d, bearing)
        return Localized(d, bearing, x, y, PAPER_SIGMA_REL * d, np.ones(len(d), bool))


@dataclass
class GroundLocalizer:
    """Bottom edge on the road plane plus the vehicle's half extent along the ray."""

    mu_h: float = PAPER_MU_H
    name: str = "ground"
    border_px: float = 1.0

    def localize(self, boxes, class_ids, spec: CameraSpec, pose: CameraPose,
                 rel_deg=None) -> Localized:
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        uc = 0.5 * (boxes[:, 0] + boxes[:, 2])
        bearing, slope = pixel_rays(spec, pose, uc, boxes[:, 3])
        h = pose.z - pose.ground_z
        ok = slope < -1e-6
        near = np.where(ok, h / np.where(ok, -slope, 1.0), np.inf)
        # the lowest pixel is the wheel contact (on the road) or, near, the body's lower
        # edge (clearance z_b above it): whichever hypothesis puts the centre farther holds
        z_b = np.asarray(CLASS_CLEARANCE_M)[VEHICLE_CLASS_INDEX[np.asarray(class_ids)]]
        d = np.maximum(near + _half_extent_along_ray(class_ids, rel_deg),
                       near * (1.0 - z_b / max(h, 0.1))
                       + _half_extent_along_ray(class_ids, rel_deg, body=True))
        valid = ok & (boxes[:, 3] < spec.height_px - self.border_px) & (near < 500)
        sigma = (d * d) / (spec.focal_px * max(h, 0.1)) * GROUND_SIGMA_PX + GROUND_SIGMA_M
        if not valid.all():  # bottom edge unusable: Eq. 3's estimate instead
            p = PaperLocalizer(self.mu_h).localize(boxes, class_ids, spec, pose)
            d = np.where(valid, d, p.distance_m)
            sigma = np.where(valid, sigma, p.sigma_m)
        x, y = place(pose, d, bearing)
        return Localized(d, bearing, x, y, sigma, valid)


@dataclass
class FusedLocalizer:
    """Inverse-variance fusion of ``paper`` and ``ground`` (fallbacks in the module doc)."""

    mu_h: float = PAPER_MU_H
    name: str = "fused"
    border_px: float = 1.0
    cover_frac: float = 0.6
    strip_px: float | None = 4.0
    width_cap: bool = True

    def localize(self, boxes, class_ids, spec: CameraSpec, pose: CameraPose,
                 rel_deg=None) -> Localized:
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        p = PaperLocalizer(self.mu_h).localize(boxes, class_ids, spec, pose)
        # Eq. 3 measures depth along the optical axis; the ground distance is depth / cos(b)
        p_dist = p.distance_m / np.cos(np.radians(p.bearing_deg))
        g = GroundLocalizer(self.mu_h, border_px=self.border_px).localize(
            boxes, class_ids, spec, pose, rel_deg)
        p_ok = boxes[:, 1] > self.border_px  # the top edge is the vehicle's roof
        wp = np.where(p_ok, 1.0 / (PAPER_SIGMA_REL * p_dist) ** 2, 0.0)
        wg = np.where(g.valid, 1.0 / np.where(g.valid, g.sigma_m, 1.0) ** 2, 0.0)
        both = (wp + wg) > 0
        dg = np.where(g.valid, g.distance_m, 0.0)
        d = np.where(both, (wp * p_dist + wg * dg) / np.where(both, wp + wg, 1.0), p_dist)
        sigma = np.where(both, 1.0 / np.sqrt(np.where(both, wp + wg, 1.0)),
                         PAPER_SIGMA_REL * p_dist)
        cues = d
        d = self._occluded_bottoms(boxes, class_ids, spec, p.bearing_deg, d)
        evidence = box_evidence(boxes, spec, self.border_px)
        if self.width_cap:  # wider than its class allows there: the bottom is hidden
            cap = width_bound(boxes, class_ids, spec, p.bearing_deg)
            wide = d > cap
            d = np.where(wide, cap, d)
            evidence = np.where(wide, evidence | TOO_WIDE, evidence)
        # a distance the hidden-bottom rules moved carries their error, not the cues' σ;
        # a tracker gates with the cues' σ still, and keeps it unless told (`HIDDEN_SIGMA_REL`)
        ruled = np.abs(d - cues) > 1e-9
        x, y = place(pose, d, p.bearing_deg)
        return Localized(d, p.bearing_deg, x, y,
                         np.where(ruled, np.maximum(sigma, HIDDEN_SIGMA_REL * d), sigma),
                         np.ones(len(d), bool), evidence, sigma if ruled.any() else None)


    def _occluded_bottoms(self, boxes, class_ids, spec, bearing_deg, d):
        """Boxes whose bottom edge is hidden by nearer detections of the same frame: the
        visible bottom is too high and both the ground and Eq. 3 estimates are too far.
        A box counts as hidden when nearer boxes (lower bottom edge, top above this box's
        bottom, and nearer by their own estimate: a detector's box on the lower part of
        the same vehicle is estimated far by its height) cover at least `cover_frac` of
        its columns. Unless it is also cut sideways
        (by one of them or the image border: its width says nothing then), use the
        distance from the box width (class width for back views, the vehicle seen
        straight; the geometric mean with the fused value for front and side views, seen
        obliquely), never more than the fused value and at least 1 m beyond the
        occluder. A hidden box cut sideways whose lowest row lies within `strip_px` of
        a covering box's top row is a strip of a vehicle above a nearer one (a car's roof
        over a lower car beside the observer): its range lies between the occluder's + 1 m
        and the fused value, which reads too far, and it gets their geometric mean (the
        median of a log-uniform prior between the two; `strip_px` None: the fused value
        stays)."""
        n = len(boxes)
        if n < 2:
            return d
        b = boxes
        w_px = np.maximum(b[:, 2] - b[:, 0], 1.0)
        below = (b[None, :, 3] > b[:, None, 3]) & (b[None, :, 1] <= b[:, None, 3] + 2.0)
        below &= d[None, :] < d[:, None]  # an occluder is nearer by its own estimate too
        np.fill_diagonal(below, False)
        # columns of box i covered by the union of its occluders j
        cols = np.linspace(0.0, 1.0, 16)
        u = b[:, 0:1] + cols[None, :] * (b[:, 2:3] - b[:, 0:1])  # (n, 16)
        inside = (b[None, :, 0, None] <= u[:, None, :]) & (u[:, None, :] <= b[None, :, 2, None])
        covered = (inside & below[:, :, None]).any(1).mean(1)
        covers = below & inside.any(2)
        hidden = covered >= self.cover_frac
        cut = below & ((np.abs(b[:, None, 0] - b[None, :, 2]) <= 2.0)
                       | (np.abs(b[:, None, 2] - b[None, :, 0]) <= 2.0))
        cut = cut.any(1) | (b[:, 0] <= self.border_px) | (b[:, 2] >= spec.width_px - self.border_px)
        occluder = np.where(covers, d[None, :], 0.0).max(1)
        if self.strip_px is not None:
            # hidden, cut sideways, and its lowest pixel a covering box's upper edge: a
            # strip of the vehicle above a nearer one. Neither its bottom row, its height
            # nor its width pins the range; it lies between the occluder's and what both
            # cues read (too far): the log-uniform median of the two
            strip = hidden & cut & (covers & (np.abs(b[:, None, 3] - b[None, :, 1])
                                              <= self.strip_px)).any(1)
            lo = occluder + 1.0
            d = np.where(strip & (d > lo), np.sqrt(lo * d), d)
        hidden &= ~cut
        if not hidden.any():
            return d
        vc = VEHICLE_CLASS_INDEX[np.asarray(class_ids)]
        back = np.array([ORIENTATION_OF_CLASS[c] == "back" for c in np.asarray(class_ids)])
        side = np.array([ORIENTATION_OF_CLASS[c] == "side" for c in np.asarray(class_ids)])
        extent = np.where(side, np.asarray(CLASS_LENGTH_M)[vc], np.asarray(CLASS_WIDTH_M)[vc])
        d_w = spec.focal_px * extent / w_px / np.cos(np.radians(bearing_deg))
        est = np.minimum(np.where(back, d_w, np.sqrt(d_w * d)), d)
        return np.where(hidden, np.maximum(est, occluder + 1.0), d)


@dataclass
class TrackedLocalizer:
    """Track-level estimation: every detection keeps its ``fused`` position when that
    can be trusted, else takes its track's ground-plane filter (the ``ego`` tracker's
    constant-velocity Kalman filter, driven by the observer's odometry).

    A ``fused`` position is trusted when the box is clean (`box_evidence` 0: neither cut
    by the image border nor partly hidden by a nearer detection) and consistent with its
    track (squared Mahalanobis distance to the track's prediction ≤ ``consistent_chi2``,
    or a detection that starts a track). Otherwise (a truncated or occluded box, or one
    that jumps away from its track) the track's filtered position is used, which carries
    what the vehicle's earlier, clean boxes said through the occlusion. Sequential and
    stateful: one instance per camera, fed every frame in time order with ``t``
    (seconds); ``sigma_m`` is ``fused``'s."""

    mu_h: float = PAPER_MU_H
    name: str = "tracked"
    consistent_chi2: float = 9.0
    sequential: bool = True
    _tracker: object = None
    track_ids: np.ndarray | None = field(default=None, repr=False)
    """After each `localize`, (N,): the confirmed track id of every detection by its
    ``ego`` filter, or −1 (what `EgoTracker.update` returned)."""

    def share_tracker(self, tracker) -> bool:
        """Drive ``tracker`` (a fresh `EgoTracker` that the caller would feed the same
        frames) as this localizer's filter, instead of a twin of it, when its settings are
        those of the filter it would make (`EgoTracker.same_settings`): each frame is then
        tracked once, and the caller reads the ids from `track_ids` instead of calling
        ``tracker.update``. Returns whether it did (False: nothing changes)."""
        from dashtraj.perception.track import EgoTracker

        if (self._tracker is not None or not isinstance(tracker, EgoTracker)
                or tracker._t is not None):
            return False
        # the confirmation score only decides which tracks are reported, never the
        # filter's states, so a tracker of any confirm_score serves as the filter
        twin = EgoTracker(spec=tracker.spec, mu_h=self.mu_h, confirm_score=tracker.confirm_score)
        if not tracker.same_settings(twin):
            return False
        self._tracker = tracker
        return True

    def localize(self, boxes, class_ids, spec: CameraSpec, pose: CameraPose,
                 t: float | None = None, scores=None) -> Localized:
        """``scores``: the detections' scores (the filter's `EgoTracker.confirm_score`
        decides which tracks `track_ids` reports; None: all 1)."""
        from dashtraj.perception.detections import Detections
        from dashtraj.perception.track import EgoTracker

        if t is None:
            raise LocalizationError(f"the {self.name} localizer needs each frame's time t")
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        class_ids = np.asarray(class_ids, np.int64)
        if self._tracker is None:
            self._tracker = EgoTracker(spec=spec, mu_h=self.mu_h)
        n = len(boxes)
        tr = self._tracker
        scores = np.ones(n) if scores is None else np.asarray(scores, np.float64)
        self.track_ids = tr.update(Detections(boxes, scores, class_ids,
                                              np.full(n, -1, np.int64)), t, pose)
        m = tr.measured
        trust = (m.evidence == 0) & (tr.innovation_d2 <= self.consistent_chi2)
        trust |= ~np.isfinite(tr.innovation_d2)
        x = np.where(trust, m.x, tr.positions[:, 0])
        y = np.where(trust, m.y, tr.positions[:, 1])
        return localized_at(pose, x, y, m.sigma_m, np.ones(n, bool), m.evidence)


@dataclass(frozen=True, slots=True, eq=False)
class _Pass:
    """One frame as one direction's filter saw it: every detection's filtered position
    (N, 2), its covariance (N, 2, 2) and squared innovation (N,; inf: a new track)."""

    xy: np.ndarray
    cov: np.ndarray
    d2: np.ndarray


def _pass_of(tracker) -> _Pass:
    return _Pass(tracker.positions.copy(), tracker.position_cov.copy(),
                 tracker.innovation_d2.copy())


SMOOTHING_FILTER = {"rule_sigma": True, "width_cap": True, "clip_iou": True,
                    "robust_range": True}
"""`EgoTracker` settings of the smoothed localizers' own filters (forward, run again
offline, and backward): the online tracker that reports the ids keeps its defaults."""


@dataclass
class SmoothedLocalizer(TrackedLocalizer):
    """Forward-backward (offline) track-level estimation of one camera's sequence.

    `localize` is `TrackedLocalizer`'s (the forward, causal estimate; fed every frame in
    time order with ``t``) and keeps the frame. `smoothed` then runs its own ``ego``
    filters (`SMOOTHING_FILTER`) forward again and backward in time (the frames
    reversed, time negated: the constant-velocity model holds either way; the observer's
    odometry is its pose in each frame) and combines, per detection:

    - the ``fused`` position where the box is clean (`box_evidence` 0) and consistent
      with its track in both directions (squared Mahalanobis distance to each
      direction's prediction ≤ ``consistent_chi2``, or the first box of a track);
    - else the inverse-covariance fusion of the two directions' filtered positions;
      where one direction has no history (the detection starts its track there) the
      other direction's alone, where neither has (a track of one box) the measurement.

    A track born truncated or occluded (a vehicle overtaking the observer enters the
    image cut by its border; a far vehicle first seen behind an undetected occluder) has
    no history forward, and its clean boxes later are its history backward. Frames are
    kept (detections and poses only) until `reset`."""

    name: str = "smoothed"
    offline: bool = True
    pitch_calibrator: object = field(default=None, repr=False)
    """A `dashtraj.perception.selfcal.PitchCalibrator` that corrected the poses fed to
    `localize` (its causal estimate), or None. `smoothed` then localizes every frame once
    more, forward and backward, from the poses with its offline estimate instead (the
    first seconds, before enough vehicles were seen, get the pitch found later)."""
    _frames: list = field(default_factory=list, repr=False)

    def localize(self, boxes, class_ids, spec: CameraSpec, pose: CameraPose,
                 t: float | None = None, scores=None) -> Localized:
        out = TrackedLocalizer.localize(self, boxes, class_ids, spec, pose, t, scores)
        tr = self._tracker
        self._frames.append((np.asarray(boxes, np.float64).reshape(-1, 4),
                             np.asarray(class_ids, np.int64), pose, float(t), tr.measured,
                             _pass_of(tr)))
        return out

    def smoothed(self) -> list[Localized]:
        """The smoothed `Localized` of every frame fed since the last `reset`, in order."""
        return self._smooth()[1]

    def _smooth(self) -> tuple[list, list[Localized]]:
        """(the frames as localized, with their final poses; their smoothed `Localized`)."""
        from dashtraj.perception.detections import Detections
        from dashtraj.perception.track import EgoTracker

        if not self._frames:
            return [], []
        frames = self._recalibrated()
        back = EgoTracker(spec=self._tracker.spec, mu_h=self.mu_h,  # the forward one's camera
                          **SMOOTHING_FILTER)
        backward: list[_Pass] = []
        for boxes, class_ids, pose, t, _, _ in reversed(frames):
            n = len(boxes)
            back.update(Detections(boxes, np.ones(n), class_ids, np.full(n, -1, np.int64)),
                        -t, pose)
            backward.append(_pass_of(back))
        backward.reverse()
        return frames, [self._combine(pose, m, f, b)
                        for (_, _, pose, _, m, f), b in zip(frames, backward, strict=True)]

    def _recalibrated(self) -> list:
        """The kept frames, localized forward again by the smoothing filter
        (`SMOOTHING_FILTER`: it updates with the hidden-bottom rules' σ and bounds a box's
        range by its width, and a box cut or hidden beyond its track's gate updates it with
        its bearing alone; the online one, which reports the ids, does none of these), from
        the poses with the pitch calibrator's offline estimate where there is one."""
        from dashtraj.perception.detections import Detections
        from dashtraj.perception.track import EgoTracker

        cal = self.pitch_calibrator
        delta = np.zeros(len(self._frames))
        if cal is not None and len(cal.applied) == len(self._frames):
            delta = cal.offsets([fr[3] for fr in self._frames]) - np.asarray(cal.applied)
        fwd = EgoTracker(spec=self._tracker.spec, mu_h=self.mu_h, **SMOOTHING_FILTER)
        out = []
        for (boxes, class_ids, pose, t, _, _), d in zip(self._frames, delta, strict=True):
            pose = replace(pose, pitch_deg=min(max(pose.pitch_deg + float(d), -89.0), 89.0))
            n = len(boxes)
            fwd.update(Detections(boxes, np.ones(n), class_ids, np.full(n, -1, np.int64)),
                       t, pose)
            out.append((boxes, class_ids, pose, t, fwd.measured, _pass_of(fwd)))
        return out

    def reset(self) -> None:
        """Forget the frames, the forward filter and the pitch calibrator (a new camera's
        sequence)."""
        self._frames = []
        self._tracker = None
        self.pitch_calibrator = None

    def _combine(self, pose: CameraPose, m: Localized, f: _Pass, b: _Pass) -> Localized:
        n = len(m.x)
        z = np.column_stack([m.x, m.y])
        f_new, b_new = ~np.isfinite(f.d2), ~np.isfinite(b.d2)
        trust = ((m.evidence == 0) & ((f.d2 <= self.consistent_chi2) | f_new)
                 & ((b.d2 <= self.consistent_chi2) | b_new))
        xy = z.copy()
        both = ~trust & ~f_new & ~b_new
        if both.any():
            ia, ib = np.linalg.inv(f.cov[both]), np.linalg.inv(b.cov[both])
            p = np.linalg.inv(ia + ib)
            xy[both] = np.einsum("nij,nj->ni", p, np.einsum("nij,nj->ni", ia, f.xy[both])
                                 + np.einsum("nij,nj->ni", ib, b.xy[both]))
        only_b = ~trust & f_new & ~b_new
        only_f = ~trust & b_new & ~f_new
        xy[only_b] = b.xy[only_b]
        xy[only_f] = f.xy[only_f]
        return localized_at(pose, xy[:, 0], xy[:, 1], m.sigma_m, np.ones(n, bool), m.evidence)


def snap_to_lanes(road_map, pose: CameraPose, loc: Localized, trigger_m: float = 1.0,
                  margin_m: float = 0.25, near: float = 0.4, far: float = 1.6,
                  step_m: float = 0.25) -> Localized:
    """Move each position lying more than ``trigger_m`` outside every vehicle lane
    (`VEHICLE_LANES`: driving, parking, shoulder) along its ray, bearing kept, to the
    nearest distance within [``near`` D, ``far`` D + 2 m] (sampled every ``step_m``) whose
    point lies within ``margin_m`` of such a lane; none there: unchanged. ``sigma_m``,
    ``valid`` and ``evidence`` are kept."""
    n = len(loc.x)
    if n == 0:
        return loc
    lanes = road_map.project(np.column_stack([loc.x, loc.y]), VEHICLE_LANES)
    off = np.flatnonzero(np.abs(lanes.lateral_m) - 0.5 * lanes.lane_width > trigger_m)
    if len(off) == 0:
        return loc
    d = np.asarray(loc.distance_m, np.float64)[off]
    r0, r1 = np.maximum(1.0, near * d), far * d + 2.0
    r = r0[:, None] + step_m * np.arange(int(np.ceil((r1 - r0).max() / step_m)) + 1)[None, :]
    x, y = place(pose, r, np.asarray(loc.bearing_deg, np.float64)[off][:, None])
    q = road_map.project(np.column_stack([x.ravel(), y.ravel()]), VEHICLE_LANES)
    on = ((np.abs(q.lateral_m) - 0.5 * q.lane_width).reshape(r.shape) <= margin_m)
    cost = np.where(on & (r <= r1[:, None]), np.abs(r - d[:, None]), np.inf)
    best = cost.argmin(axis=1)
    found = np.isfinite(cost[np.arange(len(off)), best])
    dist = np.array(loc.distance_m, np.float64)
    dist[off[found]] = r[found, best[found]]
    x, y = place(pose, dist, loc.bearing_deg)
    return Localized(dist, loc.bearing_deg, x, y, loc.sigma_m, loc.valid, loc.evidence)


ROOF_FRACTION: tuple[float, ...] = (0.55, 0.95, 0.95, 0.6, 0.6)
"""Share of a vehicle's length and its width the roof spans (car cabin; truck and bus
boxes; a rider), per class (car, truck, bus, motorcycle, bicycle)."""


def _camera_frame(pose: CameraPose, p: np.ndarray) -> np.ndarray:
    """(..., 3) CARLA world points → (..., 3) (depth along the optical axis, right, up)."""
    yaw, pitch = math.radians(pose.yaw_deg), math.radians(pose.pitch_deg)
    dx, dy, dz = p[..., 0] - pose.x, p[..., 1] - pose.y, p[..., 2] - pose.z
    fwd = dx * math.cos(yaw) + dy * math.sin(yaw)
    right = -dx * math.sin(yaw) + dy * math.cos(yaw)
    return np.stack([fwd * math.cos(pitch) + dz * math.sin(pitch), right,
                     -fwd * math.sin(pitch) + dz * math.cos(pitch)], axis=-1)


def _visible_extent(spec: CameraSpec, a: np.ndarray, b: np.ndarray, near_m: float = 0.3):
    """Segments a → b ((N, S, 3), camera frame) clipped to the part in front of
    ``near_m`` and between the image's left and right borders; returns the (N,) min and
    max column and max and min row over what is left (±inf where nothing is)."""
    f, w, h = spec.focal_px, spec.width_px, spec.height_px
    t0, t1 = np.zeros(a.shape[:-1]), np.ones(a.shape[:-1])
    ok = np.ones(a.shape[:-1], bool)
    for n, c in (((1.0, 0.0, 0.0), -near_m), ((w / 2, f, 0.0), 0.0), ((w / 2, -f, 0.0), 0.0)):
        ga, gb = a @ np.asarray(n) + c, b @ np.asarray(n) + c  # inside where >= 0
        ok &= (ga >= 0) | (gb >= 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ga / (ga - gb)
        t0 = np.where((ga < 0) & (gb >= 0), np.maximum(t0, t), t0)
        t1 = np.where((ga >= 0) & (gb < 0), np.minimum(t1, t), t1)
    ok &= t1 >= t0
    ends = np.concatenate([a + t0[..., None] * (b - a), a + t1[..., None] * (b - a)], axis=1)
    ok = np.concatenate([ok, ok], axis=1)
    z = np.where(ok, ends[..., 0], 1.0)
    u = w / 2 + f * ends[..., 1] / z
    v = h / 2 - f * ends[..., 2] / z
    return (np.where(ok, u, np.inf).min(1), np.where(ok, u, -np.inf).max(1),
            np.where(ok, v, -np.inf).max(1), np.where(ok, v, np.inf).min(1))


def _model_extent(spec: CameraSpec, pose: CameraPose, cx, cy, cz, yaw_deg, vc: int):
    """Visible (min column, max column, bottom row, top row) of a class-typical vehicle
    (body box from its ground clearance, roof, wheel contacts) standing at (cx, cy) on
    the road at elevation cz, heading ``yaw_deg``, arrays (N,)."""
    length, width, height = CLASS_LENGTH_M[vc], CLASS_WIDTH_M[vc], CLASS_HEIGHT_M[vc]
    sx, sy = np.array([1.0, 1.0, -1.0, -1.0]), np.array([1.0, -1.0, -1.0, 1.0])
    c = np.cos(np.radians(yaw_deg))[:, None]
    s = np.sin(np.radians(yaw_deg))[:, None]
    cx, cy, cz = (np.asarray(v, np.float64)[:, None] for v in (cx, cy, cz))

    def ring(lx, ly, z):  # four corners (N, 4, 3), world
        return np.stack([cx + c * lx - s * ly, cy + s * lx + c * ly,
                         np.broadcast_to(cz + z, (len(cx), 4))], axis=-1)

    body = ring(sx * length / 2, sy * width / 2, CLASS_CLEARANCE_M[vc])
    roof = ring(sx * ROOF_FRACTION[vc] * length / 2, sy * 0.9 * width / 2, height)
    wheels = ring(sx * CLASS_WHEELBASE_M[vc] / 2, sy * max(width / 2 - 0.15, 0.05), 0.0)
    a = np.concatenate([body, roof, body, wheels], axis=1)
    b = np.concatenate([np.roll(body, -1, 1), np.roll(roof, -1, 1), roof, wheels], axis=1)
    return _visible_extent(spec, _camera_frame(pose, a), _camera_frame(pose, b))


def fit_cut_boxes(road_map, spec: CameraSpec, pose: CameraPose, boxes, class_ids,
                  loc: Localized, radius_m: float = 8.0, step_m: float = 0.5,
                  prior_m: float = 2.0, prior_rel: float = 0.05) -> Localized:
    """Re-place each box cut by the left or the right image border (not both) where a
    class-typical vehicle standing on a lane centre, heading along the lane, would show
    the same box: its uncut edge column, bottom row (the lowest pixel *inside* the image)
    and top row (weighted less: heights vary), among the lane-centre points within
    ``radius_m`` of its current estimate, which also weighs in (σ = ``prior_m`` +
    ``prior_rel`` × distance). A cut box's centre column is not the vehicle's and its
    bottom row is wherever the vehicle's near side leaves the image, so the
    per-detection cues misread it; the lane says how the vehicle stands. Where a nearer
    box hides the bottom edge (`HIDDEN_BOTTOM`), or the box is too wide for its range
    (`TOO_WIDE`: something else hides it), the box's lowest row is not the vehicle's:
    the model's bottom row only has to lie at or below it. Other
    boxes, and cut boxes no candidate explains, are unchanged."""
    ev = np.asarray(loc.evidence)
    cut = (ev & (CUT_LEFT | CUT_RIGHT)) != 0
    cut &= (ev & (CUT_LEFT | CUT_RIGHT)) != (CUT_LEFT | CUT_RIGHT)
    if not cut.any():
        return loc
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    x, y = np.array(loc.x, np.float64), np.array(loc.y, np.float64)
    offsets = np.arange(-radius_m, radius_m + 1e-9, step_m)
    gx, gy = np.meshgrid(offsets, offsets)
    for i in np.flatnonzero(cut):
        lanes = road_map.project(np.column_stack([x[i] + gx.ravel(), y[i] + gy.ravel()]),
                                 VEHICLE_LANES)
        pts = np.column_stack([lanes.x, lanes.y, lanes.yaw, lanes.z])
        _, first = np.unique(np.round(pts[:, :3] * 4.0), axis=0, return_index=True)
        cand = pts[np.sort(first)]  # one per 0.25 m (and degree) of lane centre
        vc = int(VEHICLE_CLASS_INDEX[int(class_ids[i])])
        umin, umax, vbot, vtop = _model_extent(spec, pose, cand[:, 0], cand[:, 1], cand[:, 3],
                                               cand[:, 2], vc)
        b = boxes[i]
        w, h = b[2] - b[0], b[3] - b[1]
        inner, seen = (umax, b[2]) if ev[i] & CUT_LEFT else (umin, b[0])
        prior = prior_m + prior_rel * math.hypot(x[i] - pose.x, y[i] - pose.y)
        dv = vbot - b[3]
        if ev[i] & (HIDDEN_BOTTOM | TOO_WIDE):  # its lowest pixel is at or below the box's
            dv = np.minimum(dv, 0.0)
        with np.errstate(invalid="ignore"):
            cost = (((inner - seen) / (2.0 + 0.05 * w)) ** 2
                    + (dv / (2.0 + 0.03 * h)) ** 2
                    + ((vtop - b[1]) / (4.0 + 0.15 * h)) ** 2
                    + (np.hypot(cand[:, 0] - x[i], cand[:, 1] - y[i]) / prior) ** 2)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        k = int(np.argmin(cost))
        if np.isfinite(cost[k]):
            x[i], y[i] = cand[k, 0], cand[k, 1]
    return localized_at(pose, x, y, loc.sigma_m, loc.valid, loc.evidence)


@dataclass
class MappedLocalizer(SmoothedLocalizer):
    """``smoothed``, then the road map's word: each smoothed position that lies off every
    vehicle lane of ``road_map`` moved along its ray onto the nearest one
    (`snap_to_lanes`), and each box cut by the left or right image border re-placed where
    a vehicle on a lane would show that box (`fit_cut_boxes`). Offline like
    ``smoothed``; its forward estimates (`localize`) are ``tracked``'s."""

    name: str = "mapped"
    road_map: object = field(default=None, repr=False)
    trigger_m: float = 1.0
    fit_cut: bool = True

    def smoothed(self) -> list[Localized]:
        if self.road_map is None:
            raise LocalizationError("the mapped localizer needs the road map")
        frames, out = self._smooth()
        spec = self._tracker.spec if self._tracker is not None else None
        res = []
        for (boxes, class_ids, pose, *_), o in zip(frames, out, strict=True):
            o = snap_to_lanes(self.road_map, pose, o, self.trigger_m)
            if self.fit_cut and spec is not None:
                o = fit_cut_boxes(self.road_map, spec, pose, boxes, class_ids, o)
            res.append(o)
        return res


LOCALIZERS: dict[str, type] = {"paper": PaperLocalizer, "ground": GroundLocalizer,
                               "fused": FusedLocalizer, "tracked": TrackedLocalizer,
                               "smoothed": SmoothedLocalizer, "mapped": MappedLocalizer}
"""Estimators by name (see the module docstring)."""

NEEDS_MAP = frozenset({"mapped"})
"""Estimators that take the recording's road map (``build_localizer(..., road_map=)``)."""


def build_localizer(name: str, mu_h: float | None = None, road_map=None):
    """An estimator by name; ``mu_h`` overrides Eq. 3's constant (paper, fused); the
    ``mapped`` estimator takes ``road_map`` (a ``RoadMap``; None: it refuses to smooth).

    Raises LocalizationError listing the valid names."""
    if name not in LOCALIZERS:
        raise LocalizationError(f"unknown localizer {name!r}; valid: {', '.join(LOCALIZERS)}")
    cls = LOCALIZERS[name]
    kw = {} if mu_h is None else {"mu_h": mu_h}
    if name in NEEDS_MAP:
        kw["road_map"] = road_map
    return cls(**kw)
