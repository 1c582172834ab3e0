"""Driving experiments as in the paper (§II.G), end to end, and their scores.

One experiment: simulate a town with observers, one target and agents until the
target arrives → oracle sightings of the target within 15 m with the paper's
localization noise → reconstruct its route with each method → score against the
true route with SSPD and Hausdorff distance (metres), both over the whole trip
(the paper's figure) and over the stretch the sightings cover (first to last
sighting; what the sightings can speak to). The paper's set is ten experiments,
five in Town01 and five in Town10: `PAPER_SET`.

Where the target's sightings come from (`SIGHTINGS`; the reconstruction and the
scoring after them are the same code for every source):

- ``oracle``: the recording's truth within 15 m, one per track every 0.5 s, with the
  paper's localization noise (`dashtraj.world.oracle`). The target's identity is
  given, so the ReID precision and recall are 1.0 by construction.
- ``detections``: the camera pipeline (`dashtraj.perception.pipeline.perceive`:
  render, oracle detector, tracker, localizer, map-matching) writes every observer's
  detections into ``sightings.db``; the target's tracks are picked by their TRUE
  identity (each track's renderer vehicle id in the DB), so this measures tracking
  and localization without appearance ReID: the first row of the paper's error
  budget (Table IV). Precision and recall of the picked tracks are again 1.0 by
  construction (a track is picked exactly when its truth is the target); a track
  that switched identity still brings its other vehicle's detections along.

- ``vision``: from pixels, the paper's whole pipeline: `perceive` every observer
  (`detector`: the shipped ONNX detector by default, or ``oracle``: the renderer's
  exact boxes) into ``sightings.db``, embed every crop with the ReID model
  (`reid_model`, default the shipped one), then re-identify the target
  (`dashtraj.reidentify.vision.target_from_db`): the query is the target's first crop
  within 15 m (expanded with the crops of its own track, as the threshold's recipe
  says), each observer track is the target when the median cosine distance of its
  crops (adequate size, not cut by the frame) to the query is at most the threshold
  calibrated on TRAINING recordings with the same recipe (``M.threshold.json`` beside
  the model; ``dashtraj reid-threshold``), then the spatio-temporal gate (`gate`).
  Precision and recall are measured against each track's truth. The detector model
  runs with class-agnostic NMS (`PerceiveConfig`'s default,
  `dashtraj.perception.detections.AGNOSTIC_NMS_IOU`).

How the target's tracks are picked among the candidates (`REID_MODES`):

- ``identity``: by truth (above): the reference.
- ``look-alike``: every track of the target and of its twins (`twins`) is a
  candidate: an appearance model that tells every vehicle apart except exact
  look-alikes (same model and colour). With `gate` the spatio-temporal gate
  (`dashtraj.trajectory.gating`) keeps the heaviest consistent set of candidates
  (weight: sightings per track) containing the track of the target's first
  sighting (the query). This measures what the gate does to precision when
  appearance cannot help.
- ``appearance``: (``vision`` only, its default) the embedding decision and the gate.

Per method the summary holds the issue's keys ``sspd_whole_m``, ``sspd_seen_m``,
``hausdorff_seen_m`` (and ``hausdorff_whole_m``) beside the older ``sspd_m``,
``hausdorff_m``, ``seen_sspd_m``, ``seen_hausdorff_m`` (same numbers); per experiment
``reid_precision`` and ``reid_recall`` (`dashtraj.reidentify.scoring`).
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

from dashtraj.errors import DashtrajError
from dashtraj.perception.detect import DEFAULT_MIN_SCORE
from dashtraj.perception.detections import AGNOSTIC_NMS_IOU, CONFIRM_SCORE

PAPER_SSPD_M = 5.13
"""The paper's mean SSPD over its ten driving experiments, metres."""

METHODS = ("shortest-path", "hmm")

SIGHTINGS = ("oracle", "detections", "vision")
"""Sources of the target's sightings (module docstring)."""

REID_MODES = ("identity", "look-alike", "appearance")
"""How the target's tracks are picked (`target_sightings`)."""

SAMPLE_S = 0.5
"""One sighting per track every this many seconds (both sources), seconds."""

@dataclass(frozen=True, slots=True)
class ExperimentConfig:
    """One driving experiment; round-trips through JSON (`to_dict` / `from_dict`).

    Attributes:
        town: built-in town name or .xodr path.
        seed: seed of the simulation and of the sighting noise.
        observers, agents: vehicle counts (plus one target).
        duration_s: the longest drive, seconds (the run ends when the target arrives).
        noise: "paper" or "none", the oracle's localization noise.
        max_distance_m: sightings only this close to a camera (the paper's 15 m).
        methods: reconstruction methods to run and score.
        sightings: where the target's sightings come from, one of `SIGHTINGS`.
        twins: agents of the target's exact model and colour in the traffic.
        image_size: (W, H) pixels of the rendered frames for ``detections`` (None:
            the recording's camera).
        reid: how the target's tracks are picked, one of `REID_MODES` (see
            `target_sightings`).
        gate: with ``look-alike`` or ``appearance``, the spatio-temporal gate on the
            lane graph.
        detector: ``vision``: "shipped" or "gpu" (the ONNX detectors in the package), "oracle"
            or a path to an .onnx model.
        reid_model: ``vision``: the ReID .onnx model (None: the shipped one; its
            calibrated threshold must lie beside it).
        reid_threshold: ``vision``: a threshold JSON (``dashtraj reid-threshold``) of that
            model instead of the one beside it.
        look: ``vision``: the render look preset (None: the renderer's default).
        every_s: ``detections``/``vision``: the frame period, seconds.
        workers: ``detections``/``vision``: perception processes (observers in
            parallel; the database is the same for any count).
        agnostic_nms_iou: ``vision`` with a detector model: its class-agnostic NMS IoU
            (None: the model's class-aware NMS only); `PerceiveConfig.agnostic_nms_iou`.
        min_score: ``vision`` with a detector model: the smallest kept box score.
        classifier: ``vision`` with a detector model: its second stage, a box classifier
            ONNX path (`PerceiveConfig.classifier`), or None.
        confirm_score: ``detections``/``vision``: the ``ego`` tracker reports a track once
            one of its boxes scored at least this much (`PerceiveConfig.confirm_score`).
        localizer: ``detections``/``vision``: perceive's localizer
            (`dashtraj.perception.localize.LOCALIZERS`).
        drive: a drive folder (`dashtraj.datasets.drive`) to run instead of simulating
            (``vision`` only): its images are perceived, its ``truth.csv`` names the
            target (role ``target``) and scores the re-identification, its
            ``target_route.csv`` is the true route (``carla-record`` writes all three;
            ``render`` too). observers, agents, duration_s, twins, image_size and look
            do not apply; ``experiments --drives`` sets town to the drive's map and
            seed to 0.
        pose_noise: ``detections``/``vision``: the observers perceive from poses with
            GNSS/INS errors (`PerceiveConfig.pose_noise`; (xy_m, yaw_deg, pitch_deg,
            tau_s)), drawn with the experiment's seed; None: the exact poses.
        calibrate_pitch: ``detections``/``vision``: perception self-calibrates each
            observer's camera pitch (`PerceiveConfig.calibrate_pitch`).
        live_relink: ``detections``/``vision``: perception re-links the tracker's ids by
            appearance as the frames come (`PerceiveConfig.live_relink`, with
            ``reid_model``).
        gallery_m: ``vision``: the gallery and the target's sightings are the crops and
            detections estimated this close, metres, at least ``max_distance_m`` (None:
            ``max_distance_m``, the paper's 15 m); the query stays the target's first crop
            within ``max_distance_m``, and perception keeps crops to this range
            (`dashtraj.reidentify.vision.target_from_db`'s ``gallery_m``).
        route_m: ``vision``: the tracks' detections out to this range, metres (at least
            the gallery's), count where the gallery's range leaves them out: the accepted
            tracks' join the target's sightings that the route is rebuilt from, and the
            box relations see a camera's tracks that far (None: neither;
            `target_from_db`'s ``route_m``). The CLI's default is 20 m
            (`dashtraj.cli._vision_args.VISION_ROUTE_M`).
        watch: ``vision``: negative evidence in the gate (`target_from_db`'s ``watch``);
            None: the library's default (`dashtraj.reidentify.vision.WATCH`).
        lookalike: ``vision``: after the gate, once a dropped candidate has shown a
            look-alike, only tracks linked to the query's by short unseen stretches
            (`target_from_db`'s ``lookalike``); None: the library's default
            (`dashtraj.reidentify.vision.LOOKALIKE`).
    """

    town: str = "town10"
    seed: int = 7
    observers: int = 4
    agents: int = 20
    duration_s: float = 180.0
    noise: str = "paper"
    max_distance_m: float = 15.0
    methods: tuple[str, ...] = METHODS
    sightings: str = "oracle"
    twins: int = 0
    image_size: tuple[int, int] | None = None
    reid: str = "identity"
    gate: bool = True
    detector: str = "shipped"
    reid_model: str | None = None
    reid_threshold: str | None = None
    look: str | None = None
    every_s: float = 0.1
    workers: int = 2
    agnostic_nms_iou: float | None = AGNOSTIC_NMS_IOU
    min_score: float = DEFAULT_MIN_SCORE
    classifier: str | None = None
    confirm_score: float = CONFIRM_SCORE
    localizer: str = "smoothed"
    drive: str | None = None
    pose_noise: tuple[float, float, float, float] | None = None
    calibrate_pitch: bool = False
    live_relink: bool = False
    gallery_m: float | None = None
    route_m: float | None = None
    watch: bool | None = None
    lookalike: bool | None = None

    def __post_init__(self) -> None:
        if self.watch is not None and self.sightings != "vision":
            raise ExperimentError("--watch reads where the observers' cameras looked: it "
                                  "needs --sightings vision")
        if self.lookalike is not None and self.sightings != "vision":
            raise ExperimentError("--lookalike acts on appearance ReID's candidates: it "
                                  "needs --sightings vision")
        if self.gallery_m is not None:
            if self.sightings != "vision":
                raise ExperimentError("--gallery-range widens appearance ReID's gallery: it "
                                      "needs --sightings vision")
            if not (math.isfinite(self.gallery_m) and self.gallery_m >= self.max_distance_m):
                raise ExperimentError(f"--gallery-range {self.gallery_m!r}: must be a number "
                                      f"of metres, at least the query's range "
                                      f"({self.max_distance_m:g} m)")
        if self.route_m is not None:
            if self.sightings != "vision":
                raise ExperimentError("--route-range adds the accepted tracks' farther "
                                      "detections: it needs --sightings vision")
            if not (math.isfinite(self.route_m) and self.route_m >= reid_range_of(self)):
                raise ExperimentError(f"--route-range {self.route_m!r}: must be a number of "
                                      f"metres, at least the gallery's range "
                                      f"({reid_range_of(self):g} m)")
        if self.pose_noise is not None and self.sightings == "oracle":
            raise ExperimentError("--pose-noise perturbs the observers' poses in perception: "
                                  "it needs --sightings detections or vision")
        if self.calibrate_pitch and self.sightings == "oracle":
            raise ExperimentError("--calibrate-pitch corrects the observers' poses in "
                                  "perception: it needs --sightings detections or vision")
        if self.live_relink and self.sightings == "oracle":
            raise ExperimentError("--live-relink re-links the tracks of perception: it needs "
                                  "--sightings detections or vision")
        if self.drive is not None and self.sightings != "vision":
            raise ExperimentError(f"a drive is perceived from its images: sightings "
                                  f"{self.sightings!r} needs a simulated recording")
        if self.reid not in REID_MODES:
            raise ExperimentError(f"unknown reid mode {self.reid!r}; valid: "
                                  f"{', '.join(REID_MODES)}")
        if self.sightings not in SIGHTINGS:
            raise ExperimentError(f"unknown sightings source {self.sightings!r}; valid: "
                                  f"{', '.join(SIGHTINGS)}")
        from dashtraj.perception.localize import LOCALIZERS

        if self.localizer not in LOCALIZERS:
            raise ExperimentError(f"unknown localizer {self.localizer!r}; valid: "
                                  f"{', '.join(LOCALIZERS)}")
        if ((self.reid == "appearance" and self.sightings != "vision")
                or (self.sightings == "vision" and self.reid == "look-alike")):
            raise ExperimentError(f"reid mode {self.reid!r} does not go with sightings "
                                  f"{self.sightings!r} (appearance is vision's; vision takes "
                                  "appearance or identity)")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["methods"] = list(self.methods)
        d["image_size"] = None if self.image_size is None else list(self.image_size)
        d["pose_noise"] = None if self.pose_noise is None else list(self.pose_noise)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> ExperimentConfig:
        size = d.get("image_size")
        d = {"confirm_score": 0.0, **d}  # written before the rule: every track reported
        noise = d.get("pose_noise")
        return cls(**{**d, "methods": tuple(d.get("methods", METHODS)),
                      "image_size": None if size is None else tuple(size),
                      "pose_noise": None if noise is None else tuple(noise)})


class ExperimentError(DashtrajError, ValueError):
    """A bad experiment setting (the message names it)."""


@dataclass(slots=True)
class ExperimentResult:
    config: ExperimentConfig
    summary: dict
    truth: object = field(repr=False)
    seen: object = field(repr=False)
    sightings: list = field(repr=False)
    estimates: dict = field(repr=False)
    road_map: object = field(repr=False)
    true_match: dict = field(default_factory=dict, repr=False)
    """(observer_id, track_id) of each used sighting's track → True when its truth is
    the target (a false match: another vehicle, e.g. a twin, accepted as the target)."""
    timing: dict = field(default_factory=dict)
    """Stage name → {"wall_s", "cpu_s"} (`Stages`; not written to the run's files,
    which stay byte-identical for one seed)."""


class Stages:
    """Wall and CPU seconds per pipeline stage, and a progress line as each starts.

    CPU seconds are this process's (all threads) plus its finished children's (the
    perception workers): on a shared machine they measure the work, where the wall
    clock measures the load.

    Example:
        >>> st = Stages(None)
        >>> st.start("simulate"); st.stop()["simulate"]["cpu_s"] >= 0
        True
    """

    def __init__(self, say: Callable[[str], None] | None = None):
        self.say = say
        self.timing: dict[str, dict[str, float]] = {}
        self._name: str | None = None
        self._t0 = self._c0 = 0.0

    @staticmethod
    def cpu_s() -> float:
        import resource
        import time

        ch = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.process_time() + ch.ru_utime + ch.ru_stime

    def start(self, name: str, line: str | None = None) -> None:
        """Close the running stage, start `name`, and say `line` (default: the name)."""
        import time

        self.stop()
        self._name, self._t0, self._c0 = name, time.perf_counter(), self.cpu_s()
        if self.say is not None:
            self.say(line or name)

    def stop(self) -> dict[str, dict[str, float]]:
        import time

        if self._name is not None:
            t = self.timing.setdefault(self._name, {"wall_s": 0.0, "cpu_s": 0.0})
            t["wall_s"] += time.perf_counter() - self._t0
            t["cpu_s"] += self.cpu_s() - self._c0
            self._name = None
        return self.timing

    def note(self, line: str) -> None:
        if self.say is not None:
            self.say(line)


def run_experiment(config: ExperimentConfig, out: str | Path,
                   progress: Callable[[float], None] | None = None,
                   say: Callable[[str], None] | None = None) -> ExperimentResult:
    """Run one experiment, writing its files into `out`.

    Files: ``recording/`` (the simulation), ``sightings.csv``, ``truth.csv``,
    ``estimate_<method>.csv``, ``summary.json`` (with the config, to repeat the run);
    with ``sightings="detections"`` or ``"vision"`` also ``sightings.db`` (every
    observer's detections and crops). `progress` gets the simulated time; `say` a line
    as each later stage starts.
    """
    from dashtraj.roads import RoadMap
    from dashtraj.world.recording import Recording, RunConfig, simulate

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stages = Stages(say)
    if config.drive is not None:
        return _run_drive_experiment(config, out, stages)
    run_config = RunConfig(map=config.town, seed=config.seed, duration_s=config.duration_s,
                           n_observers=config.observers, n_agents=config.agents,
                           n_twins=config.twins, until_target_arrives=True)
    stages.start("simulate", f"simulate: {config.town} seed {config.seed}, {config.observers} "
                             f"observers, {config.agents} agents, up to {config.duration_s:g} s")
    run = simulate(run_config, out / "recording", progress=progress)
    rec = Recording.open(out / "recording")
    road_map = RoadMap.from_file(rec.map_path)
    stages.note(f"simulate: done, {run.simulated_to_t:.1f} s simulated, {run.vehicles} "
                "vehicles")
    sightings, reid = target_sightings(config, rec, out, road_map, stages)
    return _finish(config, out, stages, road_map, rec.target_route, sightings, reid,
                   {"simulated_s": run.simulated_to_t, "target_arrived_t": run.target_arrived_t,
                    "vehicles": run.vehicles})


def _run_drive_experiment(config: ExperimentConfig, out: Path, stages: Stages
                          ) -> ExperimentResult:
    """`run_experiment` on a drive (`ExperimentConfig.drive`): perceive its images, find
    its target (role ``target`` in ``truth.csv``) by appearance, score against its
    ``target_route.csv``."""
    from dashtraj.datasets.drive import Drive
    from dashtraj.roads import RoadMap
    from dashtraj.trajectory.io import read_trajectory

    rec = Drive.open(config.drive)
    if rec.truth is None:
        raise ExperimentError(f"{rec.path} has no truth.csv: an experiment scores the "
                              "re-identification against it")
    targets = [v for v in rec.truth.vehicle_ids if rec.truth.role(v) == "target"]
    if len(targets) != 1:
        raise ExperimentError(f"{rec.truth.path}: {len(targets)} vehicles have role "
                              "'target'; an experiment needs exactly one")
    route = rec.path / "target_route.csv"
    if not route.is_file():
        raise ExperimentError(f"{route} is missing: an experiment scores the route "
                              "against the target's true one")
    truth = read_trajectory(route)
    stages.start("drive", f"drive: {rec.path}, {len(rec.observer_ids)} observers, target "
                          f"{targets[0]}")
    road_map = RoadMap.from_file(rec.map_path)
    sightings, reid = vision_sightings(config, rec, out, road_map, stages=stages,
                                       target=targets[0])
    return _finish(config, out, stages, road_map, truth, sightings, reid,
                   {"simulated_s": max(p.t for rows in rec.poses.values() for p in rows),
                    "target_arrived_t": None, "vehicles": len(rec.truth.vehicle_ids)})


def _finish(config: ExperimentConfig, out: Path, stages: Stages, road_map, truth,
            sightings: list, reid: dict, run: dict) -> ExperimentResult:
    """Reconstruct and score the target's sightings; write the run's files and summary."""
    from dashtraj.trajectory.io import write_sightings, write_trajectory

    true_match = reid.pop("_true_match")
    stages.start("reconstruct", f"reconstruct ({', '.join(config.methods)}) from "
                                f"{len(sightings)} sightings in "
                                f"{len({(s.observer_id, s.track_id) for s in sightings})} "
                                "tracks, and score")
    write_sightings(out / "sightings.csv", sightings)
    write_trajectory(out / "truth.csv", truth)

    results, estimates, seen = reconstruct_and_score(road_map, truth, sightings,
                                                     config.methods, out, config.pose_noise)
    summary = {
        "config": config.to_dict(),
        **run,
        "sightings": len(sightings),
        "observers_that_saw_target": len({s.observer_id for s in sightings}),
        "target_tracks": len({(s.observer_id, s.track_id) for s in sightings}),
        **reid,
        "true_route_m": truth.length_m,
        "seen_route_m": seen.length_m,
        "methods": results,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return ExperimentResult(config, summary, truth, seen, sightings, estimates, road_map,
                            true_match, stages.stop())


def pose_sigma_options(pose_noise) -> dict:
    """The HMM's options for sightings made from poses with known GNSS/INS errors
    (``pose_noise``: `PerceiveConfig.pose_noise`, or None): its emission σ takes the
    observers' position and heading errors (`reconstruct_hmm`'s ``sigma_pose_m``,
    ``sigma_pose_deg``)."""
    if pose_noise is None:
        return {}
    return {"sigma_pose_m": float(pose_noise[0]), "sigma_pose_deg": float(pose_noise[1])}


def reconstruct_and_score(road_map, truth, sightings: list, methods, out: Path | None = None,
                          pose_noise=None) -> tuple[dict, dict, object]:
    """Reconstruct the route from `sightings` with each method and score it: the one
    reconstruction path of every sightings source (oracle, detections, vision) and of
    every row of the error budget.

    Args:
        road_map: the `RoadMap`. truth: the true `Trajectory`.
        sightings: the target's sightings (any source), time order.
        methods: names in `dashtraj.trajectory.reconstruct`.
        out: write ``estimate_<method>.csv`` here (None: nothing written).
        pose_noise: the observers' known pose errors (`pose_sigma_options`), or None.

    Returns:
        (per-method scores in metres: sspd/hausdorff whole and seen, points, warnings;
        per-method estimated `Trajectory`; the seen stretch of the truth, first to last
        sighting). No sightings: ({}, {}, truth).
    """
    from dashtraj.trajectory import Trajectory
    from dashtraj.trajectory.io import write_trajectory
    from dashtraj.trajectory.metrics import hausdorff, sspd
    from dashtraj.trajectory.reconstruct import reconstruct

    results: dict = {}
    estimates: dict = {}
    seen = truth
    if sightings:
        t0, t1 = min(s.t for s in sightings), max(s.t for s in sightings)
        keep = (truth.t >= t0) & (truth.t <= t1)
        if keep.sum() >= 2:
            seen = Trajectory(truth.points[keep], truth.t[keep])
        for method in methods:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                r = reconstruct(road_map, sightings, method=method,
                                **(pose_sigma_options(pose_noise) if method == "hmm" else {}))
            estimates[method] = r.trajectory
            if out is not None:
                write_trajectory(Path(out) / f"estimate_{method}.csv", r.trajectory)
            whole_sspd = float(sspd(truth, r.trajectory))
            whole_hd = float(hausdorff(truth, r.trajectory))
            seen_sspd = float(sspd(seen, r.trajectory))
            seen_hd = float(hausdorff(seen, r.trajectory))
            results[method] = {
                "sspd_whole_m": whole_sspd, "sspd_seen_m": seen_sspd,
                "hausdorff_whole_m": whole_hd, "hausdorff_seen_m": seen_hd,
                "sspd_m": whole_sspd, "hausdorff_m": whole_hd,
                "seen_sspd_m": seen_sspd, "seen_hausdorff_m": seen_hd,
                "points": len(r.trajectory),
                "warnings": [str(w.message) for w in caught],
            }
    return results, estimates, seen


def detector_of(name: str) -> str:
    """The perceive detector of an experiment's `detector` setting ("shipped", "gpu" → the
    package's ONNX detectors)."""
    from dashtraj.perception.detect import SHIPPED_DETECTORS, default_model_path

    if name in SHIPPED_DETECTORS:
        return str(default_model_path(name))
    return name


def reid_model_of(config: ExperimentConfig):
    """(ReidEmbedder, Threshold) of the experiment's ReID model (threshold beside it)."""
    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path
    from dashtraj.reidentify.vision import load_threshold

    path = Path(config.reid_model) if config.reid_model else shipped_model_path()
    th = load_threshold(path, config.reid_threshold)
    return ReidEmbedder(path, threads=1), th


def look_of(config: ExperimentConfig, threshold=None) -> str | None:
    """The render look of a vision run: the configured one, else the look the ReID
    threshold was calibrated on (its provenance: the models' domain), else the
    renderer's default (None)."""
    if config.look is not None or threshold is None:
        return config.look
    looks = {src.get("look") for src in threshold.provenance.get("sources", [])}
    return looks.pop() if len(looks) == 1 else None


def reid_range_of(config: ExperimentConfig) -> float:
    """How far perception keeps crops, metres: the gallery's range (``gallery_m``), or
    the query's (``max_distance_m``)."""
    return config.max_distance_m if config.gallery_m is None else config.gallery_m


def perceive_run(config: ExperimentConfig, rec, db_path: Path, detector: str,
                 look: str | None = None, stages: Stages | None = None,
                 also: Sequence[tuple[Path, str]] = ()) -> None:
    """Perceive every observer of `rec` into `db_path` with the experiment's settings
    (`config.workers` processes), saying how many frames are done as batches land.
    `also`: more (database path, detector) outputs perceived from the same frames, each
    rendered once (`dashtraj.perception.pipeline.perceive_each`)."""
    import math

    from dashtraj.datasets.drive import Drive
    from dashtraj.perception.pipeline import PerceiveConfig, perceive, perceive_each

    stages = stages or Stages()
    if isinstance(rec, Drive):
        n_obs = len(rec.observer_ids)
        total = rec.frame_count(config.every_s)
    else:
        n_obs = len(rec.meta.get("observer_ids", [])) or config.observers
        total = n_obs * (math.floor(float(rec.meta.get("simulated_to_t", config.duration_s))
                                    / config.every_s + 1e-9) + 1)
    detectors = [detector] + [d for _, d in also]
    stages.start(f"perceive ({', '.join(detectors)})",
                 f"perceive: {n_obs} observers × {total // max(n_obs, 1)} frames "
                 f"({config.image_size[0] if config.image_size else '?'}×"
                 f"{config.image_size[1] if config.image_size else '?'}, every "
                 f"{config.every_s:g} s), detector {' and '.join(detectors)}"
                 f"{' on the same frames' if also else ''}, {config.workers} workers")
    done = [0, 0]

    def progress(n: int) -> None:
        done[0] += n
        if done[0] - done[1] >= max(total // 10, 1) or done[0] >= total:
            done[1] = done[0]
            stages.note(f"perceive: {done[0]}/~{total} frames")

    def settings(det: str) -> PerceiveConfig:
        return PerceiveConfig(detector=detector_of(det), size=config.image_size,
                              every_s=config.every_s, look=look,
                              reid_range_m=reid_range_of(config),
                              agnostic_nms_iou=config.agnostic_nms_iou,
                              min_score=config.min_score, classifier=config.classifier,
                              confirm_score=config.confirm_score, localizer=config.localizer,
                              pose_noise=config.pose_noise, pose_noise_seed=config.seed,
                              calibrate_pitch=config.calibrate_pitch,
                              live_relink=config.live_relink,
                              reid_model=config.reid_model if config.live_relink else None)

    if also:
        outputs = [(db_path, detector), *also]
        summaries = perceive_each(rec, [(p, settings(d)) for p, d in outputs],
                                  workers=config.workers, progress=progress)
    else:
        summaries = [perceive(rec, db_path, settings(detector), workers=config.workers,
                              progress=progress)]
    for det, s in zip(detectors, summaries, strict=True):
        stages.note(f"perceive{f' ({det})' if also else ''}: {s.frames} frames, "
                    f"{s.detections} detections, {s.tracks} tracks, {s.crops} crops within "
                    f"{reid_range_of(config):g} m")


def vision_sightings(config: ExperimentConfig, rec, out: Path, road_map,
                     model=None, stages: Stages | None = None,
                     target: int | None = None) -> tuple[list, dict]:
    """``vision``: perceive into ``out/sightings.db``, then re-identify the target
    (`dashtraj.reidentify.vision.target_from_db`). `model`: (embedder, Threshold), or
    None to load `reid_model_of(config)`. `target`: its vehicle id (None: the
    recording's). A drive is perceived without a look: its images are what they are."""
    from dashtraj.datasets.drive import Drive
    from dashtraj.reidentify.vision import StageSwitches, target_from_db

    stages = stages or Stages()
    db_path = out / "sightings.db"
    if target is None:
        target = int(rec.meta.get("target_vehicle_id", 0))
    if config.reid == "identity":
        perceive_run(config, rec, db_path, config.detector,
                     None if isinstance(rec, Drive) else config.look, stages)
        stages.start("re-identify", "re-identify: the target's tracks by true identity")
        tt = target_from_db(db_path, road_map, target, switches=StageSwitches(reid="identity"),
                            max_distance_m=config.max_distance_m, sample_s=SAMPLE_S,
                            gallery_m=config.gallery_m, route_m=config.route_m)
        return tt.sightings, {**tt.summary, "look": config.look, "_true_match": tt.true_match}
    embedder, th = model if model is not None else reid_model_of(config)
    look = None if isinstance(rec, Drive) else look_of(config, th)
    perceive_run(config, rec, db_path, config.detector, look, stages)
    tt = target_from_db(db_path, road_map, target, embedder=embedder,
                        threshold=th.calibration.threshold, recipe=th.calibration.recipe,
                        gate=config.gate, max_distance_m=config.max_distance_m,
                        sample_s=SAMPLE_S, stages=stages, gallery_m=config.gallery_m,
                        route_m=config.route_m,
                        **({} if config.watch is None else {"watch": config.watch}),
                        **({} if config.lookalike is None else {"lookalike": config.lookalike}))
    s = tt.summary
    line = (f"re-identify: {s['reid_candidates']} of {s['reid_tracks']} tracks within "
            f"{reid_range_of(config):g} m pass the threshold, the gate keeps "
            f"{s['reid_candidates'] - s['reid_gated_out']}")
    if s.get("reid_split_tracks"):
        n = s["reid_split_tracks"]
        line += (f"; {n} track{'s' if n > 1 else ''} cut where {'their' if n > 1 else 'its'} "
                 f"crops' look changes ({s['reid_split_parts']} more part"
                 f"{'s' if s['reid_split_parts'] > 1 else ''})")
    if s.get("reid_jump_cuts"):
        n = s["reid_jump_cuts"]
        line += f"; {n} cut{'s' if n > 1 else ''} where a young track's box jumps"
    qc = s.get("reid_query_crops")
    if qc and qc["used"]:
        line += f" (query: the mean of {qc['used']} of its track's {qc['of']} crops)"
    elif qc:
        line += (f" (query: the one crop; none of its track's {qc['of']} usable crops is "
                 "within the threshold)")
    stages.note(line)
    return tt.sightings, {**tt.summary, "look": look, "reid_model": embedder.path.name,
                          "reid_threshold_calibration": th.calibration.to_dict(),
                          "_true_match": tt.true_match}


def target_sightings(config: ExperimentConfig, rec, out: Path, road_map,
                     stages: Stages | None = None) -> tuple[list, dict]:
    """The target's sightings from the configured source and re-identification mode.

    Candidate tracks: ``identity`` mode: the target's own (by truth: precision and
    recall 1.0 by construction); ``look-alike`` mode: every track of the target and
    of its twins (an appearance model that cannot tell vehicles of one model and
    colour apart, and tells every other vehicle apart), then, with `gate`, the
    spatio-temporal gate anchored on the track of the target's first sighting (the
    query crop, as ``calc_traj`` takes ``veh_t1.image``); a twin's track seen only
    before that sighting is not the target.

    Returns:
        (sightings of the accepted tracks, summary entries: reid_precision,
        reid_recall, their counts, reid_candidates, reid_gated_out).
    """
    from dashtraj.reidentify.scoring import reid_score
    from dashtraj.trajectory.gating import gate_tracks

    stages = stages or Stages()
    if config.sightings == "vision":
        return vision_sightings(config, rec, out, road_map, stages=stages)
    target = int(rec.meta.get("target_vehicle_id", 0))
    wanted = [target] + ([int(v) for v in rec.meta.get("twin_vehicle_ids", [])]
                         if config.reid == "look-alike" else [])
    tracks: dict[tuple, list] = {}
    truth: dict[tuple, int | None] = {}
    if config.sightings == "oracle":
        from dataclasses import replace as _replace

        stages.start("sightings", f"sightings: the oracle's within {config.max_distance_m:g} m,"
                                  f" noise {config.noise}")
        from dashtraj.world.oracle import OracleConfig, oracle_sightings

        for rank, vid in enumerate(wanted):
            ss = oracle_sightings(rec, OracleConfig(vehicle=vid, noise=config.noise,
                                                    seed=config.seed,
                                                    max_distance_m=config.max_distance_m,
                                                    sample_s=SAMPLE_S))
            for s in ss:  # one observer's track ids are per vehicle: keep them apart
                s = s if rank == 0 else _replace(s, track_id=s.track_id + 1000 * rank)
                tracks.setdefault((s.observer_id, s.track_id), []).append(s)
                truth[(s.observer_id, s.track_id)] = vid
    else:
        from dashtraj.reidentify.scoring import truth_of_tracks
        from dashtraj.store import SightingsDB

        db_path = out / "sightings.db"
        # the same perception settings as ``vision`` (frame period, box filters, the
        # tracker's confirmation rule, localizer, poses), with the renderer's exact boxes
        perceive_run(config, rec, db_path, "oracle", config.look, stages)
        with SightingsDB.open(db_path) as db:
            truth = truth_of_tracks(db, config.max_distance_m)
            every = db.sightings(max_distance_m=config.max_distance_m, sample_s=SAMPLE_S)
        for s in every:
            if truth.get((s.observer_id, s.track_id)) in wanted:
                tracks.setdefault((s.observer_id, s.track_id), []).append(s)
    candidates = list(tracks)
    accepted = candidates
    if config.reid == "look-alike" and config.gate and candidates:
        own = [k for k in candidates if truth.get(k) == target]
        anchor = start = None
        if own:
            first = min(own, key=lambda k: (min(s.t for s in tracks[k]), k))
            anchor = candidates.index(first)
            # the query is the target's first sighting: a look-alike seen only before
            # it is another vehicle
            start = min(s.t for s in tracks[first])
        res = gate_tracks(road_map, [tracks[k] for k in candidates], anchor=anchor,
                          weights=[len(tracks[k]) for k in candidates], start_t=start)
        accepted = [candidates[i] for i in res.accepted]
    keep = set(accepted)
    sightings = sorted((s for k in accepted for s in tracks[k]), key=lambda s: (s.t, s.observer_id))
    return sightings, {**reid_score(keep, truth, target).to_dict(),
                       "reid_candidates": len(candidates),
                       "reid_gated_out": len(candidates) - len(keep),
                       "_true_match": {k: truth.get(k) == target for k in accepted}}


def plot_experiment(result: ExperimentResult, path: str | Path) -> Path:
    """A top view like the paper's Fig. 6: true route red, HMM estimate yellow,
    observers as arrows with their ids where they first saw the target, each used
    sighting marked as a true match (blue) or a false one (pink)."""
    from dashtraj.report.plots import draw_map, draw_observers, draw_path, new_figure, save

    fig, ax = new_figure(result.road_map)
    draw_map(ax, result.road_map)
    truth = result.truth
    draw_path(ax, truth.points, "#d62728", label=f"ground truth ({truth.length_m:.0f} m)",
              width=3.0)
    methods = result.summary["methods"]
    if "hmm" in result.estimates:
        draw_path(ax, result.estimates["hmm"].points, "#ffcc00", width=2.0, zorder=7,
                  label=f"estimate, HMM (SSPD {methods['hmm']['sspd_m']:.2f} m)")
    first: dict = {}
    for s in result.sightings:
        first.setdefault(s.observer_id, (s.observer_id, s.observer_x, s.observer_y,
                                         s.observer_yaw))
    draw_observers(ax, list(first.values()))
    if result.sightings:
        ok = [result.true_match.get((s.observer_id, s.track_id), True) for s in result.sightings]
        for want, colour, label in ((True, "#1f5fbf", "true match"),
                                    (False, "#e377c2", "false match")):
            pts = [(s.x, s.y) for s, k in zip(result.sightings, ok, strict=True) if k == want]
            if pts:
                ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=10 if want else 18,
                           c=colour, marker="x", zorder=9 if want else 10,
                           label=f"sightings, {label} ({len(pts)}; estimated positions)")
    ax.legend(loc="upper right", fontsize=8)
    c = result.config
    where = f"drive {Path(c.drive).name}" if c.drive else f"{c.town}, seed {c.seed}"
    ax.set_title(f"{where}: {len(first)} observers saw the target")
    return save(fig, path)


PAPER_SET: tuple[ExperimentConfig, ...] = tuple(
    ExperimentConfig(town=town, seed=seed)
    for town in ("town01", "town10") for seed in range(5)
)
"""Ten experiments like the paper's: five in town01, five in town10 (seeds 0–4)."""


def aggregate(summaries: list[dict]) -> dict:
    """Mean and median per method over experiments, whole trip and seen stretch.

    Keys per method: ``experiments``; ``mean_<k>`` and ``median_<k>`` for k in
    sspd_m, hausdorff_m, seen_sspd_m, seen_hausdorff_m; and the issue's names of
    the means: ``sspd_whole_m``, ``sspd_seen_m``, ``hausdorff_whole_m``,
    ``hausdorff_seen_m``.
    """
    import numpy as np

    out: dict = {}
    for method in METHODS:
        rows = [s["methods"][method] for s in summaries if method in s["methods"]]
        if not rows:
            continue
        out[method] = {"experiments": len(rows)}
        for key in ("sspd_m", "hausdorff_m", "seen_sspd_m", "seen_hausdorff_m"):
            vals = np.array([r[key] for r in rows])
            out[method][f"mean_{key}"] = float(vals.mean())
            out[method][f"median_{key}"] = float(np.median(vals))
        for new, old in _ISSUE_KEYS.items():
            out[method][new] = out[method][f"mean_{old}"]
    return out


_ISSUE_KEYS = {"sspd_whole_m": "sspd_m", "sspd_seen_m": "seen_sspd_m",
               "hausdorff_whole_m": "hausdorff_m", "hausdorff_seen_m": "seen_hausdorff_m"}


def aggregate_reid(summaries: list[dict]) -> dict:
    """ReID precision and recall over all experiments' tracks (counts summed first), and
    with appearance ReID the misses by cause (`reidentify.vision.target_from_db`)."""
    from dashtraj.reidentify.scoring import ReidScore, pool

    out = pool(ReidScore(s.get("reid_true_matches", 0), s.get("reid_false_matches", 0),
                         s.get("reid_misses", 0)) for s in summaries).to_dict()
    if any("reid_sightings_true" in s for s in summaries):  # per sighting, from a DB
        out.update(pool(ReidScore(s.get("reid_sightings_true", 0),
                                  s.get("reid_sightings_false", 0),
                                  s.get("reid_sightings_missed", 0))
                        for s in summaries).sightings_dict())
    causes = [s["reid_misses_by_cause"] for s in summaries if "reid_misses_by_cause" in s]
    if causes:  # appearance ReID: why the target's missed tracks were missed
        out["reid_misses_by_cause"] = {k: sum(c.get(k, 0) for c in causes) for k in causes[0]}
    return out


def figures(name: str, summary: dict) -> dict:
    """One experiment's figures under the issue's keys (for ``--json``)."""
    return {"experiment": name, "sightings": summary["sightings"],
            "observers_that_saw_target": summary["observers_that_saw_target"],
            "methods": {m: {k: r[k] for k in _ISSUE_KEYS} for m, r in summary["methods"].items()},
            "reid_precision": summary.get("reid_precision"),
            "reid_recall": summary.get("reid_recall"),
            **({k: summary[k] for k in ("reid_sighting_precision", "reid_sighting_recall")
                if k in summary}),
            **({"reid_misses_by_cause": summary["reid_misses_by_cause"]}
               if "reid_misses_by_cause" in summary else {})}
