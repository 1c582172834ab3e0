"""`dashtraj perceive --append`: observers perceived apart (several machines) make the one
run that perceiving them together makes; another source, other settings or an observer
already there are refused before any work; a failure leaves the run as it was."""

from __future__ import annotations

import json
import shutil
import sqlite3

import pytest
from test_pipeline import _same_content

from dashtraj.cli import main
from dashtraj.store import SightingsDB, StoreError


def _perceive(run, out, *extra) -> list[str]:
    return ["perceive", str(run), "-o", str(out), "-q", *extra]


def test_appending_observers_one_by_one_gives_the_run_of_both(small_run, small_db, tmp_path,
                                                              capsys):
    path, _ = small_db
    out = tmp_path / "run.db"
    # the first appender creates the run; the second, from a copy of the recording at
    # another path (another machine), appends to it
    assert main(_perceive(small_run.path, out, "--observers", "3", "--append")) == 0
    assert "appended 1 observers" in capsys.readouterr().out
    copy = tmp_path / "elsewhere"
    shutil.copytree(small_run.path, copy)
    assert main(_perceive(copy, out, "--observers", "1", "--append", "--json")) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["observers"] == 1 and info["run_observers"] == [1, 3]
    _same_content(path, out)
    with SightingsDB.open(out) as a, SightingsDB.open(path) as b:
        assert a.run_info()["complete"] and a.run_info()["recording"] == str(small_run.path)
        assert a.run_info()["config"] == b.run_info()["config"]  # observers [1, 3]
        assert a.meta() == b.meta() and len(a.meta()["source_sha256"]) == 64
        assert a.meta()["detector_sha256"] == "oracle"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere", "run.db"]


def test_append_refuses_another_run_before_any_work(small_run, small_db, tmp_path, capsys):
    path, _ = small_db
    out = tmp_path / "run.db"
    shutil.copy(path, out)
    before = out.read_bytes()

    def refused(*extra) -> str:
        assert main(_perceive(small_run.path, out, *extra)) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert out.read_bytes() == before
        return err

    assert "already has observer 1" in refused("--observers", "1", "--append")
    assert "perceived with every_s=0.1, these observers with every_s=0.5" in refused(
        "--observers", "2", "--every", "0.5", "--append")
    assert "tracker='ego', these observers with tracker='sort'" in refused(
        "--observers", "2", "--tracker", "sort", "--append")
    assert "give one of them" in refused("--observers", "2", "--append", "--overwrite")
    assert "calibrate_pitch=False, these observers with calibrate_pitch=True" in refused(
        "--observers", "2", "--calibrate-pitch", "--append")
    # another recording: same town and observers, another seed
    from dashtraj.world.camera import CameraSpec
    from dashtraj.world.recording import RunConfig, simulate

    other = tmp_path / "other"
    simulate(RunConfig(map="town01", seed=2, duration_s=2.0, n_observers=3, n_agents=4,
                       camera=CameraSpec(width_px=320, height_px=180)), other)
    assert main(_perceive(other, out, "--observers", "2", "--append")) == 2
    assert "from another recording or drive" in capsys.readouterr().err
    # a run written before the source's sha256 was recorded
    with sqlite3.connect(out) as c:
        c.execute("DELETE FROM meta WHERE key = 'source_sha256'")
    assert main(_perceive(small_run.path, out, "--observers", "2", "--append")) == 2
    assert "before perceive recorded its source's sha256" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other", "run.db"]


def test_a_failed_append_keeps_its_partial_and_leaves_the_run_as_it_was(
        small_run, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run.db"
    assert main(_perceive(small_run.path, out, "--observers", "3", "--every", "1.0",
                          "--append")) == 0
    before = out.read_bytes()
    args = _perceive(small_run.path, out, "--observers", "1", "--every", "1.0", "--append")
    with monkeypatch.context() as m:  # Ctrl-C at the end of the appender's work
        m.setattr(SightingsDB, "finish_run", lambda self: (_ for _ in ()).throw(
            KeyboardInterrupt()))
        assert main(args) == 130
    assert "kept the partial output in" in capsys.readouterr().err
    assert out.read_bytes() == before
    # an appender that finds its observer appended meanwhile copies nothing
    from dashtraj.store import append as append_mod

    real = append_mod.merge_run

    def raced(d, run, part, where):
        d.execute(f"INSERT INTO {run}observers (observer_id, role) VALUES (1, 'x')")
        return real(d, run, part, where)

    with monkeypatch.context() as m:
        m.setattr(append_mod, "merge_run", raced)
        assert main(args) == 2
    err = capsys.readouterr().err
    assert "already has observer 1 (appended meanwhile?)" in err
    assert "kept the partial output in" in err
    assert out.read_bytes() == before
    kept = sorted(p.name for p in tmp_path.iterdir())
    assert kept == ["run.db", "run.db.partial-1", "run.db.partial-2"]
    with SightingsDB.open(tmp_path / "run.db.partial-2") as part:
        assert part.run_info()["complete"] and part.count("poses") == 26
    assert main(args) == 0
    with SightingsDB.open(out) as db:
        assert [o["observer_id"] for o in db.observers()] == [1, 3]
        assert db.count("poses") == 52


def test_append_without_observers_takes_those_the_run_lacks(small_run, small_db, tmp_path,
                                                            capsys):
    path, _ = small_db
    out = tmp_path / "run.db"
    shutil.copy(path, out)
    assert main(_perceive(small_run.path, out, "--every", "2.5", "--append")) == 2
    capsys.readouterr()
    assert main(_perceive(small_run.path, out, "--append", "--json")) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["observers"] == 1 and info["run_observers"] == [1, 2, 3]
    assert main(_perceive(small_run.path, out, "--append")) == 2
    assert "already has every observer" in capsys.readouterr().err


def test_append_into_postgres_from_two_processes_gives_the_one_run(small_run, small_db,
                                                                   pg_url, tmp_path):
    """Two appenders at once into one schema (two machines): each writes its partial
    schema, the first to finish becomes the run, the other is appended under the lock."""
    import subprocess
    import sys

    import psycopg

    from dashtraj.store.backend import parse_url

    path, _ = small_db
    procs = [subprocess.Popen([sys.executable, "-m", "dashtraj", *_perceive(
        small_run.path, pg_url, "--observers", o, "--append")], stderr=subprocess.PIPE,
        text=True) for o in ("1", "3")]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    _same_content(path, pg_url)
    target = parse_url(pg_url)
    with psycopg.connect(target.conninfo) as c:
        left = c.execute("SELECT schema_name FROM information_schema.schemata WHERE "
                         "schema_name LIKE %s", (target.schema + "%",)).fetchall()
    assert left == [(target.schema,)]
    with pytest.raises(StoreError, match="already has observer 3"):
        from dashtraj.perception.pipeline import PerceiveConfig, perceive
        from dashtraj.store.pg_output import pg_atomic_output

        with pg_atomic_output(pg_url, append=True, quiet=True) as part:
            perceive(small_run, part, PerceiveConfig(observers=(3,)))


def test_run_identity_fills_new_settings_in_and_takes_zero_pose_noise_for_none():
    from dashtraj.store.append import ADDED_SETTINGS, run_identity

    meta = {"source_sha256": "a" * 64, "detector_sha256": "b" * 64}
    old = {"every_s": 0.1, "tracker": "ego", "observers": [1]}
    assert "calibrate_pitch" in ADDED_SETTINGS
    assert run_identity(meta, "m", {}, old) == run_identity(
        meta, "m", {}, {**old, "calibrate_pitch": False, "observers": [2]})
    assert run_identity(meta, "m", {}, old) != run_identity(
        meta, "m", {}, {**old, "calibrate_pitch": True})
    # zero pose errors are the exact poses, whatever their seed; real errors are not
    exact = {**old, "pose_noise": None, "pose_noise_seed": 0}
    assert run_identity(meta, "m", {}, exact) == run_identity(
        meta, "m", {}, {**old, "pose_noise": [0.0, 0.0, 0.0, 30.0], "pose_noise_seed": 5})
    noisy = {**old, "pose_noise": [0.5, 0.3, 0.0, 30.0], "pose_noise_seed": 0}
    assert run_identity(meta, "m", {}, noisy) != run_identity(meta, "m", {}, exact)
    assert run_identity(meta, "m", {}, noisy) != run_identity(
        meta, "m", {}, {**noisy, "pose_noise_seed": 1})
