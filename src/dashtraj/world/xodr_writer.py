"""A small OpenDRIVE 1.4 writer: typed records in, deterministic .xodr text out.

The records mirror the OpenDRIVE elements dashtraj's towns need and nothing more:
roads with `line` / `arc` plan-view geometries, a flat elevation profile, a lane
offset, lane sections with left / center / right lanes (type, links, cubic width,
road mark), and junctions with connections and lane links.

All coordinates are OpenDRIVE's own (metres, right-handed, x east, y north, heading
in radians counter-clockwise from +x). CARLA reads a point (x, y) as (x, -y).

The output is byte-for-byte deterministic: elements and attributes are written in a
fixed order and every float goes through :func:`format_float`.

Example:
    >>> road = Road(id=0, name="r0", length=10.0, junction=-1,
    ...             geometry=(Geometry(s=0.0, x=0.0, y=0.0, hdg=0.0, length=10.0),),
    ...             lane_sections=(LaneSection(s=0.0, left=(), right=(
    ...                 Lane(id=-1, type="driving", width=3.5),)),))
    >>> text = write_xodr(OpenDriveMap(name="tiny", roads=(road,)))
    >>> text.splitlines()[1]
    '<OpenDRIVE>'
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

__all__ = [
    "Connection",
    "Geometry",
    "Junction",
    "Lane",
    "LaneSection",
    "Link",
    "OpenDriveMap",
    "Road",
    "RoadMark",
    "format_float",
    "write_xodr",
]

LANE_TYPES = frozenset({"driving", "sidewalk", "shoulder", "border", "none"})
CONTACT_POINTS = frozenset({"start", "end"})


def format_float(value: float) -> str:
    """Format a float the one way the writer ever does: 10 decimals, trailing zeros cut.

    ``-0`` is written as ``0``; 1e-10 m is far below any tolerance a map needs.
    """
    if not math.isfinite(value):
        raise ValueError(f"cannot write non-finite number {value!r} to OpenDRIVE")
    text = f"{value:.10f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


@dataclass(frozen=True)
class Geometry:
    """One plan-view record: a `line` (curvature 0) or an `arc` (curvature != 0).

    s: start along the road's reference line, metres. x, y: start point, OpenDRIVE
    frame, metres. hdg: start heading, radians. length: metres. curvature: 1/metres,
    positive turns left (counter-clockwise).
    """

    s: float
    x: float
    y: float
    hdg: float
    length: float
    curvature: float = 0.0

    def end_pose(self) -> tuple[float, float, float]:
        """(x, y, hdg) at the end of this geometry; OpenDRIVE frame, metres, radians."""
        return self.pose_at(self.length)

    def pose_at(self, ds: float) -> tuple[float, float, float]:
        """(x, y, hdg) at ``ds`` metres from this geometry's start; OpenDRIVE frame."""
        k = self.curvature
        if k == 0.0:
            return (
                self.x + ds * math.cos(self.hdg),
                self.y + ds * math.sin(self.hdg),
                self.hdg,
            )
        hdg = self.hdg + k * ds
        return (
            self.x + (math.sin(hdg) - math.sin(self.hdg)) / k,
            self.y - (math.cos(hdg) - math.cos(self.hdg)) / k,
            hdg,
        )


@dataclass(frozen=True)
class RoadMark:
    """The marking on a lane's outer border: type solid / broken / none, colour
    standard (white) / white / yellow, width in metres."""

    type: str = "solid"
    color: str = "standard"
    width: float = 0.15


@dataclass(frozen=True)
class Lane:
    """One lane of a lane section.

    id: signed OpenDRIVE lane id (0 is the center lane). type: driving, sidewalk,
    shoulder, border or none. width: constant width in metres, or the cubic
    (a, b, c, d) of ``<width sOffset="0">``. predecessor / successor: lane ids in the
    linked road (or None).
    """

    id: int
    type: str = "driving"
    width: float | tuple[float, float, float, float] = 0.0
    predecessor: int | None = None
    successor: int | None = None
    road_mark: RoadMark | None = None

    def __post_init__(self) -> None:
        if self.type not in LANE_TYPES:
            raise ValueError(f"lane {self.id}: unknown lane type {self.type!r}; "
                             f"valid: {sorted(LANE_TYPES)}")

    @property
    def width_poly(self) -> tuple[float, float, float, float]:
        """The width cubic (a, b, c, d) in metres, ds measured from the section start."""
        if isinstance(self.width, tuple):
            return self.width
        return (float(self.width), 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class LaneSection:
    """A lane section starting at ``s`` metres. ``left`` lanes have ids > 0, ``right``
    lanes ids < 0, listed in any order (written outermost-left first as OpenDRIVE
    tools do). ``center`` is lane 0 and carries the centre-line marking."""

    s: float
    left: tuple[Lane, ...] = ()
    right: tuple[Lane, ...] = ()
    center: Lane = field(default_factory=lambda: Lane(id=0, type="none"))

    def __post_init__(self) -> None:
        if any(lane.id <= 0 for lane in self.left):
            raise ValueError(f"laneSection s={self.s}: left lanes need ids > 0")
        if any(lane.id >= 0 for lane in self.right):
            raise ValueError(f"laneSection s={self.s}: right lanes need ids < 0")
        if self.center.id != 0:
            raise ValueError(f"laneSection s={self.s}: center lane must have id 0")


@dataclass(frozen=True)
class Link:
    """A road's predecessor or successor: element_type "road" or "junction",
    element_id, and contact_point ("start"/"end", roads only)."""

    element_type: str
    element_id: int
    contact_point: str | None = None

    def __post_init__(self) -> None:
        if self.element_type not in ("road", "junction"):
            raise ValueError(f"link elementType must be road or junction, "
                             f"not {self.element_type!r}")
        if self.element_type == "road" and self.contact_point not in CONTACT_POINTS:
            raise ValueError(f"link to road {self.element_id} needs contactPoint "
                             f"start or end, not {self.contact_point!r}")


@dataclass(frozen=True)
class Road:
    """An OpenDRIVE ``<road>``. length in metres; junction is -1 outside junctions.
    lane_offset is the constant ``<laneOffset a>`` in metres (positive shifts lanes
    to the left of the reference line)."""

    id: int
    name: str
    length: float
    junction: int = -1
    predecessor: Link | None = None
    successor: Link | None = None
    geometry: tuple[Geometry, ...] = ()
    lane_sections: tuple[LaneSection, ...] = ()
    lane_offset: float = 0.0
    speed_kmh: float | None = None


@dataclass(frozen=True)
class Connection:
    """A junction ``<connection>``: traffic from incoming_road enters connecting_road
    at its contact_point end; lane_links are (from lane id, to lane id) pairs."""

    id: int
    incoming_road: int
    connecting_road: int
    contact_point: str
    lane_links: tuple[tuple[int, int], ...]


@dataclass(frozen=True)
class Junction:
    """An OpenDRIVE ``<junction>`` with its connections."""

    id: int
    name: str
    connections: tuple[Connection, ...]


@dataclass(frozen=True)
class OpenDriveMap:
    """A whole map: header name, roads and junctions (written in the given order)."""

    name: str
    roads: tuple[Road, ...]
    junctions: tuple[Junction, ...] = ()

    def bounds(self) -> tuple[float, float, float, float]:
        """(north, south, east, west) of the plan-view geometry, OpenDRIVE frame,
        metres; arcs are sampled every metre, so bounds are tight to ~1 cm."""
        xs: list[float] = []
        ys: list[float] = []
        for road in self.roads:
            for g in road.geometry:
                n = max(1, math.ceil(g.length))
                for i in range(n + 1):
                    x, y, _ = g.pose_at(g.length * i / n)
                    xs.append(x)
                    ys.append(y)
        if not xs:
            return (0.0, 0.0, 0.0, 0.0)
        return (max(ys), min(ys), max(xs), min(xs))


def _attrs(pairs: list[tuple[str, object]]) -> str:
    out = []
    for key, value in pairs:
        if value is None:
            continue
        if isinstance(value, bool):
            text = "true" if value else "false"
        elif isinstance(value, float):
            text = format_float(value)
        else:
            text = str(value)
        out.append(f"{key}={quoteattr(text)}")
    return " ".join(out)


def _tag(name: str, pairs: list[tuple[str, object]], close: bool = True) -> str:
    attrs = _attrs(pairs)
    body = f"{name} {attrs}" if attrs else name
    return f"<{body}/>" if close else f"<{body}>"


def _lane_lines(lane: Lane, indent: str) -> list[str]:
    lines = [indent + _tag("lane", [("id", lane.id), ("type", lane.type),
                                    ("level", False)], close=False)]
    inner = indent + "    "
    if lane.predecessor is None and lane.successor is None:
        lines.append(inner + "<link/>")
    else:
        lines.append(inner + "<link>")
        if lane.predecessor is not None:
            lines.append(inner + "    " + _tag("predecessor", [("id", lane.predecessor)]))
        if lane.successor is not None:
            lines.append(inner + "    " + _tag("successor", [("id", lane.successor)]))
        lines.append(inner + "</link>")
    if lane.id != 0:
        a, b, c, d = (float(v) for v in lane.width_poly)
        lines.append(inner + _tag("width", [("sOffset", 0.0), ("a", a), ("b", b),
                                            ("c", c), ("d", d)]))
    mark = lane.road_mark or RoadMark(type="none", width=0.0)
    lines.append(inner + _tag("roadMark", [
        ("sOffset", 0.0), ("type", mark.type), ("weight", "standard"),
        ("color", mark.color), ("material", "standard"), ("width", float(mark.width)),
        ("laneChange", "none" if mark.type in ("solid", "solid solid") else "both"),
    ]))
    lines.append(indent + "</lane>")
    return lines


def _link_tag(kind: str, link: Link) -> str:
    return _tag(kind, [("elementType", link.element_type), ("elementId", link.element_id),
                       ("contactPoint", link.contact_point)])


def _road_lines(road: Road) -> list[str]:
    i1, i2, i3, i4, i5 = ("    " * k for k in range(1, 6))
    lines = [i1 + _tag("road", [("name", road.name), ("length", float(road.length)),
                                ("id", road.id), ("junction", road.junction)], close=False)]
    if road.predecessor is None and road.successor is None:
        lines.append(i2 + "<link/>")
    else:
        lines.append(i2 + "<link>")
        if road.predecessor is not None:
            lines.append(i3 + _link_tag("predecessor", road.predecessor))
        if road.successor is not None:
            lines.append(i3 + _link_tag("successor", road.successor))
        lines.append(i2 + "</link>")
    if road.speed_kmh is not None:
        lines.append(i2 + _tag("type", [("s", 0.0), ("type", "town")], close=False))
        lines.append(i3 + _tag("speed", [("max", float(road.speed_kmh)), ("unit", "km/h")]))
        lines.append(i2 + "</type>")
    lines.append(i2 + "<planView>")
    for g in road.geometry:
        lines.append(i3 + _tag("geometry", [("s", float(g.s)), ("x", float(g.x)),
                                            ("y", float(g.y)), ("hdg", float(g.hdg)),
                                            ("length", float(g.length))], close=False))
        if g.curvature == 0.0:
            lines.append(i4 + "<line/>")
        else:
            lines.append(i4 + _tag("arc", [("curvature", float(g.curvature))]))
        lines.append(i3 + "</geometry>")
    lines.append(i2 + "</planView>")
    lines.append(i2 + "<elevationProfile>")
    lines.append(i3 + _tag("elevation", [("s", 0.0), ("a", 0.0), ("b", 0.0), ("c", 0.0),
                                         ("d", 0.0)]))
    lines.append(i2 + "</elevationProfile>")
    lines.append(i2 + "<lateralProfile/>")
    lines.append(i2 + "<lanes>")
    lines.append(i3 + _tag("laneOffset", [("s", 0.0), ("a", float(road.lane_offset)),
                                          ("b", 0.0), ("c", 0.0), ("d", 0.0)]))
    for section in road.lane_sections:
        lines.append(i3 + _tag("laneSection", [("s", float(section.s))], close=False))
        if section.left:
            lines.append(i4 + "<left>")
            for lane in sorted(section.left, key=lambda ln: -ln.id):
                lines.extend(_lane_lines(lane, i5))
            lines.append(i4 + "</left>")
        lines.append(i4 + "<center>")
        lines.extend(_lane_lines(section.center, i5))
        lines.append(i4 + "</center>")
        if section.right:
            lines.append(i4 + "<right>")
            for lane in sorted(section.right, key=lambda ln: -ln.id):
                lines.extend(_lane_lines(lane, i5))
            lines.append(i4 + "</right>")
        lines.append(i3 + "</laneSection>")
    lines.append(i2 + "</lanes>")
    lines.append(i1 + "</road>")
    return lines


def _junction_lines(junction: Junction) -> list[str]:
    i1, i2, i3 = ("    " * k for k in range(1, 4))
    lines = [i1 + _tag("junction", [("id", junction.id), ("name", junction.name)],
                       close=False)]
    for c in junction.connections:
        lines.append(i2 + _tag("connection", [
            ("id", c.id), ("incomingRoad", c.incoming_road),
            ("connectingRoad", c.connecting_road), ("contactPoint", c.contact_point),
        ], close=False))
        for src, dst in c.lane_links:
            lines.append(i3 + _tag("laneLink", [("from", src), ("to", dst)]))
        lines.append(i2 + "</connection>")
    lines.append(i1 + "</junction>")
    return lines


def write_xodr(odr: OpenDriveMap) -> str:
    """Serialize a map to OpenDRIVE 1.4 text (UTF-8 declaration, 4-space indent, "\\n").

    Raises ValueError on duplicate road or junction ids.
    """
    road_ids = [r.id for r in odr.roads]
    if len(set(road_ids)) != len(road_ids):
        raise ValueError(f"map {odr.name!r}: duplicate road ids")
    junction_ids = [j.id for j in odr.junctions]
    if len(set(junction_ids)) != len(junction_ids):
        raise ValueError(f"map {odr.name!r}: duplicate junction ids")
    north, south, east, west = odr.bounds()
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<OpenDRIVE>"]
    lines.append("    " + _tag("header", [
        ("revMajor", 1), ("revMinor", 4), ("name", odr.name), ("version", "1"),
        ("north", north), ("south", south), ("east", east), ("west", west),
        ("vendor", "dashtraj"),
    ], close=False))
    lines.append("        <geoReference><![CDATA[+proj=tmerc +lat_0=0 +lon_0=0 +k=1 "
                 "+x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs ]]></geoReference>")
    lines.append("    </header>")
    for road in odr.roads:
        lines.extend(_road_lines(road))
    for junction in odr.junctions:
        lines.extend(_junction_lines(junction))
    lines.append("</OpenDRIVE>")
    return "\n".join(lines) + "\n"
