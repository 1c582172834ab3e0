"""`dashtraj map info|route|plot`: look at and route on an OpenDRIVE map."""

from __future__ import annotations

import json

from dashtraj.cli._args import MAX_OFF_ROAD_M, non_negative_float, positive_float
from dashtraj.cli._args import xy as _xy
from dashtraj.outputs import add_output_args

_OFF_ROAD_HELP = (f"refuse a point farther than M metres from every driving lane "
                  f"(default {MAX_OFF_ROAD_M:g})")


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
    route.add_argument("--lane-change-cost", type=non_negative_float, default=15.0, metavar="M",
                       help="penalty of one lane change in metres (default 15)")
    route.add_argument("--turn-cost", type=non_negative_float, default=0.0, metavar="M",
                       help="metres of cost per radian of heading change: a preference for "
                            "fewer turns (default 0: the shortest route by length)")
    route.add_argument("--json", action="store_true", help="print JSON (with the polyline)")
    route.add_argument("-o", "--output", help="also write the route polyline as CSV (x,y)")
    route.add_argument("--max-off-road", type=positive_float, default=MAX_OFF_ROAD_M,
                       metavar="M", help=_OFF_ROAD_HELP)
    add_output_args(route)
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
    plot.add_argument("--max-off-road", type=positive_float, default=MAX_OFF_ROAD_M,
                      metavar="M", help=_OFF_ROAD_HELP)
    add_output_args(plot)
    plot.set_defaults(func=run_plot)


def load(map_arg: str):
    """A RoadMap from a path, or from a built-in town name when no such file exists
    (named ``town01`` etc., not by its cache file); reader warnings print as ``warning:``."""
    import warnings

    from dashtraj.cli._args import load_map

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        return load_map(map_arg, "map")


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
    from dashtraj.cli._args import check_near_road
    from dashtraj.outputs import atomic_output, check_output

    if args.output:
        check_output(args.output, overwrite=args.overwrite, kind="file")
    m = load(args.map)
    check_near_road(m, args.origin, "--from", args.max_off_road)
    check_near_road(m, args.destination, "--to", args.max_off_road)
    r = m.route(args.origin, args.destination, lane_change_cost_m=args.lane_change_cost,
                turn_cost_m_per_rad=args.turn_cost)
    if args.output:
        from dashtraj.trajectory import Trajectory
        from dashtraj.trajectory.io import write_trajectory

        with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
            write_trajectory(tmp, Trajectory(r.polyline))
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
    from dashtraj.cli._args import ArgumentError, check_near_road
    from dashtraj.outputs import atomic_output, check_output
    from dashtraj.report.plots import draw_map, draw_path, new_figure, save

    check_output(args.output, overwrite=args.overwrite, kind="file")
    if args.output.rsplit(".", 1)[-1].lower() not in ("png", "svg", "pdf", "jpg", "jpeg"):
        raise ArgumentError(f"-o {args.output}: name a .png, .svg, .pdf or .jpg file")
    if (args.route_from is None) != (args.route_to is None):
        raise ArgumentError("give both --route-from and --route-to, or neither")
    m = load(args.map)
    r = None
    if args.route_from is not None:
        check_near_road(m, args.route_from, "--route-from", args.max_off_road)
        check_near_road(m, args.route_to, "--route-to", args.max_off_road)
        r = m.route(args.route_from, args.route_to)
    fig, ax = new_figure(m)
    draw_map(ax, m, lane_ids=args.ids == "lanes", road_ids=args.ids == "roads")
    if r is not None:
        draw_path(ax, r.polyline, "#ffcc00", label=f"route {r.length_m:.0f} m")
        ax.legend(loc="upper right")
    ax.set_title(m.name)
    with atomic_output(args.output, overwrite=args.overwrite, kind="file") as tmp:
        save(fig, tmp)
    print(f"wrote {args.output}")
    return 0
