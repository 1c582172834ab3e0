"""The output discipline: whole or nothing, never merged, refused unless --overwrite."""

from __future__ import annotations

import pytest

from dashtraj.outputs import OutputExistsError, OutputPathError, atomic_output, check_output


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
