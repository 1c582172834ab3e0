"""A straight synthetic road and small vehicle models: the scene of the render tests and
of ``bench/bench_render.py``.

``STRAIGHT_XODR`` is OpenDRIVE text of one straight 200 m road along +x from x = -100
(three lanes each way: two driving lanes 3.5 m wide and a 3 m sidewalk). The models carry
the attribute names of `dashtraj.world.catalog.VehicleModel` (metres) with round sizes,
so a test can reason about their pixels. It lives in the package, not under ``tests/``,
so that the benchmarks run from a clean clone without the tests on the path.
"""

from __future__ import annotations

from dataclasses import dataclass

_LANE = """<lane id="{id}" type="{type}" level="false"><link/>
  <width sOffset="0" a="{w}" b="0" c="0" d="0"/>
  <roadMark sOffset="0" type="{mark}" weight="standard" color="{color}" width="0.15"/></lane>"""


def _lanes(ids):
    out = []
    for lid in ids:
        a = abs(lid)
        if a == 3:
            out.append(_LANE.format(id=lid, type="sidewalk", w=3.0, mark="none", color="standard"))
        else:
            mark = "broken" if a == 1 else "solid"
            out.append(_LANE.format(id=lid, type="driving", w=3.5, mark=mark, color="white"))
    return "\n".join(out)


STRAIGHT_XODR = f"""<?xml version="1.0" standalone="yes"?>
<OpenDRIVE>
  <header revMajor="1" revMinor="4" name="straight" version="1.0"/>
  <road name="main" length="200.0" id="1" junction="-1">
    <link/>
    <planView><geometry s="0" x="-100" y="0" hdg="0" length="200"><line/></geometry></planView>
    <elevationProfile><elevation s="0" a="0" b="0" c="0" d="0"/></elevationProfile>
    <lanes>
      <laneSection s="0">
        <left>{_lanes([3, 2, 1])}</left>
        <center><lane id="0" type="none" level="false">
          <roadMark sOffset="0" type="solid solid" weight="standard" color="yellow" width="0.12"/>
        </lane></center>
        <right>{_lanes([-1, -2, -3])}</right>
      </laneSection>
    </lanes>
  </road>
</OpenDRIVE>
"""


@dataclass(frozen=True)
class Model:
    """Stand-in with the catalog's VehicleModel attribute names."""

    blueprint_id: str
    vehicle_class: str
    body_type: str
    length_m: float
    width_m: float
    height_m: float
    wheelbase_m: float
    wheel_radius_m: float
    ground_clearance_m: float = 0.15
    hood_fraction: float = 0.28
    cabin_start_fraction: float = 0.3
    beltline_fraction: float = 0.55


@dataclass(frozen=True)
class Identity:
    identity_id: int
    model: Model
    color_name: str
    rgb: tuple[int, int, int]


SEDAN = Model("vehicle.test.sedan", "car", "sedan", 4.6, 1.85, 1.45, 2.8, 0.33)
SUV = Model("vehicle.test.suv", "car", "suv", 4.7, 1.95, 1.75, 2.85, 0.36, 0.2, 0.25)
VAN = Model("vehicle.test.van", "car", "van", 5.9, 2.0, 2.6, 3.6, 0.36, 0.18, 0.1)
TRUCK = Model("vehicle.test.truck", "truck", "truck", 9.0, 2.5, 3.6, 5.2, 0.5, 0.3, 0.1)
BUS = Model("vehicle.test.bus", "bus", "bus", 12.0, 2.55, 3.2, 6.5, 0.5, 0.3, 0.0)
MOTO = Model("vehicle.test.moto", "motorcycle", "motorcycle", 2.1, 0.8, 1.2, 1.4, 0.32)
BIKE = Model("vehicle.test.bike", "bicycle", "bicycle", 1.75, 0.6, 1.05, 1.05, 0.34)


def identity(model: Model, rgb=(200, 30, 30), i: int = 1) -> Identity:
    return Identity(i, model, "red", rgb)
