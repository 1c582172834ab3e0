"""Built-in towns: CARLA-like street networks generated as OpenDRIVE 1.4.

CARLA's own maps cannot be shipped, so dashtraj draws its own. A town is a small
street graph (:class:`TownSpec`): nodes in CARLA world coordinates (metres, x right,
y down on a top view), edges between them. A node with three or four streets is a
junction; a node with two perpendicular streets is a rounded corner (an arc). From
that graph :func:`build_town_map` makes real OpenDRIVE:

- every street between two junctions becomes a chain of roads (one per straight or
  corner piece) linked road-to-road, with driving lanes each way (right-hand
  traffic: negative lane ids drive along the reference line), a shoulder and a
  sidewalk on each side, and road marks;
- every junction gets, for every incoming arm and every allowed movement (straight,
  left, right; no U-turns), one connecting road with a single driving lane -1 whose
  centre runs exactly from the incoming lane's end to the outgoing lane's start
  (a line, or a quarter circle for turns). With two lanes each way the rightmost
  lane feeds right turns and straight on, the leftmost left turns and straight on;
  a turn may end in any lane of the road it enters (so traffic can reach every lane
  without lane changes, and the lane graph is strongly connected).

Geometry is written in OpenDRIVE's frame: a CARLA point (x, y) is (x, -y) there.

Example:
    >>> text = build_town("town01")
    >>> text.count("<junction ")
    12
"""

from __future__ import annotations

import hashlib
import itertools
import math
import os
from dataclasses import dataclass
from pathlib import Path

from dashtraj.cache import cache_root
from dashtraj.errors import DashtrajError, OpenDriveError
from dashtraj.world.xodr_writer import (
    Connection,
    Geometry,
    Junction,
    Lane,
    LaneSection,
    Link,
    OpenDriveMap,
    Road,
    RoadMark,
    write_xodr,
)

__all__ = [
    "TOWNS",
    "TownSpec",
    "UnknownTownError",
    "build_town",
    "build_town_map",
    "resolve_map",
    "town_path",
]

_EPS = 1e-9


class UnknownTownError(DashtrajError, ValueError):
    """A town name that is not in :data:`TOWNS`; the message lists the valid names."""


@dataclass(frozen=True)
class TownSpec:
    """The street graph and cross-section of one built-in town.

    nodes: (name, x, y) in CARLA world coordinates, metres, before ``offset_m``.
    edges: pairs of node names; every node needs two or more edges (no dead ends),
    two-edge nodes must be perpendicular corners. lanes_per_direction: driving lanes
    each way. Widths in metres. junction_half_size_m: distance from a junction's
    node to where its connecting roads begin. corner_radius_m: reference-line radius
    of rounded corners. offset_m: (dx, dy) added to every node, CARLA frame.
    """

    name: str
    title: str
    description: str
    nodes: tuple[tuple[str, float, float], ...]
    edges: tuple[tuple[str, str], ...]
    lanes_per_direction: int
    lane_width_m: float
    shoulder_width_m: float
    sidewalk_width_m: float
    junction_half_size_m: float
    corner_radius_m: float
    offset_m: tuple[float, float] = (0.0, 0.0)
    speed_kmh: float = 30.0


# CARLA Town01-like: ~392 x 328 m, one lane each way, 12 junctions (8 T, 4 four-way),
# an outer ring with rounded corners and one inner corner.
_TOWN01 = TownSpec(
    name="town01",
    title="dashtraj Town01",
    description="Small town, one lane each way, 12 junctions (8 T, 4 four-way), ~392 x 328 m",
    nodes=(
        ("K1", 0, 0), ("J1", 100, 0), ("J2", 200, 0), ("J3", 290, 0), ("K2", 392, 0),
        ("J6", 0, 130), ("J7", 100, 130), ("J8", 200, 130), ("J9", 290, 130),
        ("J10", 392, 130), ("K5", 200, 200), ("J11", 290, 200), ("J12", 392, 200),
        ("K4", 0, 328), ("J4", 100, 328), ("J5", 290, 328), ("K3", 392, 328),
    ),
    edges=(
        ("K1", "J1"), ("J1", "J2"), ("J2", "J3"), ("J3", "K2"),
        ("K2", "J10"), ("J10", "J12"), ("J12", "K3"),
        ("K3", "J5"), ("J5", "J4"), ("J4", "K4"),
        ("K4", "J6"), ("J6", "K1"),
        ("J1", "J7"), ("J7", "J4"),
        ("J3", "J9"), ("J9", "J11"), ("J11", "J5"),
        ("J2", "J8"), ("J8", "K5"),
        ("J6", "J7"), ("J7", "J8"), ("J8", "J9"), ("J9", "J10"),
        ("K5", "J11"), ("J11", "J12"),
    ),
    lanes_per_direction=1,
    lane_width_m=3.75,
    shoulder_width_m=0.5,
    sidewalk_width_m=2.5,
    junction_half_size_m=12.0,
    corner_radius_m=18.0,
    offset_m=(2.0, 2.0),  # every driving-lane centre at CARLA x, y >= 0
    speed_kmh=30.0,
)

# CARLA Town10-like: ~220 x 200 m, two lanes each way, a 3 x 3 grid of four-way
# junctions whose outer arms close in loops (U-turns around blocks and corner loops).
_TOWN10 = TownSpec(
    name="town10",
    title="dashtraj Town10",
    description="Urban centre, two lanes each way, 9 four-way junctions, ~220 x 200 m",
    nodes=(
        ("TL", 45, 45), ("TM", 110, 45), ("TR", 175, 45),
        ("ML", 45, 100), ("MM", 110, 100), ("MR", 175, 100),
        ("BL", 45, 155), ("BM", 110, 155), ("BR", 175, 155),
        # top U-loop TL -> TM
        ("Kt1", 45, 0), ("Kt2", 110, 0),
        # top-right corner loop TR -> TR
        ("Kr1", 175, 0), ("Kr2", 220, 0), ("Kr3", 220, 45),
        # right U-loop MR -> BR
        ("Ke1", 220, 100), ("Ke2", 220, 155),
        # bottom U-loop BR -> BM
        ("Kb1", 175, 200), ("Kb2", 110, 200),
        # bottom-left corner loop BL -> BL
        ("Kl1", 45, 200), ("Kl2", 0, 200), ("Kl3", 0, 155),
        # left U-loop ML -> TL
        ("Kw1", 0, 100), ("Kw2", 0, 45),
    ),
    edges=(
        ("TL", "TM"), ("TM", "TR"), ("ML", "MM"), ("MM", "MR"), ("BL", "BM"), ("BM", "BR"),
        ("TL", "ML"), ("ML", "BL"), ("TM", "MM"), ("MM", "BM"), ("TR", "MR"), ("MR", "BR"),
        ("TL", "Kt1"), ("Kt1", "Kt2"), ("Kt2", "TM"),
        ("TR", "Kr1"), ("Kr1", "Kr2"), ("Kr2", "Kr3"), ("Kr3", "TR"),
        ("MR", "Ke1"), ("Ke1", "Ke2"), ("Ke2", "BR"),
        ("BR", "Kb1"), ("Kb1", "Kb2"), ("Kb2", "BM"),
        ("BL", "Kl1"), ("Kl1", "Kl2"), ("Kl2", "Kl3"), ("Kl3", "BL"),
        ("ML", "Kw1"), ("Kw1", "Kw2"), ("Kw2", "TL"),
    ),
    lanes_per_direction=2,
    lane_width_m=3.5,
    shoulder_width_m=0.5,
    sidewalk_width_m=3.0,
    junction_half_size_m=14.0,
    corner_radius_m=15.0,
    offset_m=(6.0, 6.0),  # every driving-lane centre at CARLA x, y >= 0
    speed_kmh=30.0,
)

TOWNS: dict[str, TownSpec] = {"town01": _TOWN01, "town10": _TOWN10}
"""Registry of built-in towns by name."""


# --- small 2-D vector helpers (OpenDRIVE frame) --------------------------------------

Vec = tuple[float, float]


def _sub(a: Vec, b: Vec) -> Vec:
    return (a[0] - b[0], a[1] - b[1])


def _add(a: Vec, b: Vec, k: float = 1.0) -> Vec:
    return (a[0] + k * b[0], a[1] + k * b[1])


def _unit(v: Vec) -> Vec:
    n = math.hypot(v[0], v[1])
    return (v[0] / n, v[1] / n)


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1]


def _cross(a: Vec, b: Vec) -> float:
    return a[0] * b[1] - a[1] * b[0]


def _left(v: Vec) -> Vec:
    return (-v[1], v[0])


def _right(v: Vec) -> Vec:
    return (v[1], -v[0])


def _heading(v: Vec) -> float:
    return math.atan2(v[1], v[0])


# --- building --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Arm:
    """Where a street meets a junction: the road, which of its ends, and the
    direction pointing out of the junction along the street (unit, OpenDRIVE)."""

    road_id: int
    end: str  # "start" or "end" of road_id touches the junction
    direction: Vec


def _check_spec(spec: TownSpec) -> tuple[dict[str, Vec], dict[str, list[str]]]:
    pos: dict[str, Vec] = {}
    for name, x, y in spec.nodes:
        if name in pos:
            raise ValueError(f"town {spec.name}: duplicate node {name!r}")
        # CARLA (x, y) -> OpenDRIVE (x, -y)
        pos[name] = (float(x) + spec.offset_m[0], -(float(y) + spec.offset_m[1]))
    adj: dict[str, list[str]] = {name: [] for name in pos}
    seen: set[frozenset[str]] = set()
    for a, b in spec.edges:
        if a not in pos or b not in pos:
            raise ValueError(f"town {spec.name}: edge ({a}, {b}) names an unknown node")
        key = frozenset((a, b))
        if a == b or key in seen:
            raise ValueError(f"town {spec.name}: edge ({a}, {b}) is a loop or a duplicate")
        seen.add(key)
        adj[a].append(b)
        adj[b].append(a)
    for name, nbs in adj.items():
        if len(nbs) < 2:
            raise ValueError(f"town {spec.name}: node {name} is a dead end")
        if len(nbs) > 4:
            raise ValueError(f"town {spec.name}: node {name} has more than 4 streets")
        if len(nbs) == 2:
            u1 = _unit(_sub(pos[name], pos[nbs[0]]))
            u2 = _unit(_sub(pos[nbs[1]], pos[name]))
            if abs(_dot(u1, u2)) > 1e-9:
                raise ValueError(f"town {spec.name}: corner {name} is not a right angle")
    for name, nbs in adj.items():
        # a fixed arm order: counter-clockwise from east, OpenDRIVE frame
        nbs.sort(key=lambda nb, c=pos[name]: _heading(_sub(pos[nb], c)) % (2 * math.pi))
    return pos, adj


def _cross_section(spec: TownSpec, pred: bool, succ: bool) -> LaneSection:
    """Lanes of a street road; pred / succ: whether it links to a road on that side."""
    n = spec.lanes_per_direction

    def lane(lid: int, typ: str, width: float, mark: RoadMark | None) -> Lane:
        return Lane(id=lid, type=typ, width=width, road_mark=mark,
                    predecessor=lid if pred else None, successor=lid if succ else None)

    sides: dict[int, list[Lane]] = {1: [], -1: []}
    for sign in (1, -1):
        for k in range(1, n + 1):
            mark = RoadMark("solid" if k == n else "broken", "standard", 0.15)
            sides[sign].append(lane(sign * k, "driving", spec.lane_width_m, mark))
        sides[sign].append(lane(sign * (n + 1), "shoulder", spec.shoulder_width_m, None))
        sides[sign].append(lane(sign * (n + 2), "sidewalk", spec.sidewalk_width_m,
                                RoadMark("solid", "standard", 0.15)))
    center_mark = RoadMark("solid solid" if n > 1 else "solid", "yellow", 0.15)
    return LaneSection(s=0.0, left=tuple(sides[1]), right=tuple(sides[-1]),
                       center=Lane(id=0, type="none", road_mark=center_mark))


def _street_pieces(spec: TownSpec, pos: dict[str, Vec], path: list[str]) -> list[Geometry]:
    """Plan-view pieces (each with s = 0) of a street along ``path`` (junction, corners,
    junction): lines between corners and quarter arcs at corners."""
    R, rc = spec.junction_half_size_m, spec.corner_radius_m
    d0 = _unit(_sub(pos[path[1]], pos[path[0]]))
    point = _add(pos[path[0]], d0, R)
    direction = d0
    pieces: list[Geometry] = []

    def line_to(target: Vec) -> None:
        delta = _sub(target, point)
        length = _dot(delta, direction)
        if length < 0.5 or abs(_cross(direction, delta)) > 1e-6:
            raise ValueError(f"town {spec.name}: street {'-'.join(path)} is too short "
                             f"between its junctions and corners ({length:.2f} m)")
        pieces.append(Geometry(0.0, point[0], point[1], _heading(direction), length))

    for i in range(1, len(path) - 1):
        corner = pos[path[i]]
        out = _unit(_sub(pos[path[i + 1]], corner))
        line_to(_add(corner, direction, -rc))
        start = _add(corner, direction, -rc)
        turn = 1.0 if _cross(direction, out) > 0 else -1.0
        pieces.append(Geometry(0.0, start[0], start[1], _heading(direction),
                               rc * math.pi / 2, turn / rc))
        point, direction = _add(corner, out, rc), out
    line_to(_add(pos[path[-1]], direction, -R))
    return pieces


def _walk_streets(pos: dict[str, Vec], adj: dict[str, list[str]]) -> list[list[str]]:
    """Split the graph into junction-to-junction paths, deterministically."""
    junctions = [n for n in pos if len(adj[n]) >= 3]
    used: set[tuple[str, str]] = set()
    streets: list[list[str]] = []
    for j in junctions:
        for nb in adj[j]:
            if (j, nb) in used:
                continue
            path = [j, nb]
            while len(adj[path[-1]]) == 2:
                a, b = adj[path[-1]]
                path.append(b if a == path[-2] else a)
            for u, v in itertools.pairwise(path):
                used.add((u, v))
                used.add((v, u))
            streets.append(path)
    if not junctions:
        raise ValueError("a town needs at least one junction")
    return streets


def _movement(h: Vec, out: Vec) -> str | None:
    if _dot(h, out) > 0.5:
        return "straight"
    c = _cross(h, out)
    if c > 0.5:
        return "left"
    if c < -0.5:
        return "right"
    return None  # U-turn


def build_town_map(name: str) -> OpenDriveMap:
    """Build the OpenDRIVE records of built-in town ``name`` (see :data:`TOWNS`).

    Road ids: street roads first (0 ..), then junction ids, then connecting roads.
    Raises UnknownTownError for a name not in TOWNS.
    """
    spec = _get_spec(name)
    pos, adj = _check_spec(spec)
    n, w, R = spec.lanes_per_direction, spec.lane_width_m, spec.junction_half_size_m
    streets = _walk_streets(pos, adj)

    roads: list[Road] = []
    arms: dict[tuple[str, str], _Arm] = {}  # (junction, neighbour) -> arm
    street_pieces = [_street_pieces(spec, pos, path) for path in streets]
    junction_names = [j for j in pos if len(adj[j]) >= 3]
    n_street_roads = sum(len(p) for p in street_pieces)
    junction_id = {j: n_street_roads + i for i, j in enumerate(junction_names)}

    rid = 0
    for path, pieces in zip(streets, street_pieces, strict=True):
        first, last = rid, rid + len(pieces) - 1
        for i, g in enumerate(pieces):
            pred = (Link("junction", junction_id[path[0]]) if i == 0
                    else Link("road", rid - 1, "end"))
            succ = (Link("junction", junction_id[path[-1]]) if i == len(pieces) - 1
                    else Link("road", rid + 1, "start"))
            kind = "arc" if g.curvature else "line"
            roads.append(Road(
                id=rid, name=f"{path[0]}-{path[-1]} {kind} {i}", length=g.length,
                predecessor=pred, successor=succ, geometry=(g,),
                lane_sections=(_cross_section(spec, i > 0, i < len(pieces) - 1),),
                speed_kmh=spec.speed_kmh,
            ))
            rid += 1
        arms[(path[0], path[1])] = _Arm(first, "start", _unit(_sub(pos[path[1]],
                                                                     pos[path[0]])))
        arms[(path[-1], path[-2])] = _Arm(last, "end", _unit(_sub(pos[path[-2]],
                                                                   pos[path[-1]])))

    rid = n_street_roads + len(junction_names)
    junctions: list[Junction] = []
    for j in junction_names:
        centre = pos[j]
        connections: list[Connection] = []
        for a in adj[j]:
            arm_in = arms[(j, a)]
            h = (-arm_in.direction[0], -arm_in.direction[1])  # heading into the junction
            in_sign = -1 if arm_in.end == "end" else 1
            for b in adj[j]:
                arm_out = arms[(j, b)]
                move = _movement(h, arm_out.direction) if b != a else None
                if move is None:
                    continue
                out_sign = -1 if arm_out.end == "start" else 1
                if move == "straight":
                    pairs = [(k, k) for k in range(1, n + 1)]
                elif move == "right":  # from the rightmost lane, into any lane
                    pairs = [(n, k) for k in range(n, 0, -1)]
                else:  # from the leftmost lane, into any lane
                    pairs = [(1, k) for k in range(1, n + 1)]
                for k_in, k_out in pairs:
                    p_in = _add(_add(centre, arm_in.direction, R), _right(h), (k_in - 0.5) * w)
                    d_out = arm_out.direction
                    p_out = _add(_add(centre, d_out, R), _right(d_out), (k_out - 0.5) * w)
                    geoms = _connector(p_in, h, p_out, d_out, w, move, name=f"junction {j}")
                    in_id, out_id = in_sign * k_in, out_sign * k_out
                    lane = Lane(id=-1, type="driving", width=w, predecessor=in_id,
                                successor=out_id, road_mark=RoadMark("none", "standard", 0.0))
                    roads.append(Road(
                        id=rid, name=f"{j} {a}->{b} {move} lane {k_in}->{k_out}",
                        length=sum(g.length for g in geoms),
                        junction=junction_id[j],
                        predecessor=Link("road", arm_in.road_id, arm_in.end),
                        successor=Link("road", arm_out.road_id, arm_out.end),
                        geometry=geoms,
                        lane_sections=(LaneSection(s=0.0, right=(lane,), center=Lane(
                            id=0, type="none", road_mark=RoadMark("none", "standard", 0.0))),),
                        speed_kmh=spec.speed_kmh,
                    ))
                    connections.append(Connection(
                        id=len(connections), incoming_road=arm_in.road_id, connecting_road=rid,
                        contact_point="start", lane_links=((in_id, -1),)))
                    rid += 1
        junctions.append(Junction(id=junction_id[j], name=j, connections=tuple(connections)))
    return OpenDriveMap(name=spec.title, roads=tuple(roads), junctions=tuple(junctions))


def _connector(p_in: Vec, h: Vec, p_out: Vec, d_out: Vec, w: float, move: str,
               name: str) -> tuple[Geometry, ...]:
    """Reference line of a one-lane connecting road whose lane -1 centre runs from
    p_in (heading h) to p_out (heading d_out): the path shifted w/2 to the left.

    Straight on it is one line. A turn is a quarter circle, preceded by a line when
    it ends in a lane further out than it started, or followed by one when it ends
    in a lane further in (OpenDRIVE frame, metres, radians)."""
    delta = _sub(p_out, p_in)
    start = _add(p_in, _left(h), w / 2)
    if move == "straight":
        if abs(_cross(h, delta)) > 1e-6:
            raise ValueError(f"{name}: straight lanes do not line up")
        return (Geometry(0.0, start[0], start[1], _heading(h), _dot(h, delta)),)
    sign = 1.0 if move == "left" else -1.0
    forward = _dot(h, delta)
    lateral = sign * _dot(_left(h), delta)
    if abs(_dot(d_out, _left(h)) - sign) > 1e-9 or forward <= 0 or lateral <= 0:
        raise ValueError(f"{name}: a {move} turn does not fit a quarter circle")
    rho = min(forward, lateral)  # lane-centre radius of the quarter circle
    radius = rho - sign * w / 2  # reference line is w/2 to the left of the lane centre
    if radius <= _EPS:
        raise ValueError(f"{name}: junction too small for a {move} turn")
    pieces: list[Geometry] = []
    s, x, y, hdg = 0.0, start[0], start[1], _heading(h)
    for length, curvature in ((forward - rho, 0.0), (radius * math.pi / 2, sign / radius),
                              (lateral - rho, 0.0)):
        if length <= 1e-6:
            continue
        g = Geometry(s, x, y, hdg, length, curvature)
        pieces.append(g)
        x, y, hdg = g.end_pose()
        s += length
    return tuple(pieces)


def _get_spec(name: str) -> TownSpec:
    try:
        return TOWNS[name.lower()]
    except KeyError:
        raise UnknownTownError(
            f"unknown town {name!r}; valid names: {', '.join(sorted(TOWNS))}") from None


def build_town(name: str) -> str:
    """The OpenDRIVE 1.4 text of built-in town ``name`` (deterministic bytes).

    Raises UnknownTownError for a name not in TOWNS.
    """
    return write_xodr(build_town_map(name))


def _cache_root(cache_dir: str | os.PathLike[str] | None) -> Path:
    return Path(cache_dir) if cache_dir is not None else cache_root("towns")


def town_path(name: str, cache_dir: str | os.PathLike[str] | None = None) -> Path:
    """Path of town ``name`` written as .xodr in a cache folder, writing it once.

    The folder is ``cache_dir`` if given, else ``$DASHTRAJ_CACHE/towns``, else
    ``$XDG_CACHE_HOME/dashtraj/towns`` (when set to an absolute path), else
    ``~/.cache/dashtraj/towns``. The file is named ``<name>-<sha256[:16]>.xodr`` after
    its content, so a changed generator writes a new file; an existing identical file
    is never rewritten (the write is atomic via a temporary file and rename).
    """
    text = build_town(name).encode("utf-8")
    digest = hashlib.sha256(text).hexdigest()[:16]
    root = _cache_root(cache_dir)
    path = root / f"{name.lower()}-{digest}.xodr"
    if path.is_file() and path.read_bytes() == text:
        return path
    root.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(text)
    os.replace(tmp, path)
    return path


def resolve_map(source: str | os.PathLike[str]) -> Path:
    """The .xodr file a user named: a path as given, or a built-in town's file.

    A name ending in ``.xodr``, or one that exists on disk, is a path; anything
    else is a built-in town name (see `town_path`).

    Raises:
        OpenDriveError: the path does not name a file.
        UnknownTownError: not a path and not a town; the message lists the towns.
    """
    p = Path(source)
    if p.suffix.lower() == ".xodr" or p.exists():
        if not p.is_file():
            raise OpenDriveError(f"map file {p} does not exist" if not p.exists()
                                 else f"map {p} is a folder, not an .xodr file")
        return p
    return town_path(str(source))
