"""Fixtures of the dataset tests: tiny recordings on town10."""

from __future__ import annotations

import pytest

from dashtraj.world.camera import CameraSpec
from dashtraj.world.recording import Recording, RunConfig, simulate


def _recording(root, seed: int) -> Recording:
    cfg = RunConfig(map="town10", seed=seed, duration_s=5.0, n_observers=2, n_agents=4,
                    camera=CameraSpec(width_px=160, height_px=90))
    simulate(cfg, root)
    return Recording.open(root)


@pytest.fixture(scope="session")
def recordings(tmp_path_factory):
    """Two 5 s recordings on town10 (2 observers, 4 agents, 160 x 90 camera)."""
    base = tmp_path_factory.mktemp("recordings")
    return [_recording(base / f"run{s}", s) for s in (1, 2)]
