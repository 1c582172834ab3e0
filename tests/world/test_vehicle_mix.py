"""The "balanced" vehicle mix of `simulate`: every class gets an equal share, as far as the
catalog has distinct identities (two bus liveries), deterministic for a seed."""

import csv
from collections import Counter

import numpy as np
import pytest

from dashtraj.cli import main
from dashtraj.world.catalog import VEHICLE_CLASSES, identities
from dashtraj.world.recording import RecordingError, RunConfig, balanced_class_counts, simulate


def test_balanced_counts_share_equally_within_the_catalog():
    rng = np.random.default_rng(0)
    c = balanced_class_counts(rng, 23, VEHICLE_CLASSES)
    assert sum(c.values()) == 23 and max(c.values()) - min(c.values()) <= 1
    avail = Counter(i.model.vehicle_class for i in identities())
    c = balanced_class_counts(rng, 47, VEHICLE_CLASSES, dict(avail))
    assert sum(c.values()) == 47
    assert c["bus"] == avail["bus"] == 2  # all it has; the rest share the remainder
    others = [c[k] for k in VEHICLE_CLASSES if k != "bus"]
    assert max(others) - min(others) <= 1
    with pytest.raises(ValueError, match="only"):
        balanced_class_counts(rng, 10, ["bus"], {"bus": 2})


def test_simulate_balanced_mix(tmp_path):
    cfg = RunConfig(map="town01", seed=3, duration_s=1.0, n_observers=2, n_agents=22,
                    vehicle_mix="balanced", vehicle_classes=VEHICLE_CLASSES)
    simulate(cfg, tmp_path / "a")
    rows = list(csv.DictReader(open(tmp_path / "a" / "vehicles.csv", encoding="utf-8")))
    counts = Counter(r["vehicle_class"] for r in rows)
    assert counts["bus"] == 2  # both bus liveries; the other classes share the other 23
    assert sorted(counts[k] for k in ("car", "truck", "motorcycle", "bicycle")) == [5, 6, 6, 6]
    assert len({r["identity_id"] for r in rows}) == len(rows) == 25
    # same seed, same vehicles
    simulate(cfg, tmp_path / "b")
    assert (tmp_path / "a" / "vehicles.csv").read_bytes() == \
        (tmp_path / "b" / "vehicles.csv").read_bytes()
    with pytest.raises(RecordingError, match="unknown vehicle mix"):
        simulate(RunConfig(map="town01", duration_s=1.0, vehicle_mix="even"), tmp_path / "c")


def test_cli_vehicle_mix_options(tmp_path, capsys):
    assert main(["simulate", "--town", "town01", "--seed", "1", "--duration", "1",
                 "--observers", "1", "--agents", "9", "--vehicle-mix", "balanced",
                 "--vehicle-classes", "truck,bicycle", "-o", str(tmp_path / "r"), "-q"]) == 0
    rows = list(csv.DictReader(open(tmp_path / "r" / "vehicles.csv", encoding="utf-8")))
    assert Counter(r["vehicle_class"] for r in rows) == {"truck": 6, "bicycle": 5} or \
        Counter(r["vehicle_class"] for r in rows) == {"truck": 5, "bicycle": 6}
    assert main(["simulate", "--vehicle-classes", "car,tank", "-o", str(tmp_path / "x")]) == 2
    assert "tank" in capsys.readouterr().err
