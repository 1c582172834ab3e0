"""Benchmark of dashtraj.render: frames per second with 20 vehicles in view, and the
cost of each effect of the look (lighting, shadows, textures, weather, camera).

Labels included (instance, depth and silhouette passes), image encoding excluded.
Scene: the synthetic straight town of the render tests (`dashtraj.render.synthetic`),
camera on a lane looking down the road at 20 vehicles (dense: most overlap in the image, 11 hidden).

Usage:
    .venv/bin/python bench/bench_render.py [--frames 60] [--threads 0] [--msaa 4 0]

``--threads 0`` makes llvmpipe rasterize on the calling thread (one core); the
targets are ≥ 100 fps at 640×360 and ≥ 25 fps at 1280×720 on one core. The
one-core figure is the CPU time per frame (``time.process_time``, all threads): on
a machine whose cores are shared, wall-clock time also counts waiting for a core.
Each ``--msaa`` value is timed (0: one pass for colour, ids and depth, no AA; 4:
MSAA colour pass + id/depth pass; llvmpipe supports only 4 samples), with the default
look (clear daytime: sun, shadows, textures, sky, camera response).

Effects (640×360, no MSAA, labels included; ``--no-effects`` skips them): the peer is
the ``flat`` look (the renderer before lighting, materials and camera effects existed)
measured in the same run; each row is the default look with one effect removed (−) or
added (+), and ``randomized`` draws a new look per frame (``dashtraj.render.randomize``).
Rows are timed in interleaved rounds (so load changes hit all of them alike); the
figure is the median CPU time per frame, its difference to the default look and its
ratio to the flat peer.

Geometry (``--no-geometry`` skips it): the same frames without the street clutter and
without the contact shadows under the vehicles (the cost of the new geometry), on the
straight street and on Town01 when ``../shared/maps/carla`` is there.

Mesa (``--no-mesa`` skips it; only where a private Mesa is installed, ``scripts/fetch_mesa.sh``):
the default look at 640×360 without MSAA, labels included, timed in alternating child
processes with the private Mesa (Mesa 25 from Debian bookworm-backports) and with the
system's (``DASHTRAJ_MESA=system``; Debian 12: Mesa 22.3): the peer is the system's
rasterizer, same frames, same run. Each round is one process per side (``--mesa-rounds``);
the figure is the median over rounds of each process's median CPU ms per frame.

Passes (``--no-passes`` skips it): where a frame of the default look goes (640×360, no
MSAA, labels included), pass by pass (``Renderer.pass_times``: each pass ends with
``ctx.finish()``, so llvmpipe's deferred rasterization counts toward the pass that
queued it; the fences add a little, so the passes sum to slightly more than the
unfenced frame).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def scene_vehicles(n: int, rng: np.random.Generator):
    """``n`` vehicles on the straight town's four lanes, 8–90 m ahead of a camera at x=-95."""
    from dashtraj.render.synthetic import BIKE, BUS, MOTO, SEDAN, SUV, TRUCK, VAN, identity

    models = [SEDAN, SEDAN, SUV, SUV, VAN, TRUCK, BUS, MOTO, BIKE, SEDAN]
    lanes = [(-5.25, 180.0), (-1.75, 180.0), (1.75, 0.0), (5.25, 0.0)]
    out = []
    for i in range(n):
        y, yaw = lanes[i % 4]
        x = -87.0 + 82.0 * (i // 4) / max(1, (n - 1) // 4) + rng.uniform(-2, 2)
        rgb = tuple(int(c) for c in rng.integers(20, 235, 3))
        out.append(
            (
                i + 1,
                identity(models[i % len(models)], rgb, i + 1),
                x,
                y,
                0.0,
                yaw + rng.uniform(-8, 8),
            )
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--vehicles", type=int, default=20)
    ap.add_argument("--threads", type=int, default=0, help="llvmpipe threads (0 = one core)")
    ap.add_argument("--msaa", type=int, nargs="+", default=[4, 0])
    ap.add_argument("--no-depth", action="store_true", help="render(..., depth=False)")
    ap.add_argument("--no-effects", action="store_true", help="skip the per-effect costs")
    ap.add_argument("--no-geometry", action="store_true",
                    help="skip the cost of the clutter and the contact shadows")
    ap.add_argument("--no-passes", action="store_true", help="skip the per-pass costs")
    ap.add_argument("--no-mesa", action="store_true",
                    help="skip the private Mesa vs the system's Mesa comparison")
    ap.add_argument("--mesa-rounds", type=int, default=6)
    ap.add_argument("--time-only", action="store_true",
                    help="print one JSON line: median CPU ms of the default look at 640x360, "
                         "no MSAA (the Mesa comparison's child processes)")
    ap.add_argument("--json", type=Path, help="write the results here")
    args = ap.parse_args(argv)
    os.environ["LP_NUM_THREADS"] = str(args.threads)
    if args.time_only:
        return time_only(args.frames, args.vehicles, args.threads)

    from dashtraj.render.gl import context_info, create_context
    from dashtraj.render.scene import Renderer
    from dashtraj.render.synthetic import STRAIGHT_XODR
    from dashtraj.roads import RoadMap

    ctx = create_context(args.threads)
    m = RoadMap.from_string(STRAIGHT_XODR, name="straight")
    vehicles = scene_vehicles(args.vehicles, np.random.default_rng(0))
    results = {
        "gl": context_info(ctx),
        "threads": args.threads,
        "vehicles": args.vehicles,
        "depth": not args.no_depth,
        "runs": [],
    }
    for msaa in args.msaa:
        for w, h in ((640, 360), (1280, 720)):
            r = Renderer(m, w, h, 90.0, msaa=msaa, ctx=ctx)
            f = r.render((-95.0, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)  # warm up
            n_view = sum(lb.in_view for lb in f.labels)
            times, cpu = [], []
            for i in range(args.frames):
                pose = (-95.0 + 0.05 * i, 1.75, 1.6, 0.0, 0.0, 0.0)
                t, c = time.perf_counter(), time.process_time()
                r.render(pose, vehicles, depth=not args.no_depth)
                times.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
            r.release()
            t_med, c_med = float(np.median(times)), float(np.median(cpu))
            run = {
                "size": f"{w}x{h}",
                "msaa": msaa,
                "fps_cpu": 1.0 / c_med,
                "cpu_ms_median": 1e3 * c_med,
                "fps_wall": 1.0 / t_med,
                "ms_median": 1e3 * t_med,
                "ms_p90": 1e3 * float(np.percentile(times, 90)),
                "vehicles_in_view": n_view,
            }
            results["runs"].append(run)
            # with --threads 0 all rasterization runs on this thread, so CPU time per
            # frame is the one-core cost even while other processes share the machine
            print(
                f"{w}x{h} msaa {msaa}: CPU {1e3 * c_med:6.2f} ms/frame = {1.0 / c_med:6.1f} fps "
                f"(one core); wall {1.0 / t_med:6.1f} fps (median {1e3 * t_med:.2f} ms, "
                f"p90 {run['ms_p90']:.2f} ms); {n_view}/{args.vehicles} vehicles visible, "
                f"llvmpipe threads {args.threads}"
            )
    if not args.no_mesa:
        results["mesa"] = mesa_costs(args.mesa_rounds, args.frames, args.threads)
    if not args.no_passes:
        results["passes"] = pass_costs(ctx, m, vehicles, args.frames)
    if not args.no_effects:
        results["effects"] = effect_costs(ctx, m, vehicles)
    if not args.no_geometry:
        results["geometry"] = geometry_costs(ctx, m, vehicles)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


def time_only(frames: int, n_vehicles: int, threads: int) -> int:
    """Print {"gl": ..., "cpu_ms_median": ...} of the default look, 640x360, no MSAA."""
    from dashtraj.render.gl import context_info, create_context
    from dashtraj.render.scene import Renderer
    from dashtraj.render.synthetic import STRAIGHT_XODR
    from dashtraj.roads import RoadMap

    ctx = create_context(threads)
    m = RoadMap.from_string(STRAIGHT_XODR, name="straight")
    vehicles = scene_vehicles(n_vehicles, np.random.default_rng(0))
    r = Renderer(m, 640, 360, 90.0, msaa=0, ctx=ctx)
    r.render((-95.0, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)  # warm up
    cpu = []
    for i in range(frames):
        c = time.process_time()
        r.render((-95.0 + 0.05 * i, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)
        cpu.append(time.process_time() - c)
    print(json.dumps({"gl": context_info(ctx)["GL_VERSION"],
                      "cpu_ms_median": 1e3 * float(np.median(cpu))}))
    return 0


def mesa_costs(rounds: int, frames: int, threads: int) -> dict | None:
    """The private Mesa against the system's, in alternating child processes (module
    docstring); None when no private Mesa is installed."""
    from dashtraj.render.gl import private_mesa_dir

    d = private_mesa_dir()
    if d is None:
        print("mesa: no private Mesa (scripts/fetch_mesa.sh) in use; comparison skipped")
        return None
    sides = {"private": str(d), "system": "system"}
    runs = {k: [] for k in sides}
    gl = {}
    for _ in range(rounds):
        for k, value in sides.items():
            env = {**os.environ, "DASHTRAJ_MESA": value}
            env.pop("__EGL_VENDOR_LIBRARY_FILENAMES", None)
            proc = subprocess.run([sys.executable, __file__, "--time-only", "--frames",
                                   str(frames), "--threads", str(threads)], env=env,
                                  capture_output=True, text=True)
            lines = proc.stdout.strip().splitlines()
            if proc.returncode != 0 or not lines:
                why = (proc.stderr.strip().splitlines() or ["no output"])[-1]
                print(f"mesa: the {k} Mesa's child process failed (exit {proc.returncode}: "
                      f"{why}); comparison skipped")
                return None
            row = json.loads(lines[-1])
            gl[k] = row["gl"]
            runs[k].append(row["cpu_ms_median"])
    med = {k: float(np.median(v)) for k, v in runs.items()}
    ratio = med["system"] / med["private"]
    print(f"mesa, 640x360, no MSAA, default look, labels included (CPU ms/frame, one core; "
          f"{rounds} alternating processes each):")
    for k in sides:
        print(f"  {k:8s} {gl[k]:40s} {med[k]:6.2f} ms = {1e3 / med[k]:6.1f} fps  "
              f"(rounds: {', '.join(f'{x:.2f}' for x in runs[k])})")
    print(f"  the private Mesa is {ratio:.2f}x the system's speed")
    return {"gl": gl, "cpu_ms_median": med, "rounds": runs, "speedup_vs_system": ratio}


def pass_costs(ctx, road_map, vehicles, frames: int = 60) -> list[dict]:
    """CPU ms per frame of each pass (``Renderer.pass_times``) of the default look at
    640x360 without MSAA, labels included; prints the table."""
    from dashtraj.render.scene import Renderer

    r = Renderer(road_map, 640, 360, 90.0, msaa=0, ctx=ctx)
    r.render((-95.0, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)  # warm up
    r.pass_times = {}
    c = time.process_time()
    for i in range(frames):
        r.render((-95.0 + 0.05 * i, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)
    total = 1e3 * (time.process_time() - c) / frames
    times, r.pass_times = r.pass_times, None
    r.release()
    out = []
    print("pass costs, 640x360, no MSAA, default look, labels included "
          f"(CPU ms/frame, one core, fenced: {total:.2f} ms/frame in all):")
    for name, sec in sorted(times.items(), key=lambda kv: -kv[1]):
        ms = 1e3 * sec / frames
        out.append({"pass": name, "cpu_ms": ms, "share": ms / total})
        print(f"  {name:44s} {ms:6.2f} ms  {100 * ms / total:5.1f} %")
    return out


def effect_looks():
    """(name, look or "randomized") rows of the effect table."""
    from dataclasses import replace

    from dashtraj.render.look import LookConfig, preset, with_weather

    d = LookConfig()
    cam, mat = d.camera, d.materials
    return [
        ("flat (peer: before)", preset("flat")),
        ("default (clear)", d),
        ("- shadows", replace(d, materials=replace(mat, shadows=False))),
        ("- textures/windows", replace(d, materials=replace(mat, textures=False))),
        ("- sensor noise", replace(d, camera=replace(cam, noise_stddev=0.0))),
        ("- vignetting", replace(d, camera=replace(cam, lens_circle_multiplier=0.0))),
        ("+ clouds 60", with_weather(d, cloudiness=60.0)),
        ("+ fog 40", with_weather(d, fog_density=40.0)),
        ("+ wet road, puddles", with_weather(d, wetness=80.0, precipitation_deposits=60.0)),
        ("+ rain streaks 60", with_weather(d, precipitation=60.0)),
        ("+ blur 1 px", replace(d, camera=replace(cam, blur_radius=1.0))),
        ("+ JPEG q60", replace(d, camera=replace(cam, jpeg_quality=60))),
        ("randomized (per frame)", "randomized"),
    ]


def effect_costs(ctx, road_map, vehicles, rounds: int = 10, per_round: int = 5) -> list[dict]:
    """Median CPU ms per frame of each effect row (module docstring); prints the table."""
    from dashtraj.render.randomize import frame_rng, random_look
    from dashtraj.render.scene import Renderer

    r = Renderer(road_map, 640, 360, 90.0, msaa=0, ctx=ctx)
    rows = effect_looks()
    rand = [random_look(frame_rng(0, i)) for i in range(rounds * per_round)]
    for _, look in rows:  # warm up: compile every shader variant used below
        for lk in rand if look == "randomized" else [look]:
            r.set_look(lk)
            r.render((-95.0, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)
    cpu = {name: [] for name, _ in rows}
    for k in range(rounds):
        for name, look in rows:
            for i in range(per_round):
                r.set_look(rand[k * per_round + i] if look == "randomized" else look)
                pose = (-95.0 + 0.05 * i, 1.75, 1.6, 0.0, 0.0, 0.0)
                c = time.process_time()
                r.render(pose, vehicles)
                cpu[name].append(time.process_time() - c)
    r.release()
    med = {name: 1e3 * float(np.median(v)) for name, v in cpu.items()}
    flat, default = med[rows[0][0]], med[rows[1][0]]
    out = []
    print("effect costs, 640x360, no MSAA, labels included (CPU ms/frame, one core):")
    for name, _ in rows:
        row = {"effect": name, "cpu_ms_median": med[name], "fps_cpu": 1e3 / med[name],
               "delta_vs_default_ms": med[name] - default, "ratio_vs_flat": med[name] / flat}
        out.append(row)
        print(f"  {name:24s} {med[name]:6.2f} ms = {1e3 / med[name]:6.1f} fps  "
              f"({med[name] - default:+6.2f} ms vs default, {med[name] / flat:4.2f}x flat)")
    return out


def geometry_costs(ctx, road_map, vehicles, rounds: int = 10, per_round: int = 5) -> list[dict]:
    """Median CPU ms per frame (640x360, no MSAA, labels, default look) with and without
    the street clutter (``Renderer(clutter=False)``) and the contact shadows under the
    vehicles, on the bench's straight street and, when the CARLA maps are beside the
    checkout, on Town01 (more clutter in view: a junction ahead); rows interleaved."""
    from dashtraj.render.scene import Renderer

    scenes = [("straight", road_map, (-95.0, 1.75, 1.6, 0.0, 0.0, 0.0), vehicles)]
    town = Path(__file__).resolve().parents[2] / "shared" / "maps" / "carla" / "Town01.xodr"
    if town.is_file():
        from dashtraj.roads import RoadMap

        t1 = RoadMap.from_string(town.read_text(), name="Town01")
        w = t1.generate_waypoints(40.0)[7]
        loc, yaw = w.transform.location, w.transform.rotation.yaw
        vs, nxt = [], w
        for i, (_, ident, *_rest) in enumerate(vehicles[:8]):
            nx = nxt.next(9.0)
            if not nx:
                break
            nxt = nx[0]
            lc = nxt.transform.location
            vs.append((i + 1, ident, lc.x, lc.y, lc.z, nxt.transform.rotation.yaw))
        scenes.append(("Town01", t1, (loc.x, loc.y, loc.z + 1.6, yaw, 0.0, 0.0), vs))
    out = []
    print("geometry costs, 640x360, no MSAA, labels included (CPU ms/frame, one core):")
    for name, m, pose, vs in scenes:
        rows = {"default": Renderer(m, 640, 360, 90.0, msaa=0, ctx=ctx),
                "- clutter": Renderer(m, 640, 360, 90.0, msaa=0, ctx=ctx, clutter=False)}
        rows["- contact shadows"] = rows["default"]
        cpu = {k: [] for k in rows}
        for r in set(rows.values()):
            r.render(pose, vs)
        for _ in range(rounds):
            for k, r in rows.items():
                r.contact_shadows = k != "- contact shadows"
                for i in range(per_round):
                    p = (pose[0] + 0.05 * i, *pose[1:])
                    c = time.process_time()
                    r.render(p, vs)
                    cpu[k].append(time.process_time() - c)
        for r in set(rows.values()):
            r.release()
        med = {k: 1e3 * float(np.median(v)) for k, v in cpu.items()}
        for k in rows:
            row = {"scene": name, "row": k, "cpu_ms_median": med[k], "fps_cpu": 1e3 / med[k],
                   "delta_vs_default_ms": med[k] - med["default"]}
            out.append(row)
            print(f"  {name:9s} {k:18s} {med[k]:6.2f} ms = {1e3 / med[k]:6.1f} fps  "
                  f"({med[k] - med['default']:+6.2f} ms vs default)")
    return out


if __name__ == "__main__":
    raise SystemExit(main())
