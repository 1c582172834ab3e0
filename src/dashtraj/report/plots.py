"""Top-view pictures of maps, routes and reconstructions (matplotlib, Agg).

Axes are CARLA world metres. CARLA's frame is left-handed (y points "down" when x
points right, seen from above), so the y axis is inverted: the picture looks like
CARLA's own top view.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dashtraj.roads import LaneType, RoadMap

_LANE_STYLE = {
    LaneType.Driving: ("#4a4a4a", 1.0),
    LaneType.Sidewalk: ("#c8c3b8", 0.9),
    LaneType.Shoulder: ("#8a8a80", 0.7),
    LaneType.Parking: ("#6d6d6d", 0.9),
    LaneType.Biking: ("#7a4f4f", 0.9),
}


def new_figure(road_map: RoadMap, size_in: float = 10.0):
    """A figure and axes sized to the map's aspect ratio (Agg backend)."""
    from matplotlib.figure import Figure

    x0, y0, x1, y1 = road_map.extent
    w, h = max(x1 - x0, 1.0), max(y1 - y0, 1.0)
    fig = Figure(figsize=(size_in, max(3.0, size_in * h / w)), dpi=120)
    ax = fig.add_subplot(1, 1, 1)
    ax.set_aspect("equal")
    ax.set_facecolor("#dfe8d8")
    ax.set_xlim(x0 - 10, x1 + 10)
    ax.set_ylim(y1 + 10, y0 - 10)  # CARLA's left-handed frame, seen from above
    ax.set_xlabel("x (m, CARLA)")
    ax.set_ylabel("y (m, CARLA)")
    return fig, ax


def draw_map(ax, road_map: RoadMap, lane_ids: bool = False, road_ids: bool = False) -> None:
    """Fill every lane as a polygon between its borders; optionally label ids."""
    from matplotlib.collections import PolyCollection

    polys: dict[LaneType, list[np.ndarray]] = {}
    for lane in road_map.lane_list:
        style = _LANE_STYLE.get(lane.type)
        if style is None or lane.v1 - lane.v0 < 2:
            continue
        left, right = road_map.lane_border_polylines(lane.key)
        polys.setdefault(lane.type, []).append(np.vstack([left, right[::-1]]))
    for lane_type, ps in polys.items():
        color, alpha = _LANE_STYLE[lane_type]
        ax.add_collection(PolyCollection(ps, facecolors=color, edgecolors=color,
                                         linewidths=0.2, alpha=alpha, zorder=1))
    if lane_ids or road_ids:
        done = set()
        for lane, pts in road_map.lane_centres(LaneType.Driving):
            mid = pts[len(pts) // 2]
            if lane_ids:
                ax.text(mid[0], mid[1], f"{lane.road_id}:{lane.lane_id}", fontsize=4,
                        ha="center", va="center", color="white", zorder=5)
            elif lane.road_id not in done:
                done.add(lane.road_id)
                ax.text(mid[0], mid[1], str(lane.road_id), fontsize=5, ha="center",
                        va="center", color="white", zorder=5)


def draw_path(ax, points: np.ndarray, color: str, label: str | None = None,
              width: float = 2.0, zorder: int = 6) -> None:
    """A polyline (N, 2), CARLA world metres."""
    pts = np.asarray(points, dtype=float)
    ax.plot(pts[:, 0], pts[:, 1], color=color, lw=width, label=label, zorder=zorder,
            solid_capstyle="round")


def draw_observers(ax, observers: list[tuple[int, float, float, float]],
                   color: str = "#1f5fbf") -> None:
    """Observers as arrows along their yaw with their ids: (id, x, y, yaw_deg)."""
    for oid, x, y, yaw in observers:
        dx, dy = 6.0 * np.cos(np.radians(yaw)), 6.0 * np.sin(np.radians(yaw))
        ax.annotate("", xy=(x + dx, y + dy), xytext=(x, y), zorder=8,
                    arrowprops={"arrowstyle": "-|>", "color": color, "lw": 1.8})
        ax.text(x, y - 4.0, str(oid), color=color, fontsize=7, ha="center", zorder=8,
                fontweight="bold")


def save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight", metadata={"Software": None})
    return path
