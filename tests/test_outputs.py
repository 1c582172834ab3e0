"""The output discipline: whole or nothing, never merged, refused unless --overwrite."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from dashtraj.outputs import (
    OutputExistsError,
    OutputPathError,
    atomic_output,
    check_output,
    replace_together,
)


def _fill(d, names):
    for n in names:
        (d / n).write_text(n)


def test_new_folder_created_with_missing_parents(tmp_path):
    out = tmp_path / "a" / "b" / "run"
    with atomic_output(out) as tmp:
        assert tmp.parent == out.parent and tmp != out
        _fill(tmp, ["x.txt"])
        assert not out.exists()
    assert sorted(p.name for p in out.iterdir()) == ["x.txt"]
    assert [p.name for p in out.parent.iterdir()] == ["run"]  # no temporary left


def test_existing_output_refused_and_untouched(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    _fill(out, ["old.txt"])
    with pytest.raises(OutputExistsError, match="--overwrite"), atomic_output(out):
        pytest.fail("body must not run")
    assert [p.name for p in out.iterdir()] == ["old.txt"]


def test_empty_existing_folder_is_fine(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    with atomic_output(out) as tmp:
        _fill(tmp, ["new.txt"])
    assert [p.name for p in out.iterdir()] == ["new.txt"]


def test_overwrite_replaces_whole_never_merges(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    _fill(out, ["old.txt", "shared.txt"])
    with atomic_output(out, overwrite=True) as tmp:
        _fill(tmp, ["shared.txt", "new.txt"])
    assert sorted(p.name for p in out.iterdir()) == ["new.txt", "shared.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_failure_leaves_old_output_untouched(tmp_path, exc):
    out = tmp_path / "run"
    out.mkdir()
    _fill(out, ["old.txt"])
    with pytest.raises(type(exc)), atomic_output(out, overwrite=True) as tmp:
        _fill(tmp, ["new.txt"])
        raise exc
    assert [p.name for p in out.iterdir()] == ["old.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_keep_partial_goes_to_its_own_folder(tmp_path, capsys):
    out = tmp_path / "rec"
    out.mkdir()
    _fill(out, ["old.txt"])
    for _ in range(2):
        with pytest.raises(KeyboardInterrupt), atomic_output(out, overwrite=True,
                                                              keep_partial=True) as tmp:
            _fill(tmp, ["meta.json"])
            raise KeyboardInterrupt
    assert [p.name for p in out.iterdir()] == ["old.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec", "rec.partial-1", "rec.partial-2"]
    assert (tmp_path / "rec.partial-2" / "meta.json").exists()
    assert "rec.partial-1" in capsys.readouterr().err


def test_file_output(tmp_path):
    out = tmp_path / "d" / "x.csv"
    with atomic_output(out, kind="file") as tmp:
        assert tmp.suffix == ".csv"
        tmp.write_text("a\n")
    assert out.read_text() == "a\n"
    with pytest.raises(OutputExistsError):
        check_output(out, overwrite=False, kind="file")
    with atomic_output(out, kind="file", overwrite=True) as tmp:
        tmp.write_text("b\n")
    assert out.read_text() == "b\n"
    assert sorted(p.name for p in out.parent.iterdir()) == ["x.csv"]


def test_file_output_nothing_written(tmp_path):
    with pytest.raises(OutputPathError, match="nothing was written"), \
            atomic_output(tmp_path / "x.csv", kind="file"):
        pass


def test_kind_mismatch_and_file_parent(tmp_path):
    f = tmp_path / "f"
    f.write_text("keep")
    with pytest.raises(OutputPathError, match="is a file"):
        check_output(f, overwrite=True, kind="dir")
    with pytest.raises(OutputPathError, match="is a file"):
        check_output(f / "sub", overwrite=True, kind="dir")
    with pytest.raises(OutputPathError, match="is a folder"):
        check_output(tmp_path, overwrite=True, kind="file")
    assert f.read_text() == "keep"


def test_unwritable_parent_refused_up_front(tmp_path):
    import os

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        if os.access(ro, os.W_OK):  # root ignores permissions
            pytest.skip("running as a user who can write anywhere")
        with pytest.raises(OutputPathError, match="cannot write in"):
            check_output(ro / "new" / "out.csv", overwrite=False, kind="file")
    finally:
        ro.chmod(0o755)


def _dead_pid() -> int:
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temporaries_of_killed_processes_are_swept(tmp_path):
    # a process of this host killed outright (SIGKILL) leaves its temporary sibling behind;
    # the next write to the same output removes it, and nothing else
    from dashtraj.outputs import _HOST

    dead, live = _dead_pid(), os.getppid()
    out = tmp_path / "run"
    stale = [tmp_path / f".run.tmp-{dead}@{_HOST}", tmp_path / f".run.tmp-{dead}@{_HOST}-2"]
    kept = [
        tmp_path / f".run.tmp-{live}@{_HOST}",          # a live writer
        tmp_path / f".run.tmp-{dead}@not-{_HOST}",      # another host's (shared disk)
        tmp_path / f".run.tmp-{dead}",                  # an older name without the host
        tmp_path / f".run.old-{dead}",                  # a replacement's backup: user data
        tmp_path / f".runs.tmp-{dead}@{_HOST}",         # another output's
    ]
    for d in stale + kept:
        d.mkdir()
        _fill(d, ["part.txt"])
    with atomic_output(out) as tmp:
        _fill(tmp, ["x.txt"])
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted(["run"] + [d.name for d in kept])

    db = tmp_path / "s.db"
    stale_files = [tmp_path / f".s.db.tmp-{dead}@{_HOST}.db{j}" for j in ("", "-wal", "-shm")]
    for f in stale_files:
        f.write_bytes(b"half a database")
    with atomic_output(db, kind="file") as tmp:
        tmp.write_bytes(b"whole")
    assert not any(f.exists() for f in stale_files) and db.read_bytes() == b"whole"


def test_temporary_sibling_names_its_process_and_host(tmp_path):
    from dashtraj.outputs import _HOST

    with atomic_output(tmp_path / "run") as tmp:
        assert tmp.name == f".run.tmp-{os.getpid()}@{_HOST}"


def _staged(tmp_path):
    """A folder and the list naming its files, old ones in place and new ones staged."""
    (tmp_path / "set").mkdir()
    _fill(tmp_path / "set", ["a.jpg"])
    (tmp_path / "names.txt").write_text("a.jpg\n")
    stage = tmp_path / ".stage"
    (stage / "set").mkdir(parents=True)
    _fill(stage / "set", ["a.jpg", "b.jpg"])
    (stage / "names.txt").write_text("a.jpg\nb.jpg\n")
    (stage / "new.json").write_text("{}")
    return [(stage / "set", tmp_path / "set"), (stage / "names.txt", tmp_path / "names.txt"),
            (stage / "new.json", tmp_path / "new.json")]


def test_replace_together_moves_all(tmp_path):
    replace_together(_staged(tmp_path))
    assert sorted(p.name for p in (tmp_path / "set").iterdir()) == ["a.jpg", "b.jpg"]
    assert (tmp_path / "names.txt").read_text().split() == ["a.jpg", "b.jpg"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".stage", "names.txt", "new.json",
                                                            "set"]  # no backup left
    assert not any((tmp_path / ".stage").iterdir())


@pytest.mark.parametrize("fail_at", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("exc", [OSError("disk"), KeyboardInterrupt()])
def test_replace_together_interrupted_restores_all(tmp_path, monkeypatch, fail_at, exc):
    moves = _staged(tmp_path)
    calls = {"n": 0}
    rename = Path.rename

    def flaky(self, target):  # the fail_at-th rename fails (2 backups, then 3 moves in)
        calls["n"] += 1
        if calls["n"] == fail_at:
            raise exc
        return rename(self, target)

    monkeypatch.setattr(Path, "rename", flaky)
    with pytest.raises(type(exc)):
        replace_together(moves)
    monkeypatch.setattr(Path, "rename", rename)
    # every path holds what it held before, the staged files are still staged
    assert [p.name for p in (tmp_path / "set").iterdir()] == ["a.jpg"]
    assert (tmp_path / "names.txt").read_text() == "a.jpg\n"
    assert not (tmp_path / "new.json").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [".stage", "names.txt", "set"]
    assert sorted(p.name for p in (tmp_path / ".stage").iterdir()) == ["names.txt", "new.json",
                                                                      "set"]
