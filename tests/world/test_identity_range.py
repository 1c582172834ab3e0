"""Recordings can draw their vehicles from a range of catalog identities."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.world.catalog import sample_identities
from dashtraj.world.recording import RunConfig


def test_sample_identities_in_range():
    ids = sample_identities(np.random.default_rng(0), 30, id_range=(650, 700))
    assert len({i.identity_id for i in ids}) == 30
    assert all(650 <= i.identity_id < 700 for i in ids)
    with pytest.raises(ValueError, match="only 50 match"):
        sample_identities(np.random.default_rng(0), 51, id_range=(650, 700))


def test_run_config_round_trips_the_range():
    cfg = RunConfig(map="town01", identity_range=(650, 700))
    assert RunConfig.from_json(cfg.to_json()) == cfg


def test_simulate_with_identities(tmp_path):
    out = tmp_path / "run"
    assert main(["simulate", "--town", "town01", "--agents", "6", "--duration", "2",
                 "--identities", "650-700", "-q", "-o", str(out)]) == 0
    with open(out / "vehicles.csv", newline="") as f:
        ids = [int(r["identity_id"]) for r in csv.DictReader(f)]
    assert len(ids) == 11 and all(650 <= i < 700 for i in ids)
