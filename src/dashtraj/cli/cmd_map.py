"""`dashtraj map info|route|plot`: look at and route on an OpenDRIVE map."""

from __future__ import annotations

import argparse
import json
import sys
import warnings


def _xy(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y in metres, got {text!r}") from None
    return x, y


def register(sub) -> None:
    p = sub.add_parser("map", help="inspect, route on and plot an OpenDRIVE map")
    msub = p.add_subparsers(dest="map_command", metavar="ACTION")
    msub.required = True

    info = msub.add_parser("info", help="roads, junctions, lanes, topology, extent")
    info.add_argument("map", help="OpenDRIVE .xodr file or built-in town name")
    info.add_argument("--json", action="store_true", help="print JSON")
    info.set_defaults(func=run_info)

    route = msub.add_parser("route", help="shortest route between two points (A*, metres)")
    route.add_argument("map", help="OpenDRIVE .xodr file or built-in town name")
    route.add_argument("--from", dest="origin", type=_xy, required=True, metavar="X,Y",
                       help="origin, CARLA world metres (--from=-4,20 for a negative x)")
    route.add_argument("--to", dest="destination", type=_xy, required=True, metavar="X,Y",
                       help="destination, CARLA world metres")
    route.add_argument("--lane-change-cost", type=float, default=15.0, metavar="M",
                       help="penalty of one lane change in metres (default 15)")
    route.add_argument("--json", action="store_true", help="print JSON (with the polyline)")
    route.add_argument("-o", "--output", help="also write the route polyline as CSV (x,y)")
    route.set_defaults(func=run_route)

    plot = msub.add_parser("plot", help="top view of the lanes as a PNG")
    plot.add_argument("map", help="OpenDRIVE .xodr file or built-in town name")
    plot.add_argument("-o", "--output", required=True, help="PNG path")
    plot.add_argument("--ids", choices=("none", "roads", "lanes"), default="none",
                      help="label road or lane ids")
    plot.add_argument("--route-from", type=_xy, metavar="X,Y",
                      help="also draw the route from this point (write --route-from=-4,20 "
                      "for a negative x)")
    plot.add_argument("--route-to", type=_xy, metavar="X,Y", help="… to this point")
    plot.set_defaults(func=run_plot)


def load(map_arg: str):
    """A RoadMap from a path, or from a built-in town name when no such file exists."""
    from dashtraj.roads import RoadMap
    from dashtraj.world.towns import resolve_map

    path = resolve_map(map_arg)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = RoadMap.from_file(path)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    return m


def run_info(args) -> int:
    m = load(args.map)
    info = m.summary()
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    e = info["extent"]
    print(f"{info['map']}")
    print(f"  roads           {info['roads']}")
    print(f"  junctions       {info['junctions']}")
    print(f"  lane sections   {info['lane_sections']}")
    print(f"  driving lanes   {info['driving_lanes']}")
    print(f"  topology pairs  {info['topology_pairs']}")
    print(f"  extent (CARLA)  x [{e['x_min']:.2f}, {e['x_max']:.2f}]  "
          f"y [{e['y_min']:.2f}, {e['y_max']:.2f}]  "
          f"({e['x_max'] - e['x_min']:.0f} × {e['y_max'] - e['y_min']:.0f} m)")
    return 0


def run_route(args) -> int:
    m = load(args.map)
    r = m.route(args.origin, args.destination, lane_change_cost_m=args.lane_change_cost)
    if args.output:
        from dashtraj.trajectory import Trajectory
        from dashtraj.trajectory.io import write_trajectory

        write_trajectory(args.output, Trajectory(r.polyline))
    if args.json:
        print(json.dumps({
            "length_m": r.length_m,
            "cost_m": r.cost_m,
            "lane_changes": r.lane_changes,
            "legs": [{"road_id": lg.key[0], "section_id": lg.key[1], "lane_id": lg.key[2],
                      "s_from": lg.s_from, "s_to": lg.s_to, "lane_change": lg.lane_change}
                     for lg in r.legs],
            "polyline": r.polyline.round(3).tolist(),
        }))
        return 0
    roads = []
    for lg in r.legs:
        if not roads or roads[-1] != lg.key[0]:
            roads.append(lg.key[0])
    print(f"route {r.length_m:.1f} m (cost {r.cost_m:.1f} m), {len(r.legs)} lane legs, "
          f"{r.lane_changes} lane changes")
    print("  roads: " + " → ".join(str(x) for x in roads))
    return 0


def run_plot(args) -> int:
    from dashtraj.report.plots import draw_map, draw_path, new_figure, save

    m = load(args.map)
    fig, ax = new_figure(m)
    draw_map(ax, m, lane_ids=args.ids == "lanes", road_ids=args.ids == "roads")
    if (args.route_from is None) != (args.route_to is None):
        raise SystemExit("dashtraj map plot: give both --route-from and --route-to")
    if args.route_from is not None:
        r = m.route(args.route_from, args.route_to)
        draw_path(ax, r.polyline, "#ffcc00", label=f"route {r.length_m:.0f} m")
        ax.legend(loc="upper right")
    ax.set_title(m.name)
    out = save(fig, args.output)
    print(f"wrote {out}")
    return 0
