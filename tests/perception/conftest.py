"""Fixtures of the perception tests: a small recording and its database."""

from __future__ import annotations

import warnings

import pytest

from dashtraj.world.camera import CameraSpec
from dashtraj.world.recording import Recording, RunConfig, simulate


@pytest.fixture(scope="session")
def small_run(tmp_path_factory):
    """25 s on town01, seed 1, 3 observers (1 and 3 pass the target within 15 m), 4 agents,
    a 320 x 180 camera."""
    root = tmp_path_factory.mktemp("perc") / "run"
    cfg = RunConfig(map="town01", seed=1, duration_s=25.0, n_observers=3, n_agents=4,
                    camera=CameraSpec(width_px=320, height_px=180))
    simulate(cfg, root)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return Recording.open(root)


@pytest.fixture(scope="session")
def small_db(small_run, gl_available, tmp_path_factory):
    """`dashtraj perceive` of observers 1 and 3 of `small_run` (the defaults: oracle, ego,
    smoothed)."""
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    path = tmp_path_factory.mktemp("percdb") / "run.db"
    summary = perceive(small_run, path, PerceiveConfig(observers=(1, 3)))
    return path, summary
