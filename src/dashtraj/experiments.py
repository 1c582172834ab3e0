"""Driving experiments as in the paper (§II.G), end to end, and their scores.

One experiment: simulate a town with observers, one target and agents until the
target arrives → oracle sightings of the target within 15 m with the paper's
localization noise → reconstruct its route with each method → score against the
true route with SSPD and Hausdorff distance (metres), both over the whole trip
(the paper's figure) and over the stretch the sightings cover (first to last
sighting; what the sightings can speak to). The paper's set is ten experiments,
five in Town01 and five in Town10: `PAPER_SET`.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

PAPER_SSPD_M = 5.13
"""The paper's mean SSPD over its ten driving experiments, metres."""

METHODS = ("shortest-path", "hmm")


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
    """

    town: str = "town10"
    seed: int = 7
    observers: int = 4
    agents: int = 20
    duration_s: float = 180.0
    noise: str = "paper"
    max_distance_m: float = 15.0
    methods: tuple[str, ...] = METHODS

    def to_dict(self) -> dict:
        d = asdict(self)
        d["methods"] = list(self.methods)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> ExperimentConfig:
        return cls(**{**d, "methods": tuple(d.get("methods", METHODS))})


@dataclass(slots=True)
class ExperimentResult:
    config: ExperimentConfig
    summary: dict
    truth: object = field(repr=False)
    seen: object = field(repr=False)
    sightings: list = field(repr=False)
    estimates: dict = field(repr=False)
    road_map: object = field(repr=False)


def run_experiment(config: ExperimentConfig, out: str | Path,
                   progress: Callable[[float], None] | None = None) -> ExperimentResult:
    """Run one experiment, writing its files into `out`.

    Files: ``recording/`` (the simulation), ``sightings.csv``, ``truth.csv``,
    ``estimate_<method>.csv``, ``summary.json`` (with the config, to repeat the run).
    """
    from dashtraj.roads import RoadMap
    from dashtraj.trajectory import Trajectory
    from dashtraj.trajectory.io import write_sightings, write_trajectory
    from dashtraj.trajectory.metrics import hausdorff, sspd
    from dashtraj.trajectory.reconstruct import reconstruct
    from dashtraj.world.oracle import OracleConfig, oracle_sightings
    from dashtraj.world.recording import Recording, RunConfig, simulate

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    run_config = RunConfig(map=config.town, seed=config.seed, duration_s=config.duration_s,
                           n_observers=config.observers, n_agents=config.agents,
                           until_target_arrives=True)
    run = simulate(run_config, out / "recording", progress=progress)
    rec = Recording.open(out / "recording")
    sightings = oracle_sightings(rec, OracleConfig(noise=config.noise, seed=config.seed,
                                                   max_distance_m=config.max_distance_m))
    write_sightings(out / "sightings.csv", sightings)
    truth = rec.target_route
    write_trajectory(out / "truth.csv", truth)
    road_map = RoadMap.from_file(rec.map_path)

    results: dict = {}
    estimates: dict = {}
    seen = truth
    if sightings:
        t0, t1 = min(s.t for s in sightings), max(s.t for s in sightings)
        keep = (truth.t >= t0) & (truth.t <= t1)
        if keep.sum() >= 2:
            seen = Trajectory(truth.points[keep], truth.t[keep])
        for method in config.methods:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                r = reconstruct(road_map, sightings, method=method)
            estimates[method] = r.trajectory
            write_trajectory(out / f"estimate_{method}.csv", r.trajectory)
            results[method] = {
                "sspd_m": float(sspd(truth, r.trajectory)),
                "hausdorff_m": float(hausdorff(truth, r.trajectory)),
                "seen_sspd_m": float(sspd(seen, r.trajectory)),
                "seen_hausdorff_m": float(hausdorff(seen, r.trajectory)),
                "points": len(r.trajectory),
                "warnings": [str(w.message) for w in caught],
            }
    summary = {
        "config": config.to_dict(),
        "simulated_s": run.simulated_to_t,
        "target_arrived_t": run.target_arrived_t,
        "vehicles": run.vehicles,
        "sightings": len(sightings),
        "observers_that_saw_target": len({s.observer_id for s in sightings}),
        "true_route_m": truth.length_m,
        "seen_route_m": seen.length_m,
        "methods": results,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return ExperimentResult(config, summary, truth, seen, sightings, estimates, road_map)


def plot_experiment(result: ExperimentResult, path: str | Path) -> Path:
    """A top view like the paper's Fig. 6: true route red, HMM estimate yellow,
    observers as arrows with their ids where they first saw the target."""
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
        ax.scatter([s.x for s in result.sightings], [s.y for s in result.sightings], s=10,
                   c="#1f5fbf", marker="x", zorder=9, label="sightings (estimated positions)")
    ax.legend(loc="upper right", fontsize=8)
    c = result.config
    ax.set_title(f"{c.town}, seed {c.seed}: {len(first)} observers saw the target")
    return save(fig, path)


PAPER_SET: tuple[ExperimentConfig, ...] = tuple(
    ExperimentConfig(town=town, seed=seed)
    for town in ("town01", "town10") for seed in range(5)
)
"""Ten experiments like the paper's: five in town01, five in town10 (seeds 0–4)."""


def aggregate(summaries: list[dict]) -> dict:
    """Mean and median per method over experiments, whole trip and seen stretch."""
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
    return out
