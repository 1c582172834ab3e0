"""A tiny OpenDRIVE writer for the roads tests' synthetic maps.

The real CARLA maps and their fixtures (town01, town10, carla_map) are shared by
all test folders: ``tests/carla_maps.py`` and ``tests/conftest.py``.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

# --- a tiny OpenDRIVE writer for synthetic maps ------------------------------------------


def geometry(s: float, x: float, y: float, hdg: float, length: float, body: str = "<line/>"):
    """One ``<geometry>`` record; `body` is the kind element, e.g. ``<arc curvature="0.1"/>``."""
    return (f'<geometry s="{s!r}" x="{x!r}" y="{y!r}" hdg="{hdg!r}" length="{length!r}">'
            f"{body}</geometry>")


def lane(lid: int, width=(3.5, 0.0, 0.0, 0.0), type_: str = "driving", pred: int | None = None,
         succ: int | None = None, border=None) -> str:
    """One ``<lane>``; `width` / `border` are (a, b, c, d) or a list of (sOffset, a, b, c, d)."""

    def records(tag, spec):
        if spec is None:
            return ""
        rows = spec if isinstance(spec, list) else [(0.0, *spec)]
        return "".join(f'<{tag} sOffset="{r[0]!r}" a="{r[1]!r}" b="{r[2]!r}" c="{r[3]!r}" '
                       f'd="{r[4]!r}"/>' for r in rows)

    link = ""
    if pred is not None or succ is not None:
        link = ("<link>" + (f'<predecessor id="{pred}"/>' if pred is not None else "")
                + (f'<successor id="{succ}"/>' if succ is not None else "") + "</link>")
    body = records("border", border) if border is not None else records("width", width)
    return f'<lane id="{lid}" type="{type_}" level="false">{link}{body}</lane>'


def section(s: float, *lanes: str) -> str:
    """A ``<laneSection>``; lanes with positive ids go left, negative right."""
    left = [ln for ln in lanes if 'id="-' not in ln]
    right = [ln for ln in lanes if 'id="-' in ln]
    out = f'<laneSection s="{s!r}">'
    if left:
        out += "<left>" + "".join(left) + "</left>"
    out += '<center><lane id="0" type="none" level="false"/></center>'
    if right:
        out += "<right>" + "".join(right) + "</right>"
    return out + "</laneSection>"


def road(rid, geometries, length: float, sections=None, *, junction: int = -1,
         lane_offset=(), elevation=(), pred=None, succ=None) -> str:
    """One ``<road>``. `pred` / `succ`: (elementType, id, contactPoint or None).

    `lane_offset` and `elevation` are lists of (s, a, b, c, d). Default lanes: one
    3.5 m driving lane each side.
    """
    if isinstance(geometries, str):
        geometries = [geometries]
    if sections is None:
        sections = [section(0.0, lane(1), lane(-1))]
    link = ""
    for tag, ln in (("predecessor", pred), ("successor", succ)):
        if ln is not None:
            cp = f' contactPoint="{ln[2]}"' if ln[2] else ""
            link += f'<{tag} elementType="{ln[0]}" elementId="{ln[1]}"{cp}/>'
    elev = "".join(f'<elevation s="{r[0]!r}" a="{r[1]!r}" b="{r[2]!r}" c="{r[3]!r}" '
                   f'd="{r[4]!r}"/>' for r in elevation)
    offs = "".join(f'<laneOffset s="{r[0]!r}" a="{r[1]!r}" b="{r[2]!r}" c="{r[3]!r}" '
                   f'd="{r[4]!r}"/>' for r in lane_offset)
    return (f'<road name="r{rid}" length="{length!r}" id="{rid}" junction="{junction}">'
            f"<link>{link}</link><planView>{''.join(geometries)}</planView>"
            f"<elevationProfile>{elev}</elevationProfile>"
            f"<lanes>{offs}{''.join(sections)}</lanes></road>")


def opendrive(*elements: str) -> str:
    """A whole document around roads and junctions."""
    return ('<?xml version="1.0" standalone="yes"?><OpenDRIVE>'
            '<header revMajor="1" revMinor="4" name="synthetic"/>'
            + "".join(elements) + "</OpenDRIVE>")


@pytest.fixture(scope="session")
def xodr() -> SimpleNamespace:
    """The synthetic OpenDRIVE writer: xodr.geometry / lane / section / road / opendrive."""
    return SimpleNamespace(geometry=geometry, lane=lane, section=section, road=road,
                           opendrive=opendrive)
