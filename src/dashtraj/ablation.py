"""The error budget (the paper's Table IV, with numbers): each perception stage switched
between an oracle and the real thing, and the SSPD each real stage adds.

One experiment is simulated once and perceived twice from the same frames, each rendered
once (`dashtraj.perception.pipeline.perceive_each`): the renderer's exact boxes and the
detector model. The target's sightings are then taken five ways, stages turned real one
at a time in pipeline order (`ROWS`):

1. ``oracle``: exact boxes, tracks by true identity, true positions, the target's
   tracks by identity;
2. ``+ detection``: the detector model's boxes (tracks still by true identity);
3. ``+ tracking``: the tracker's tracks;
4. ``+ localization``: estimated positions (localizer and map-matching);
5. ``+ ReID``: appearance re-identification with the calibrated threshold and the
   gate: the whole ``--sightings vision`` pipeline.

(`EXTRA_ROWS`: the whole pipeline on the exact boxes, from the same databases.)

Every row goes through the same `dashtraj.experiments.reconstruct_and_score`; a
stage's impact is the mean SSPD of its row minus that of the row before (metres; a
negative impact means the real stage happened to do better on these runs).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

ROWS: tuple[tuple[str, str, str, str, str], ...] = (
    # name, detector db, tracks, positions, reid
    ("oracle", "oracle", "truth", "truth", "identity"),
    ("detection", "model", "truth", "truth", "identity"),
    ("tracking", "model", "tracker", "truth", "identity"),
    ("localization", "model", "tracker", "estimated", "identity"),
    ("reid", "model", "tracker", "estimated", "appearance"),
)
"""The ablation's rows: stages turned real cumulatively in pipeline order."""

EXTRA_ROWS: tuple[tuple[str, str, str, str, str], ...] = (
    ("vision-oracle-detector", "oracle", "tracker", "estimated", "appearance"),
)
"""Also computed (no extra perception): the vision pipeline on the exact boxes."""

SOURCES = {"detection": "vehicle detection (the detector model vs exact boxes)",
           "tracking": "tracking (the tracker vs true identities)",
           "localization": "localization and map-matching (estimated vs true positions)",
           "reid": "re-identification (appearance + gate vs identity)"}
"""Error source of each real stage, in Table IV's words."""


def run_ablation(config, out: str | Path,
                 progress: Callable[[str], None] | None = None) -> dict:
    """Run one experiment's ablation, writing ``out/ablation.json``.

    Args:
        config: an `ExperimentConfig` (its detector is the "model" of rows 2-5; its
            ReID model and threshold those of row 5).
        out: a folder (recording/, oracle.db, model.db, ablation.json).
        progress: called with a stage name as each starts.

    Returns:
        {"config", "rows": {row: {"sightings", reid counts, "methods": scores}}}.
    """
    from dashtraj.experiments import (
        SAMPLE_S,
        look_of,
        perceive_run,
        reconstruct_and_score,
        reid_model_of,
    )
    from dashtraj.reidentify.vision import StageSwitches, target_from_db, true_positions
    from dashtraj.roads import RoadMap
    from dashtraj.world.recording import Recording, RunConfig, simulate

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda _s: None)
    embedder, th = reid_model_of(config)
    look = look_of(config, th)
    say("simulate")
    simulate(RunConfig(map=config.town, seed=config.seed, duration_s=config.duration_s,
                       n_observers=config.observers, n_agents=config.agents,
                       n_twins=config.twins, until_target_arrives=True), out / "recording")
    rec = Recording.open(out / "recording")
    road_map = RoadMap.from_file(rec.map_path)
    truth = rec.target_route
    target = int(rec.meta.get("target_vehicle_id", 0))
    dbs = {"oracle": out / "oracle.db", "model": out / "model.db"}
    say(f"perceive (oracle and {config.detector} detectors, each frame rendered once)")
    perceive_run(config, rec, dbs["oracle"], "oracle", look,
                 also=[(dbs["model"], config.detector)])
    positions = true_positions(rec)
    rows: dict = {}
    for name, db, tracks, pos, reid in ROWS + EXTRA_ROWS:
        say(f"row {name}")
        tt = target_from_db(dbs[db], road_map, target,
                            switches=StageSwitches(tracks=tracks, positions=pos, reid=reid),
                            embedder=embedder, threshold=th.calibration.threshold,
                            recipe=th.calibration.recipe, gate=config.gate,
                            max_distance_m=config.max_distance_m, sample_s=SAMPLE_S,
                            positions_of=positions)
        results, _est, _seen = reconstruct_and_score(road_map, truth, tt.sightings,
                                                     config.methods)
        rows[name] = {"sightings": len(tt.sightings),
                      **{k: v for k, v in tt.summary.items() if k.startswith("reid_")},
                      "methods": {m: {k: r[k] for k in ("sspd_whole_m", "sspd_seen_m",
                                                         "hausdorff_whole_m",
                                                         "hausdorff_seen_m")}
                                  for m, r in results.items()}}
    res = {"config": config.to_dict(), "look": look, "reid_model": embedder.path.name,
           "detector": config.detector, "rows": rows}
    (out / "ablation.json").write_text(json.dumps(res, indent=2) + "\n")
    return res


def budget(results: list[dict], methods=("hmm", "shortest-path")) -> dict:
    """Mean SSPD per row and method over experiments, and each real stage's impact.

    A row's mean is over the experiments where it had sightings (a row with none has
    nothing to reconstruct); a stage's impact is the mean over the experiments where
    both its row and the row before had sightings of the difference between the two.

    Returns:
        {method: {"experiments": n, "rows": {row: {"sspd_whole_m", "sspd_seen_m",
        "experiments"}}, "impact": {stage: {"sspd_whole_m", "sspd_seen_m",
        "experiments"}}}}, metres.
    """
    import numpy as np

    keys = ("sspd_whole_m", "sspd_seen_m")
    out: dict = {}
    names = [r[0] for r in ROWS] + [r[0] for r in EXTRA_ROWS]
    for m in methods:
        def has(r, n, m=m):
            return m in r["rows"].get(n, {}).get("methods", {})

        rows = {}
        for n in names:
            ok = [r for r in results if has(r, n)]
            if ok:
                rows[n] = {**{k: float(np.mean([r["rows"][n]["methods"][m][k] for r in ok]))
                              for k in keys}, "experiments": len(ok)}
        impact = {}
        for i in range(1, len(ROWS)):
            a, b = ROWS[i - 1][0], ROWS[i][0]
            ok = [r for r in results if has(r, a) and has(r, b)]
            if ok:
                impact[b] = {**{k: float(np.mean([r["rows"][b]["methods"][m][k]
                                                  - r["rows"][a]["methods"][m][k] for r in ok]))
                                for k in keys}, "experiments": len(ok)}
        if rows:
            out[m] = {"experiments": len(results), "rows": rows, "impact": impact}
    return out
