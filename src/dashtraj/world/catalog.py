"""The vehicle catalog: models like CARLA's blueprint library, a paint palette, and
the identities (model x colour) that traffic and re-identification draw from.

Dimensions are the real vehicles' (metres, bumper to bumper, mirrors folded, unladen),
so the photogrammetric distance of a detection (which uses an object's height) can be
checked against them. The shape parameters are what a simple renderer needs to draw
a recognisable silhouette; lengths along the vehicle are fractions of ``length_m``
measured from the front bumper, heights fractions of ``height_m``.

Example:
    >>> get_model("vehicle.tesla.model3").vehicle_class
    'car'
    >>> len(identities()) >= 700
    True
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass, fields

import numpy as np

from dashtraj.errors import DashtrajError

__all__ = [
    "BODY_TYPES",
    "CATALOG_VERSION",
    "COLORS",
    "VEHICLE_CLASSES",
    "Trim",
    "UnknownBlueprintError",
    "VehicleIdentity",
    "VehicleModel",
    "get_model",
    "identities",
    "models",
    "sample_identities",
]

CATALOG_VERSION = "1.1"
"""Bumped whenever a model, a dimension, a trim, a colour or the identity order changes
(1.1: every model got its trim, so that no two identities look the same)."""

VEHICLE_CLASSES = ("car", "truck", "bus", "motorcycle", "bicycle")
"""The detector's vehicle classes (a van is a "car")."""

BODY_TYPES = {
    "sedan": "car", "hatchback": "car", "suv": "car", "coupe": "car", "van": "car",
    "pickup": "car", "truck": "truck", "bus": "bus", "motorcycle": "motorcycle",
    "bicycle": "bicycle",
}
"""Body type -> detector class."""


class UnknownBlueprintError(DashtrajError, ValueError):
    """A blueprint id that is not in the catalog; the message lists the valid ids."""


@dataclass(frozen=True)
class Trim:
    """What tells two models of one shape apart, as CARLA's blueprints differ in lamps,
    rims and roofs: without it the Volkswagen T2 and T2 2021 (identical dimensions), or
    the Lincoln MKZ 2017 and 2020 (1 cm apart), would render pixel for pixel alike in one
    colour, and re-identification could not tell those identities apart.

    roof: "paint", "black" (two-tone), "white" (two-tone), "glass" (a glass roof) or
    "rails" (paint with dark roof rails); cars only. rims: "silver" or "dark".
    glass: "clear" or "tinted" windows; cars only. tail: "pair" (two tail lamps) or "bar"
    (one light bar across the back); cars only. cladding: dark plastic sills and
    bumpers (an SUV's); cars only. rider: the jacket of a two-wheeler's rider, "navy",
    "black", "brown", "red" or "hivis".
    """

    roof: str = "paint"
    rims: str = "silver"
    glass: str = "clear"
    tail: str = "pair"
    cladding: bool = False
    rider: str = "navy"

    def __post_init__(self) -> None:
        for name, allowed in (("roof", TRIM_ROOFS), ("rims", ("silver", "dark")),
                              ("glass", ("clear", "tinted")), ("tail", ("pair", "bar")),
                              ("rider", TRIM_RIDERS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"trim {name} {getattr(self, name)!r}; valid: "
                                 f"{', '.join(allowed)}")

    def differences(self, other: Trim) -> int:
        """How many of the six trim features differ from ``other``'s."""
        return sum(getattr(self, f.name) != getattr(other, f.name) for f in fields(self))


TRIM_ROOFS = ("paint", "black", "white", "glass", "rails")
TRIM_RIDERS = ("navy", "black", "brown", "red", "hivis")


@dataclass(frozen=True)
class VehicleModel:
    """One vehicle model (a CARLA-style blueprint).

    blueprint_id: CARLA-style id, e.g. "vehicle.tesla.model3". vehicle_class: one of
    VEHICLE_CLASSES. body_type: one of BODY_TYPES. length_m, width_m, height_m: outer
    dimensions, metres. wheelbase_m, wheel_radius_m, ground_clearance_m: metres.
    hood_fraction: share of the length taken by the bonnet, from the front.
    cabin_start_fraction, cabin_end_fraction: where the roof / greenhouse begins and
    ends, fractions of the length from the front. beltline_fraction: height of the
    window line over height_m. recolorable: whether the paint can be any colour of
    COLORS; otherwise the model only comes in ``default_color`` (a livery: taxi,
    police, fire engine, bus). trim: the details that tell it from models of a similar
    shape (:class:`Trim`).
    """

    blueprint_id: str
    make: str
    model: str
    vehicle_class: str
    body_type: str
    length_m: float
    width_m: float
    height_m: float
    wheelbase_m: float
    wheel_radius_m: float
    ground_clearance_m: float
    hood_fraction: float
    cabin_start_fraction: float
    cabin_end_fraction: float
    beltline_fraction: float
    recolorable: bool = True
    default_color: str = "white"
    trim: Trim = Trim()

    def __post_init__(self) -> None:
        if BODY_TYPES.get(self.body_type) != self.vehicle_class:
            raise ValueError(f"{self.blueprint_id}: body type {self.body_type!r} does not "
                             f"belong to class {self.vehicle_class!r}")
        if not 0 < self.wheelbase_m < self.length_m:
            raise ValueError(f"{self.blueprint_id}: wheelbase must lie inside the length")
        if not 0 <= self.cabin_start_fraction < self.cabin_end_fraction <= 1:
            raise ValueError(f"{self.blueprint_id}: cabin fractions out of order")
        if self.default_color not in _COLOR_NAMES:
            raise ValueError(f"{self.blueprint_id}: unknown default colour "
                             f"{self.default_color!r}")


@dataclass(frozen=True)
class VehicleIdentity:
    """One distinguishable vehicle look: a model in a paint colour.

    identity_id: index in the catalog's canonical identity order (stable for a given
    CATALOG_VERSION). rgb: paint colour, 0-255 sRGB.
    """

    identity_id: int
    model: VehicleModel
    color_name: str
    rgb: tuple[int, int, int]

    @property
    def key(self) -> str:
        """A readable unique key, e.g. "vehicle.audi.a2/red"."""
        return f"{self.model.blueprint_id}/{self.color_name}"


COLORS: dict[str, tuple[int, int, int]] = {
    "black": (20, 20, 22),
    "dark grey": (64, 66, 70),
    "grey": (118, 120, 124),
    "light grey": (170, 172, 176),
    "silver": (192, 194, 198),
    "white": (236, 236, 234),
    "pearl white": (246, 243, 234),
    "red": (190, 22, 30),
    "dark red": (110, 14, 22),
    "orange": (232, 110, 20),
    "yellow": (240, 200, 30),
    "beige": (212, 196, 160),
    "brown": (100, 66, 40),
    "green": (40, 140, 60),
    "dark green": (22, 70, 40),
    "olive": (110, 112, 60),
    "teal": (20, 120, 124),
    "light blue": (120, 170, 220),
    "blue": (30, 70, 170),
    "navy": (20, 30, 80),
    "purple": (90, 40, 120),
    "pink": (225, 130, 160),
    "gold": (190, 160, 90),
    "bronze": (140, 100, 60),
}
"""Named paint colours, 0-255 sRGB, in canonical order."""

_COLOR_NAMES = frozenset(COLORS)

# Shape defaults per body type: wheel radius, ground clearance (m); hood, cabin start,
# cabin end (fractions of length from the front); beltline (fraction of height).
_SHAPE = {
    "sedan": (0.33, 0.14, 0.30, 0.30, 0.80, 0.62),
    "hatchback": (0.31, 0.14, 0.24, 0.25, 0.92, 0.60),
    "suv": (0.37, 0.20, 0.25, 0.26, 0.94, 0.62),
    "coupe": (0.34, 0.12, 0.34, 0.34, 0.78, 0.64),
    "van": (0.34, 0.17, 0.10, 0.08, 0.98, 0.50),
    "pickup": (0.40, 0.24, 0.24, 0.26, 0.62, 0.62),
    "truck": (0.48, 0.28, 0.02, 0.00, 0.28, 0.55),
    "bus": (0.50, 0.30, 0.00, 0.00, 1.00, 0.35),
    "motorcycle": (0.31, 0.14, 0.20, 0.35, 0.75, 0.55),
    "bicycle": (0.34, 0.30, 0.10, 0.30, 0.70, 0.60),
}


def _m(blueprint_id: str, make: str, model: str, body: str, length: float, width: float,
       height: float, wheelbase: float, *, recolorable: bool = True,
       default_color: str = "white", **shape: float) -> VehicleModel:
    wr, gc, hood, c0, c1, belt = _SHAPE[body]
    trim = _TRIMS.get(blueprint_id, Trim())
    return VehicleModel(
        blueprint_id=blueprint_id, make=make, model=model, vehicle_class=BODY_TYPES[body],
        body_type=body, length_m=length, width_m=width, height_m=height,
        wheelbase_m=wheelbase, wheel_radius_m=shape.get("wheel_radius_m", wr),
        ground_clearance_m=shape.get("ground_clearance_m", gc),
        hood_fraction=shape.get("hood_fraction", hood),
        cabin_start_fraction=shape.get("cabin_start_fraction", c0),
        cabin_end_fraction=shape.get("cabin_end_fraction", c1),
        beltline_fraction=shape.get("beltline_fraction", belt),
        recolorable=recolorable, default_color=default_color, trim=trim,
    )


# Trims, chosen after the real cars where they have one (a MINI's black roof, a Tesla's
# glass roof, an SUV's rails and cladding) and so that every two models of one class
# whose dimensions lie within 15 cm differ in at least two features (test_catalog).
_TRIMS: dict[str, Trim] = {
    "vehicle.audi.tt": Trim(rims="dark", tail="bar"),
    "vehicle.audi.etron": Trim(roof="rails", cladding=True, tail="bar", glass="tinted"),
    "vehicle.bmw.grandtourer": Trim(roof="rails"),
    "vehicle.bmw.x5": Trim(roof="rails", cladding=True, rims="dark"),
    "vehicle.citroen.c3": Trim(roof="black", cladding=True),
    "vehicle.dodge.charger_2020": Trim(tail="bar", rims="dark", roof="black"),
    "vehicle.dodge.charger_police_2020": Trim(roof="white", rims="dark"),
    "vehicle.ford.mustang": Trim(rims="dark", glass="tinted"),
    "vehicle.ford.f150": Trim(cladding=True),
    "vehicle.honda.civic": Trim(tail="bar", glass="tinted"),
    "vehicle.jeep.wrangler_rubicon": Trim(roof="black", cladding=True, rims="dark"),
    "vehicle.lincoln.mkz_2020": Trim(tail="bar", rims="dark", glass="tinted"),
    "vehicle.mercedes.coupe": Trim(roof="black"),
    "vehicle.mercedes.coupe_2020": Trim(rims="dark", tail="bar"),
    "vehicle.audi.a2": Trim(glass="tinted"),
    "vehicle.mini.cooper_s": Trim(roof="black", tail="bar"),
    "vehicle.mini.cooper_s_2021": Trim(roof="black", rims="dark", tail="bar", glass="tinted"),
    "vehicle.nissan.micra": Trim(roof="black", glass="tinted", cladding=True),
    "vehicle.nissan.patrol": Trim(roof="rails", cladding=True),
    "vehicle.nissan.patrol_2021": Trim(rims="dark", tail="bar", glass="tinted", cladding=True),
    "vehicle.renault.clio": Trim(rims="dark"),
    "vehicle.seat.leon": Trim(tail="bar", rims="dark"),
    "vehicle.volkswagen.golf": Trim(glass="tinted"),
    "vehicle.tesla.model3": Trim(roof="glass", rims="dark", tail="bar"),
    "vehicle.toyota.prius": Trim(tail="bar", glass="tinted"),
    "vehicle.toyota.rav4": Trim(roof="rails", cladding=True, rims="dark", tail="bar"),
    "vehicle.mercedes.sprinter": Trim(glass="tinted"),
    "vehicle.volkswagen.t2": Trim(roof="white"),
    "vehicle.volkswagen.t2_2021": Trim(rims="dark", glass="tinted", tail="bar"),
    "vehicle.carlamotors.european_hgv": Trim(rims="dark"),
    "vehicle.kawasaki.ninja": Trim(rims="dark", rider="red"),
    "vehicle.harley-davidson.low_rider": Trim(rider="brown"),
    "vehicle.vespa.zx125": Trim(rider="black"),
    "vehicle.bh.crossbike": Trim(rims="dark", rider="black"),
    "vehicle.diamondback.century": Trim(rider="hivis"),
}


def _models() -> tuple[VehicleModel, ...]:
    """The catalog, in canonical order (tuple of immutable records)."""
    return (
        # cars: (length, width, height, wheelbase) in metres, manufacturers' figures
        _m("vehicle.audi.a2", "Audi", "A2", "hatchback", 3.83, 1.67, 1.55, 2.41),
        _m("vehicle.audi.tt", "Audi", "TT", "coupe", 4.18, 1.83, 1.35, 2.51),
        _m("vehicle.audi.etron", "Audi", "e-tron", "suv", 4.90, 1.94, 1.63, 2.93),
        _m("vehicle.bmw.grandtourer", "BMW", "2 Series Gran Tourer", "hatchback",
           4.56, 1.80, 1.61, 2.78),
        _m("vehicle.bmw.x5", "BMW", "X5", "suv", 4.92, 2.00, 1.75, 2.98),
        _m("vehicle.chevrolet.impala", "Chevrolet", "Impala", "sedan", 5.36, 2.03, 1.40, 3.02),
        _m("vehicle.citroen.c3", "Citroen", "C3", "hatchback", 3.99, 1.75, 1.47, 2.54),
        _m("vehicle.dodge.charger_2020", "Dodge", "Charger", "sedan", 5.04, 1.91, 1.46, 3.05),
        _m("vehicle.dodge.charger_police_2020", "Dodge", "Charger Police", "sedan",
           5.04, 1.91, 1.46, 3.05, recolorable=False, default_color="black"),
        _m("vehicle.ford.crown", "Ford", "Crown Victoria Taxi", "sedan", 5.39, 1.98, 1.44,
           2.91, recolorable=False, default_color="yellow"),
        _m("vehicle.ford.mustang", "Ford", "Mustang", "coupe", 4.79, 1.92, 1.38, 2.72),
        _m("vehicle.ford.f150", "Ford", "F-150", "pickup", 5.89, 2.03, 1.96, 3.68),
        _m("vehicle.honda.civic", "Honda", "Civic", "sedan", 4.55, 1.80, 1.42, 2.70),
        _m("vehicle.jeep.wrangler_rubicon", "Jeep", "Wrangler Rubicon", "suv",
           4.22, 1.87, 1.84, 2.46, hood_fraction=0.28, cabin_start_fraction=0.30),
        _m("vehicle.lincoln.mkz_2017", "Lincoln", "MKZ 2017", "sedan", 4.93, 1.86, 1.48, 2.85),
        _m("vehicle.lincoln.mkz_2020", "Lincoln", "MKZ 2020", "sedan", 4.93, 1.86, 1.47, 2.85),
        _m("vehicle.mercedes.coupe", "Mercedes-Benz", "C-Class Coupe", "coupe",
           4.70, 1.79, 1.40, 2.76),
        _m("vehicle.mercedes.coupe_2020", "Mercedes-Benz", "C-Class Coupe 2020", "coupe",
           4.83, 1.86, 1.42, 2.84),
        _m("vehicle.mini.cooper_s", "MINI", "Cooper S", "hatchback", 3.86, 1.73, 1.41, 2.50),
        _m("vehicle.mini.cooper_s_2021", "MINI", "Cooper S 2021", "hatchback",
           3.88, 1.73, 1.43, 2.50),
        _m("vehicle.nissan.micra", "Nissan", "Micra", "hatchback", 3.83, 1.67, 1.52, 2.43),
        _m("vehicle.nissan.patrol", "Nissan", "Patrol", "suv", 5.17, 1.99, 1.94, 3.07),
        _m("vehicle.nissan.patrol_2021", "Nissan", "Patrol 2021", "suv", 5.18, 2.00, 1.95, 3.08),
        _m("vehicle.renault.clio", "Renault", "Clio", "hatchback", 4.05, 1.80, 1.44, 2.58),
        _m("vehicle.seat.leon", "SEAT", "Leon", "hatchback", 4.28, 1.82, 1.44, 2.64),
        _m("vehicle.tesla.model3", "Tesla", "Model 3", "sedan", 4.69, 1.85, 1.44, 2.88,
           hood_fraction=0.26),
        _m("vehicle.tesla.cybertruck", "Tesla", "Cybertruck", "pickup", 5.68, 2.03, 1.79, 3.81,
           recolorable=False, default_color="silver", cabin_end_fraction=0.70),
        _m("vehicle.toyota.prius", "Toyota", "Prius", "hatchback", 4.54, 1.76, 1.49, 2.70),
        _m("vehicle.toyota.rav4", "Toyota", "RAV4", "suv", 4.60, 1.86, 1.69, 2.69),
        _m("vehicle.volkswagen.golf", "Volkswagen", "Golf", "hatchback", 4.28, 1.79, 1.46, 2.64),
        # vans (detector class "car")
        _m("vehicle.mercedes.sprinter", "Mercedes-Benz", "Sprinter", "van",
           5.93, 2.02, 2.60, 3.66),
        _m("vehicle.volkswagen.t2", "Volkswagen", "T2", "van", 4.51, 1.72, 1.96, 2.40,
           hood_fraction=0.0, cabin_start_fraction=0.04),
        _m("vehicle.volkswagen.t2_2021", "Volkswagen", "T2 2021", "van", 4.51, 1.72, 1.96,
           2.40, hood_fraction=0.0, cabin_start_fraction=0.04),
        _m("vehicle.ford.ambulance", "Ford", "E-Series Ambulance", "van", 6.70, 2.30, 2.80,
           4.01, recolorable=False, default_color="white"),
        # trucks
        _m("vehicle.carlamotors.carlacola", "CarlaMotors", "CarlaCola", "truck",
           6.80, 2.45, 3.20, 3.90, recolorable=False, default_color="red"),
        _m("vehicle.carlamotors.european_hgv", "CarlaMotors", "European HGV", "truck",
           7.80, 2.55, 3.70, 4.50),
        _m("vehicle.carlamotors.firetruck", "CarlaMotors", "Fire Truck", "truck",
           8.70, 2.50, 3.40, 4.80, recolorable=False, default_color="red"),
        _m("vehicle.mitsubishi.fuso_canter", "Mitsubishi", "Fuso Canter", "truck",
           6.00, 2.00, 2.90, 3.40),
        # buses
        _m("vehicle.mitsubishi.fusorosa", "Mitsubishi", "Fuso Rosa", "bus",
           10.30, 2.50, 3.20, 5.60, recolorable=False, default_color="pearl white"),
        _m("vehicle.mercedes.citaro", "Mercedes-Benz", "Citaro", "bus",
           12.10, 2.55, 3.10, 5.85, recolorable=False, default_color="yellow"),
        # motorcycles
        _m("vehicle.harley-davidson.low_rider", "Harley-Davidson", "Low Rider", "motorcycle",
           2.36, 0.90, 1.15, 1.63),
        _m("vehicle.kawasaki.ninja", "Kawasaki", "Ninja", "motorcycle", 2.03, 0.75, 1.12, 1.37),
        _m("vehicle.yamaha.yzf", "Yamaha", "YZF-R6", "motorcycle", 2.04, 0.70, 1.15, 1.38),
        _m("vehicle.vespa.zx125", "Vespa", "ZX 125", "motorcycle", 1.86, 0.75, 1.14, 1.34,
           wheel_radius_m=0.28),
        # bicycles
        _m("vehicle.diamondback.century", "Diamondback", "Century", "bicycle",
           1.70, 0.45, 1.05, 1.00),
        _m("vehicle.gazelle.omafiets", "Gazelle", "Omafiets", "bicycle",
           1.85, 0.62, 1.10, 1.12),
        _m("vehicle.bh.crossbike", "BH", "Crossbike", "bicycle", 1.75, 0.62, 1.08, 1.06),
    )


@functools.cache
def _all_models() -> tuple[VehicleModel, ...]:
    """The models, built once on first use (pure: the same immutable tuple each call)."""
    models = _models()
    ids = [m.blueprint_id for m in models]
    if len(set(ids)) != len(ids):
        raise ValueError("vehicle catalog: duplicate blueprint ids")
    return models


def models(vehicle_class: str | None = None) -> list[VehicleModel]:
    """Every model in canonical order, or only those of one detector class.

    Raises ValueError for a class not in VEHICLE_CLASSES.
    """
    if vehicle_class is None:
        return list(_all_models())
    if vehicle_class not in VEHICLE_CLASSES:
        raise ValueError(f"unknown vehicle class {vehicle_class!r}; "
                         f"valid: {', '.join(VEHICLE_CLASSES)}")
    return [m for m in _all_models() if m.vehicle_class == vehicle_class]


def get_model(blueprint_id: str) -> VehicleModel:
    """The model with this blueprint id.

    Raises UnknownBlueprintError (listing the valid ids) for an unknown id.
    """
    for m in _all_models():
        if m.blueprint_id == blueprint_id:
            return m
    valid = ", ".join(m.blueprint_id for m in _all_models())
    raise UnknownBlueprintError(f"unknown vehicle blueprint {blueprint_id!r}; valid: {valid}")


@functools.cache
def _all_identities() -> tuple[VehicleIdentity, ...]:
    out: list[VehicleIdentity] = []
    # Colour-major order: the first identities cover every model once (each in its
    # first colour or its livery), so identities(n) for small n is varied.
    for round_, color in enumerate(COLORS):
        for m in _all_models():
            if m.recolorable:
                out.append(VehicleIdentity(len(out), m, color, COLORS[color]))
            elif round_ == 0:
                out.append(VehicleIdentity(len(out), m, m.default_color,
                                           COLORS[m.default_color]))
    return tuple(out)


def identities(n: int | None = None) -> list[VehicleIdentity]:
    """Every identity (recolorable models x all COLORS, plus each livery model once),
    in the canonical order, or the first ``n`` of them.

    The order is colour-major: colour 0 for every model, then colour 1 for every
    recolorable model, and so on, so the first identities span all models.
    Raises ValueError if n is negative or larger than the catalog.
    """
    pool = _all_identities()
    if n is None:
        return list(pool)
    if not 0 <= n <= len(pool):
        raise ValueError(f"asked for {n} identities; the catalog has {len(pool)}")
    return list(pool[:n])


def sample_identities(rng: np.random.Generator, n: int,
                      classes: Iterable[str] | None = None,
                      id_range: tuple[int, int] | None = None) -> list[VehicleIdentity]:
    """Draw ``n`` distinct identities uniformly at random (without replacement),
    optionally only of the given detector classes and with identity_id in
    ``[id_range[0], id_range[1])`` (e.g. the ReID set's test identities).

    Deterministic for a given generator state. Raises ValueError for an unknown
    class or if fewer than ``n`` identities match.
    """
    pool = _all_identities()
    if id_range is not None:
        lo, hi = id_range
        pool = tuple(i for i in pool if lo <= i.identity_id < hi)
    if classes is not None:
        wanted = set(classes)
        unknown = wanted - set(VEHICLE_CLASSES)
        if unknown:
            raise ValueError(f"unknown vehicle classes {sorted(unknown)}; "
                             f"valid: {', '.join(VEHICLE_CLASSES)}")
        pool = tuple(i for i in pool if i.model.vehicle_class in wanted)
    if not 0 <= n <= len(pool):
        raise ValueError(f"asked for {n} distinct identities; only {len(pool)} match")
    picks = rng.choice(len(pool), size=n, replace=False)
    return [pool[int(i)] for i in picks]
