"""Where the built-in towns' .xodr files are cached: DASHTRAJ_CACHE, then XDG_CACHE_HOME,
then ~/.cache (the README's 'Built-in towns' section)."""

from __future__ import annotations

from pathlib import Path

from dashtraj.world.towns import town_path


def test_xdg_cache_home_is_honoured(tmp_path, monkeypatch):
    monkeypatch.delenv("DASHTRAJ_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    p = town_path("town01")
    assert p.parent == tmp_path / "xdg" / "dashtraj" / "towns"
    assert p.name.startswith("town01-") and p.suffix == ".xodr"


def test_dashtraj_cache_wins_over_xdg(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("DASHTRAJ_CACHE", str(tmp_path / "mine"))
    assert town_path("town01").parent == tmp_path / "mine" / "towns"
    assert not (tmp_path / "xdg").exists()


def test_home_cache_without_either(tmp_path, monkeypatch):
    monkeypatch.delenv("DASHTRAJ_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/ignored")  # the spec ignores relative paths
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert town_path("town01").parent == Path(tmp_path / "home" / ".cache" / "dashtraj" / "towns")
