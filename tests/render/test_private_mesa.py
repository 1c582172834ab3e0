"""The private Mesa (scripts/fetch_mesa.sh → <venv>/mesa): which Mesa a process picks, that a
spawned child picks the same one, that a broken one falls back to the system's, and that
both rasterize the same frame (the labels exactly, the pixels all but a few by one level)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from dashtraj.render import gl

_CHILD = textwrap.dedent("""
    import json, sys
    import numpy as np
    sys.path.insert(0, sys.argv[2])
    from render_scene import SEDAN, SUV, TRUCK, STRAIGHT_XODR, identity
    from dashtraj.render.gl import create_context, private_mesa
    from dashtraj.render.scene import Renderer
    from dashtraj.roads import RoadMap
    ctx = create_context(0)
    r = Renderer(RoadMap.from_string(STRAIGHT_XODR, name="s"), 320, 180, 90.0, msaa=0, ctx=ctx)
    cars = [(1, identity(SEDAN, (200, 30, 30), 1), -80.0, 1.75, 0.0, 0.0),
            (2, identity(SUV, (30, 30, 200), 2), -70.0, -1.75, 0.0, 180.0),
            (3, identity(TRUCK, (220, 220, 220), 3), -91.0, 5.25, 0.0, 0.0)]
    f = r.render((-95.0, 1.75, 1.6, 0.0, 0.0, 0.0), cars)
    np.save(sys.argv[1], f.rgb)
    print(json.dumps({"gl": ctx.info["GL_VERSION"], "mesa": str(private_mesa()),
                      "labels": [[lb.instance_id, lb.visible_box, lb.silhouette_box,
                                  lb.visible_pixels, lb.truncation] for lb in f.labels]}))
""")


def _render_in_child(tmp_path, name: str, **env) -> tuple[dict, np.ndarray]:
    tests_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = tmp_path / f"{name}.npy"
    full = {k: v for k, v in os.environ.items() if k != "__EGL_VENDOR_LIBRARY_FILENAMES"}
    r = subprocess.run([sys.executable, "-c", _CHILD, str(out), tests_dir],
                       env={**full, **env}, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1]), np.load(out)


def test_which_private_mesa_a_process_would_use(tmp_path, monkeypatch):
    d = tmp_path / "mesa"
    (d / "lib").mkdir(parents=True)
    monkeypatch.delenv("__EGL_VENDOR_LIBRARY_FILENAMES", raising=False)
    monkeypatch.setenv("DASHTRAJ_MESA", str(d))
    assert gl.private_mesa_dir() is None  # no vendor file: not a private Mesa
    (d / "egl_vendor.json").write_text("{}")
    assert gl.private_mesa_dir() == d
    monkeypatch.setenv("DASHTRAJ_MESA", "system")
    assert gl.private_mesa_dir() is None
    monkeypatch.setenv("DASHTRAJ_MESA", str(d))
    # the user's own vendor choice (e.g. NVIDIA's) wins; a worker inheriting ours keeps it
    monkeypatch.setenv("__EGL_VENDOR_LIBRARY_FILENAMES", "/usr/share/glvnd/egl_vendor.d/x.json")
    assert gl.private_mesa_dir() is None
    monkeypatch.setenv("__EGL_VENDOR_LIBRARY_FILENAMES", str(d / "egl_vendor.json"))
    assert gl.private_mesa_dir() == d


def test_a_moved_private_mesa_gets_its_vendor_file_rewritten(tmp_path):
    vendor = tmp_path / "egl_vendor.json"
    vendor.write_text(json.dumps({"ICD": {"library_path": "/old/place/libEGL_mesa.so.0"}}))
    lib = tmp_path / "lib" / "libEGL_mesa.so.0"
    gl._point_vendor_file_at(vendor, lib)
    assert json.loads(vendor.read_text())["ICD"]["library_path"] == str(lib)
    before = vendor.stat().st_mtime_ns
    gl._point_vendor_file_at(vendor, lib)  # already right: left alone
    assert vendor.stat().st_mtime_ns == before
    assert sorted(os.listdir(tmp_path)) == ["egl_vendor.json"]


def test_a_broken_private_mesa_falls_back_to_the_systems(tmp_path, gl_available):
    d = tmp_path / "mesa"
    (d / "lib").mkdir(parents=True)
    (d / "egl_vendor.json").write_text("{}")  # libraries missing
    info, _ = _render_in_child(tmp_path, "broken", DASHTRAJ_MESA=str(d))
    assert info["mesa"] == "None" and len(info["labels"]) == 3


def test_the_private_mesa_draws_what_the_systems_draws(tmp_path, gl_available):
    d = gl.private_mesa_dir()
    if d is None:
        pytest.skip("no private Mesa installed (scripts/fetch_mesa.sh: Debian 12 only)")
    mine, rgb_mine = _render_in_child(tmp_path, "private", DASHTRAJ_MESA=str(d))
    system, rgb_system = _render_in_child(tmp_path, "system", DASHTRAJ_MESA="system")
    assert mine["mesa"] == str(d) and system["mesa"] == "None"
    assert mine["gl"] != system["gl"]  # e.g. Mesa 25.0.7 against Debian 12's 22.3.6
    assert mine["labels"] == system["labels"]
    assert sum(lb[3] for lb in mine["labels"]) > 1000  # the cars are in view
    diff = np.abs(rgb_mine.astype(int) - rgb_system.astype(int))
    assert diff.max() <= 1 and (diff.max(axis=2) > 0).mean() < 1e-3
