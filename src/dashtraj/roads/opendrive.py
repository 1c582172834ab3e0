"""OpenDRIVE (.xodr) reader: XML to typed records, nothing evaluated yet.

Reads what CARLA's own parser reads (``RoadParser``, ``GeometryParser``,
``LaneParser``, ``JunctionParser``, ``ElevationParser``): roads with their links,
plan view (line, arc, spiral, poly3, paramPoly3), elevation profile, laneOffset,
lane sections with lanes (type, width or border, links, road marks) and junctions
with connections and lane links. Signals, objects and the rest are ignored.

Quirks of real maps (a link to a lane that does not exist, a zero-length or
negative-length geometry, an unknown geometry element) give an
`OpenDriveWarning` naming the road and element, and the reader goes on. A file
that is not XML, or whose root is not ``<OpenDRIVE>``, raises `OpenDriveError`
naming the file; so does a NaN or infinite number in the geometry (plan view,
elevation, laneOffset, lane widths, road length, section starts), naming the
road and element.
"""

from __future__ import annotations

import hashlib
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree

from dashtraj.errors import OpenDriveError
from dashtraj.roads.planview import Cubic, Geometry, PlanView


class OpenDriveWarning(UserWarning):
    """A quirk of an OpenDRIVE file that the reader survived."""


@dataclass(frozen=True, slots=True)
class RoadMark:
    """A `<roadMark>` of a lane: s_offset from the section start, metres."""

    s_offset: float
    type: str  # solid, broken, solid solid, curb, none, ...
    color: str  # standard, white, yellow, ...
    width: float


@dataclass(slots=True)
class LaneRecord:
    id: int
    type: str
    width: Cubic  # lane width over ds from the section start (metres)
    border: Cubic | None  # outer border offset, when given instead of width
    predecessor: int | None
    successor: int | None
    level: bool = False
    _element: object = field(default=None, repr=False, compare=False)
    _marks: tuple[RoadMark, ...] | None = field(default=None, repr=False, compare=False)

    @property
    def road_marks(self) -> tuple[RoadMark, ...]:
        """The lane's `<roadMark>` records, read on first use (most users never need them)."""
        if self._marks is None:
            self._marks = _parse_marks(self._element) if self._element is not None else ()
        return self._marks


@dataclass(slots=True)
class LaneSectionRecord:
    s: float
    single_side: bool
    lanes: dict[int, LaneRecord]  # lane id -> lane, centre lane (0) excluded
    _center: object = field(default=None, repr=False, compare=False)
    _center_marks: tuple[RoadMark, ...] | None = field(default=None, repr=False, compare=False)

    @property
    def center_marks(self) -> tuple[RoadMark, ...]:
        """The centre lane's `<roadMark>` records (the centre line), read on first use."""
        if self._center_marks is None:
            self._center_marks = _parse_marks(self._center) if self._center is not None else ()
        return self._center_marks


@dataclass(frozen=True, slots=True)
class RoadLink:
    element_type: str  # "road" or "junction"
    element_id: int
    contact_point: str | None  # "start" / "end" (roads only)


@dataclass(slots=True)
class RoadRecord:
    id: int
    name: str
    length: float
    junction: int
    predecessor: RoadLink | None
    successor: RoadLink | None
    plan_view: PlanView
    elevation: Cubic
    lane_offset: Cubic
    sections: list[LaneSectionRecord]
    section_ends: list[float] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class JunctionConnection:
    id: int
    incoming_road: int
    connecting_road: int
    contact_point: str  # where the connecting road touches the incoming road
    lane_links: tuple[tuple[int, int], ...]  # (from lane of incoming, to lane of connecting)


@dataclass(frozen=True, slots=True)
class JunctionRecord:
    id: int
    name: str
    connections: tuple[JunctionConnection, ...]


@dataclass(slots=True)
class OpenDrive:
    """A parsed OpenDRIVE document."""

    name: str
    header: dict[str, str]
    roads: dict[int, RoadRecord]
    junctions: dict[int, JunctionRecord]
    sha256: str = ""
    """SHA-256 (hex) of the document's bytes as parsed ("" when built otherwise): two
    documents with the same digest are the same map."""


_GEOMETRY_KINDS = {
    "line": (),
    "arc": ("curvature",),
    "spiral": ("curvStart", "curvEnd"),
    "poly3": ("a", "b", "c", "d"),
    "paramPoly3": ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV"),
}
_KNOWN_TOP = {"header", "road", "controller", "junction", "junctionGroup", "station", "userData"}


def _warn(source: str, message: str) -> None:
    warnings.warn(f"{source}: {message}", OpenDriveWarning, stacklevel=4)


class _NotANumber(OpenDriveError):
    """An attribute that should be a number is not; `parse_opendrive` adds the file."""


def _number(el, attr: str, v: str) -> float:
    try:
        return float(v)
    except ValueError:
        raise _NotANumber(f"line {el.sourceline}: <{el.tag}> {attr}={v!r} is not a number") \
            from None


def _f(el, attr: str, default: float | None = None) -> float:
    v = el.get(attr)
    if v is None:
        if default is None:
            raise KeyError(attr)
        return default
    return _number(el, attr, v)


def _check_finite(source: str, where: str, what: str, values, names=None) -> None:
    """Raise `OpenDriveError` naming the element when a number is NaN or infinite.

    One sum tells: any NaN or infinity makes it non-finite (inf − inf is NaN).
    `names` (same length as `values`) names the attributes in the message.
    """
    if not math.isfinite(sum(values)):
        names = names or ("s", "a", "b", "c", "d")[:len(values)]
        bad = ", ".join(f"{n}={v!r}" for n, v in zip(names, values, strict=False)
                        if not math.isfinite(v))
        if not bad:  # finite numbers whose sum overflowed
            return
        raise OpenDriveError(f"{source}: {where}: {what} has a non-finite value ({bad}); "
                             "the map's geometry must be finite numbers")


def _check_records(source: str, where: str, tag: str, key: str, records) -> None:
    """`_check_finite` over (start, a, b, c, d) records, naming the bad one."""
    if not math.isfinite(sum(map(sum, records))):
        for r in records:
            _check_finite(source, where, f"<{tag}> at {key}={r[0]:g}", r,
                          (key, "a", "b", "c", "d"))


def _int(v: str | None, what: str, source: str) -> int:
    if v is None:
        raise OpenDriveError(f"{source}: {what} has no id")
    try:
        return int(v)
    except ValueError:
        try:
            f = float(v)
        except ValueError:
            raise OpenDriveError(
                f"{source}: {what} id {v!r} is not an integer (CARLA-style maps number "
                "roads, lanes and junctions with integers)"
            ) from None
        if f != int(f):
            raise OpenDriveError(f"{source}: {what} id {v!r} is not an integer") from None
        return int(f)


def read_opendrive(path: str | Path) -> OpenDrive:
    """Read an OpenDRIVE file.

    Args:
        path: the .xodr file.

    Returns:
        The parsed `OpenDrive` records.

    Raises:
        OpenDriveError: the file is missing, not XML, or not OpenDRIVE.

    Example:
        >>> od = read_opendrive("Town01.xodr")  # doctest: +SKIP
        >>> len(od.roads)  # doctest: +SKIP
        122
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise OpenDriveError(f"cannot read map {path}: {exc.strerror or exc}") from exc
    return parse_opendrive(data, name=str(path))


def parse_opendrive(data: bytes | str, name: str = "<string>") -> OpenDrive:
    """Parse OpenDRIVE text (bytes or str); `name` labels errors and warnings."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    try:
        parser = etree.XMLParser(remove_comments=True, remove_blank_text=True, collect_ids=False,
                                 huge_tree=True, resolve_entities=False)
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise OpenDriveError(f"{name} is not OpenDRIVE: XML error: {exc}") from None
    if isinstance(root.tag, str) and root.tag.startswith("{"):
        # A namespaced document (ASAM OpenDRIVE 1.8 declares one): read it by local names.
        for el in root.iter():
            if isinstance(el.tag, str) and el.tag.startswith("{"):
                el.tag = etree.QName(el).localname
        etree.cleanup_namespaces(root)
    if root.tag != "OpenDRIVE":
        raise OpenDriveError(
            f"{name} is not OpenDRIVE: its root element is <{root.tag}>, expected <OpenDRIVE>"
        )
    header_el = root.find("header")
    header = dict(header_el.attrib) if header_el is not None else {}
    try:
        roads, junctions = _parse_children(root, name)
    except _NotANumber as exc:
        raise OpenDriveError(f"{name}: {exc}") from None
    if not roads:
        if root.find("road") is not None:
            raise OpenDriveError(f"{name}: none of the OpenDRIVE file's <road> elements "
                                 "is usable (see the warnings above)")
        raise OpenDriveError(f"{name}: the OpenDRIVE file has no <road> elements")
    od = OpenDrive(name=name, header=header, roads=roads, junctions=junctions,
                   sha256=hashlib.sha256(data).hexdigest())
    _check_links(od)
    return od


def _parse_children(root, name: str) -> tuple[dict, dict]:
    """The roads and junctions of the document root, by id."""
    roads: dict[int, RoadRecord] = {}
    junctions: dict[int, JunctionRecord] = {}
    for child in root:
        tag = child.tag
        if tag == "road":
            road = _parse_road(child, name)
            if road is None:
                continue
            if road.id in roads:
                _warn(name, f"road {road.id} defined twice; the second definition is ignored")
                continue
            roads[road.id] = road
        elif tag == "junction":
            j = _parse_junction(child, name)
            junctions[j.id] = j
        elif isinstance(tag, str) and tag not in _KNOWN_TOP:
            _warn(name, f"unknown element <{tag}> at line {child.sourceline} ignored")
    return roads, junctions


def _parse_link(el, source: str, where: str) -> RoadLink | None:
    if el is None:
        return None
    etype = el.get("elementType", "road")
    eid = el.get("elementId")
    if eid is None:
        _warn(source, f"{where} has no elementId; link ignored")
        return None
    cp = el.get("contactPoint")
    if etype == "road" and cp not in ("start", "end"):
        _warn(source, f"{where} to road {eid} has contactPoint {cp!r}; assuming 'start'")
        cp = "start"
    return RoadLink(etype, _int(eid, where, source), cp)


def _parse_road(el, source: str) -> RoadRecord | None:
    rid = _int(el.get("id"), "road", source)
    where = f"road {rid}"
    length = _f(el, "length", 0.0)
    _check_finite(source, where, "<road>", (length,), ("length",))
    junction = _int(el.get("junction", "-1"), f"{where} junction", source)
    pred = succ = None
    link = el.find("link")
    if link is not None:
        pred = _parse_link(link.find("predecessor"), source, f"{where} predecessor")
        succ = _parse_link(link.find("successor"), source, f"{where} successor")

    geoms: list[Geometry] = []
    pv = el.find("planView")
    for g in pv.iterfind("geometry") if pv is not None else ():
        gl = _f(g, "length", 0.0)
        kind_el = next((c for c in g if isinstance(c.tag, str)), None)
        kind = kind_el.tag if kind_el is not None else None
        gs = _f(g, "s", 0.0)
        if kind not in _GEOMETRY_KINDS:
            _warn(source, f"{where} geometry at s={gs:g}: unknown element <{kind}>, read as a line")
            kind, params = "line", {}
        else:
            try:
                params = {k: _f(kind_el, k) for k in _GEOMETRY_KINDS[kind]}
            except (KeyError, ValueError) as exc:
                _warn(source, f"{where} geometry <{kind}> at s={gs:g}: bad attribute {exc}; "
                      "read as a line")
                kind, params = "line", {}
            if kind == "paramPoly3":
                params["pRange"] = kind_el.get("pRange", "normalized")
        gx, gy, hdg = _f(g, "x", 0.0), _f(g, "y", 0.0), _f(g, "hdg", 0.0)
        if not math.isfinite(gs + gx + gy + hdg + gl
                             + sum(v for v in params.values() if v.__class__ is float)):
            nums = {k: v for k, v in params.items() if v.__class__ is float}
            _check_finite(source, where, f"geometry <{kind}> at s={gs:g} (line {g.sourceline})",
                          (gs, gx, gy, hdg, gl, *nums.values()),
                          ("s", "x", "y", "hdg", "length", *nums))
        if gl < 0:
            _warn(source, f"{where} geometry <{kind}> at s={gs:g} has negative length "
                  f"{gl:g} m; skipped")
            continue
        if gl <= 1e-9:
            _warn(source, f"{where} geometry <{kind}> at s={gs:g} has zero length; skipped")
            continue
        geoms.append(Geometry(gs, gx, gy, hdg, gl, kind, params))
    if not geoms:
        _warn(source, f"{where} has no usable plan-view geometry; road skipped")
        return None
    geoms.sort(key=lambda g: g.s)
    plan_view = PlanView(geoms)
    if length <= 0:
        length = plan_view.length
    elif abs(plan_view.length - length) > 0.01 * max(1.0, length):
        _warn(source, f"{where}: length {length:g} m but its geometries span "
              f"{plan_view.length:g} m; using the geometries")
        length = plan_view.length

    ep = el.find("elevationProfile")
    elev_records = [_poly(e, "s") for e in (ep.iterfind("elevation") if ep is not None else ())]
    _check_records(source, where, "elevation", "s", elev_records)
    elevation = Cubic.from_records(elev_records)
    lanes_el = el.find("lanes")
    if lanes_el is None:
        _warn(source, f"{where} has no <lanes>; road skipped")
        return None
    offset_records = [_poly(e, "s") for e in lanes_el.iterfind("laneOffset")]
    _check_records(source, where, "laneOffset", "s", offset_records)
    lane_offset = Cubic.from_records(offset_records)
    sections = [_parse_section(ls, source, where) for ls in lanes_el.iterfind("laneSection")]
    if not sections:
        _warn(source, f"{where} has no <laneSection>; road skipped")
        return None
    sections.sort(key=lambda sec: sec.s)
    ends = [sec.s for sec in sections[1:]] + [length]
    return RoadRecord(rid, el.get("name", ""), length, junction, pred, succ, plan_view,
                      elevation, lane_offset, sections, ends)


def _parse_marks(lane_el) -> tuple[RoadMark, ...]:
    return tuple(
        RoadMark(_f(m, "sOffset", 0.0), m.get("type", "none"), m.get("color", "standard"),
                 _f(m, "width", 0.12))
        for m in lane_el.iterfind("roadMark")
    )


_POLY_KEYS = {"sOffset": ["sOffset", "a", "b", "c", "d"], "s": ["s", "a", "b", "c", "d"]}


def _poly(el, start: str) -> tuple[float, float, float, float, float]:
    """(start, a, b, c, d) of a cubic record; missing attributes read as 0."""
    if el.keys() == _POLY_KEYS[start]:  # the usual attribute order: read them in one call
        try:
            return tuple(map(float, el.values()))
        except ValueError:
            pass  # name the attribute below
    return tuple(_number(el, k, el.get(k) or "0") for k in (start, "a", "b", "c", "d"))


def _lane_id(el, what, source: str) -> int:
    """An integer id attribute; `what()` names the element only when it is bad."""
    v = el.get("id")
    try:
        return int(v)
    except (TypeError, ValueError):
        return _int(v, what(), source)


def _parse_section(ls, source: str, road_where: str) -> LaneSectionRecord:
    s = _f(ls, "s", 0.0)
    _check_finite(source, road_where, "<laneSection>", (s,), ("s",))
    lanes: dict[int, LaneRecord] = {}
    center = None
    for side in ("left", "center", "right"):
        side_el = ls.find(side)
        if side_el is None:
            continue
        for lane in side_el.iterfind("lane"):
            lid = _lane_id(lane, lambda: f"{road_where} lane", source)
            if lid == 0:
                center = lane
                continue
            widths, borders, link = [], [], None
            for child in lane:  # one pass over the lane's children
                tag = child.tag
                if tag == "width":
                    widths.append(_poly(child, "sOffset"))
                elif tag == "link":
                    link = child
                elif tag == "border":
                    borders.append(_poly(child, "sOffset"))
            pred = succ = None
            if link is not None:
                p = link.find("predecessor")
                q = link.find("successor")
                pred = _lane_id(p, lambda lid=lid: f"{road_where} lane {lid} predecessor", source) \
                    if p is not None else None
                succ = _lane_id(q, lambda lid=lid: f"{road_where} lane {lid} successor", source) \
                    if q is not None else None
            if widths:
                _check_records(source, f"{road_where} section at s={s:g} lane {lid}", "width",
                               "sOffset", widths)
            if borders:
                _check_records(source, f"{road_where} section at s={s:g} lane {lid}", "border",
                               "sOffset", borders)
            if not widths and not borders:
                _warn(source, f"{road_where} section at s={s:g} lane {lid} has no <width>; "
                      "width 0")
            lanes[lid] = LaneRecord(
                id=lid,
                type=lane.get("type", "none"),
                width=Cubic.from_records(widths),
                border=Cubic.from_records(borders) if (borders and not widths) else None,
                predecessor=pred,
                successor=succ,
                level=lane.get("level", "false") in ("true", "1"),
                _element=lane,
            )
    return LaneSectionRecord(s, ls.get("singleSide", "false") == "true", lanes, center)


def _parse_junction(el, source: str) -> JunctionRecord:
    jid = _int(el.get("id"), "junction", source)
    conns = []
    for c in el.iterfind("connection"):
        where = f"junction {jid} connection {c.get('id')}"
        try:
            inc = _int(c.get("incomingRoad"), f"{where} incomingRoad", source)
            con = _int(c.get("connectingRoad"), f"{where} connectingRoad", source)
        except OpenDriveError as exc:
            _warn(source, f"{exc}; connection ignored")
            continue
        links = tuple(
            (_int(ll.get("from"), f"{where} laneLink", source),
             _int(ll.get("to"), f"{where} laneLink", source))
            for ll in c.iterfind("laneLink")
        )
        conns.append(JunctionConnection(_int(c.get("id", "-1"), where, source), inc, con,
                                        c.get("contactPoint", "start"), links))
    return JunctionRecord(jid, el.get("name", ""), tuple(conns))


def _check_links(od: OpenDrive) -> None:
    """Warn about links that point at roads, junctions or lanes that do not exist."""
    for road in od.roads.values():
        for which, link in (("predecessor", road.predecessor), ("successor", road.successor)):
            if link is None:
                continue
            table = od.roads if link.element_type == "road" else od.junctions
            if link.element_id not in table:
                _warn(od.name, f"road {road.id} {which} links to missing "
                      f"{link.element_type} {link.element_id}; link ignored")
                if which == "predecessor":
                    road.predecessor = None
                else:
                    road.successor = None
    for j in od.junctions.values():
        for c in j.connections:
            for rid in (c.incoming_road, c.connecting_road):
                if rid not in od.roads:
                    _warn(od.name, f"junction {j.id} connection {c.id} names missing road {rid}")
