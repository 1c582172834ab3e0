"""Every benchmark script imports from a clean clone and has a guarded ``main``.

`make bench` runs ``bench/bench_*.py`` one after the other and stops at the first that
fails; a bench that imported a test helper (``tests/`` is not on the path there) broke
the loop once without any test noticing. This imports each module the way the loop
runs it (by file, with only the installed package importable), checks that it defines
``main(argv)`` behind ``if __name__ == "__main__":`` (so importing runs nothing), and
parses ``--help`` through it. It does not time anything.
"""

from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
SCRIPTS = sorted(BENCH.glob("bench_*.py"))
TEST_MODULES = {p.stem for p in Path(__file__).resolve().parent.rglob("*.py")}
"""Names of modules under tests/ (conftest, render_scene, carla_maps, ...)."""


def _imported_names(source: str) -> set[str]:
    """Top-level names of every module imported anywhere in ``source`` (functions too)."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_there_are_benchmarks():
    assert len(SCRIPTS) >= 6


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_bench_module_imports_and_parses_help(script, monkeypatch, capsys):
    tests_dir = str(Path(__file__).resolve().parent)
    # as `python bench/bench_x.py` sees it: bench/ first, never tests/
    path = [p for p in sys.path if Path(p or ".").resolve() != Path(tests_dir)]
    monkeypatch.setattr(sys, "path", [str(BENCH), *path])
    source = script.read_text(encoding="utf-8")
    assert 'if __name__ == "__main__":' in source
    from_tests = _imported_names(source) & TEST_MODULES
    assert not from_tests, f"{script.name} imports test helpers {sorted(from_tests)}"
    assert "tests" not in [part for line in source.splitlines() if "sys.path" in line
                           for part in line.replace('"', " ").replace("'", " ").split()]
    spec = importlib.util.spec_from_file_location(f"_bench_{script.stem}", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert callable(getattr(module, "main", None))
    with pytest.raises(SystemExit) as exc:
        module.main(["--help"])
    assert exc.value.code == 0
    assert "usage:" in capsys.readouterr().out
