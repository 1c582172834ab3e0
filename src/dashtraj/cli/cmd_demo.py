"""`dashtraj demo`: the main job on the built-in world, end to end."""

from __future__ import annotations

import json
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on a built-in town and score it")
    p.add_argument("--town", default="town10", help="built-in town name or .xodr path")
    p.add_argument("-o", "--output", default="runs/demo", help="output folder")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from dashtraj.cli.cmd_map import load
    from dashtraj.report.plots import draw_map, draw_path, new_figure, save

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    m = load(args.town)
    info = m.summary()
    x0, y0, x1, y1 = m.extent
    r = m.route((x0 + 0.1 * (x1 - x0), y0 + 0.1 * (y1 - y0)),
                (x0 + 0.9 * (x1 - x0), y0 + 0.9 * (y1 - y0)))
    fig, ax = new_figure(m)
    draw_map(ax, m)
    draw_path(ax, r.polyline, "#ffcc00", label=f"route {r.length_m:.0f} m")
    ax.legend(loc="upper right")
    png = save(fig, out / "route.png")
    summary = {**info, "route_length_m": r.length_m, "picture": str(png)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{info['map']}: {info['roads']} roads, {info['junctions']} junctions, "
              f"{info['driving_lanes']} driving lanes, {info['topology_pairs']} topology pairs")
        print(f"route across the town: {r.length_m:.1f} m → {png}")
    return 0
