"""Before/after contact sheet of the renderer's vehicles and street clutter.

Renders the same street scenes (Town01 and Town10HD from ``../shared/maps/carla``, camera
1.6 m above a lane, vehicles of every class ahead and in the next lane; default look) with
an older checkout's ``src`` (``--before-src``, run in a subprocess) and with this one, and
writes one PNG: rows = scenes; columns = before | after | after with a randomized look |
(with ``--compare DIR``) the real frame whose coarse layout is nearest to *after*
(``dashtraj.datasets.look_sheet.layout_descriptor``; validation pictures, only looked at).

Usage:
    .venv/bin/python docs/make_render_sheet.py --before-src /tmp/main_src/src \\
        --compare ../shared/carla_frames -o docs/render_before_after.png
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

MAPS = Path(__file__).resolve().parents[2] / "shared" / "maps" / "carla"
SCENES = (("Town01", 3), ("Town01", 11), ("Town10HD", 5), ("Town10HD", 21))
PANEL = (320, 180)


def render_scenes(randomized: bool = False) -> list[np.ndarray]:
    """The scenes' frames (640×360 RGB) with the dashtraj importable here."""
    from dashtraj.render.gl import create_context
    from dashtraj.render.scene import Renderer
    from dashtraj.render.synthetic import BIKE, BUS, MOTO, SEDAN, SUV, TRUCK, VAN, identity
    from dashtraj.roads import RoadMap

    ctx = create_context(0)
    models = [SEDAN, SUV, TRUCK, SEDAN, VAN, MOTO, BUS, BIKE]
    out = []
    maps = {}
    for k, (town, pick) in enumerate(SCENES):
        if town not in maps:
            maps[town] = RoadMap.from_string((MAPS / f"{town}.xodr").read_text(), name=town)
        m = maps[town]
        r = Renderer(m, 640, 360, 90.0, msaa=0, ctx=ctx)
        if randomized:
            from dashtraj.render.randomize import frame_rng, random_look

            r.set_look(random_look(frame_rng(13, k)))
        wps = [w for w in m.generate_waypoints(30.0) if not w.is_junction]
        w = wps[(pick * 7919) % len(wps)]
        rng = np.random.default_rng(k)
        vs = []
        lanes = [(w, 1.0)]
        left = w.get_left_lane()
        if left is not None:
            same = (left.transform.rotation.yaw - w.transform.rotation.yaw + 540) % 360 - 180
            lanes.append((left, 1.0 if abs(same) < 90 else -1.0))
        for lane, sign in lanes:
            for d in (8.0, 17.0, 29.0):
                nx = lane.next(d) if sign > 0 else lane.previous(d)
                if not nx:
                    continue
                p = nx[0]
                loc = p.transform.location
                yaw = p.transform.rotation.yaw  # opposite lanes drive toward the camera
                model = models[len(vs) % len(models)]
                rgb = tuple(int(c) for c in rng.integers(20, 235, 3))
                vs.append((len(vs) + 1, identity(model, rgb, len(vs) + 1), loc.x, loc.y, loc.z,
                           yaw))
        loc = w.transform.location
        f = r.render((loc.x, loc.y, loc.z + 1.6, w.transform.rotation.yaw, -2.0, 0.0), vs)
        out.append(f.rgb)
        r.release()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before-src", type=Path, help="src/ folder of the older checkout")
    ap.add_argument("--compare", type=Path, help="folder of real reference frames")
    ap.add_argument("-o", "--output", type=Path, default=Path("docs/render_before_after.png"))
    ap.add_argument("--dump", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.dump:  # subprocess mode: render with whatever dashtraj is importable
        np.savez_compressed(args.dump, *render_scenes())
        return 0
    from PIL import Image, ImageDraw

    cols = []
    if args.before_src:
        with tempfile.TemporaryDirectory() as tmp:
            dump = Path(tmp) / "before.npz"
            env = dict(os.environ, PYTHONPATH=str(args.before_src))
            subprocess.run([sys.executable, __file__, "--dump", str(dump)], env=env, check=True)
            z = np.load(dump)
            cols.append(("before", [z[f"arr_{i}"] for i in range(len(SCENES))]))
    after = render_scenes()
    cols += [("after", after), ("after, randomized look", render_scenes(randomized=True))]
    refs = None
    if args.compare:
        from dashtraj.datasets.look_sheet import layout_descriptor, reference_images

        files = reference_images(args.compare)
        descs = np.stack([layout_descriptor(Image.open(p).convert("RGB")) for p in files])
        refs = []
        for img in after:
            d = layout_descriptor(Image.fromarray(img))
            refs.append(np.asarray(Image.open(files[int(np.argmin(((descs - d) ** 2).sum(1)))])
                                   .convert("RGB")))
        cols.append(("real CARLA frame (nearest layout)", refs))
    pw, ph = PANEL
    sheet = Image.new("RGB", (pw * len(cols), 20 + ph * len(SCENES)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for c, (title, imgs) in enumerate(cols):
        draw.text((c * pw + 6, 4), title, fill=(0, 0, 0))
        for r, img in enumerate(imgs):
            sheet.paste(Image.fromarray(img).resize(PANEL, Image.Resampling.BILINEAR),
                        (c * pw, 20 + r * ph))
    args.output.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.output)
    print(f"wrote {args.output}: {len(SCENES)} scenes x {len(cols)} columns")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
