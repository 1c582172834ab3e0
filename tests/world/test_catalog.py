"""Vehicle catalog: coverage of classes, plausible dimensions, distinct and
deterministic identities, sampling."""

from __future__ import annotations

import re
from collections import Counter

import numpy as np
import pytest

from dashtraj.world.catalog import (
    BODY_TYPES,
    CATALOG_VERSION,
    COLORS,
    VEHICLE_CLASSES,
    UnknownBlueprintError,
    VehicleModel,
    get_model,
    identities,
    models,
    sample_identities,
)

# body type -> (length, width, height) ranges in metres
PLAUSIBLE = {
    "sedan": ((4.0, 5.5), (1.6, 2.1), (1.3, 1.6)),
    "hatchback": ((3.5, 4.7), (1.6, 1.9), (1.35, 1.7)),
    "suv": ((4.0, 5.3), (1.7, 2.1), (1.55, 2.0)),
    "coupe": ((3.8, 5.0), (1.7, 2.0), (1.25, 1.45)),
    "van": ((4.3, 7.0), (1.7, 2.4), (1.9, 3.0)),
    "pickup": ((5.0, 6.2), (1.9, 2.2), (1.7, 2.1)),
    "truck": ((5.5, 12.0), (1.9, 2.6), (2.5, 4.0)),
    "bus": ((9.0, 18.5), (2.3, 2.6), (2.8, 3.5)),
    "motorcycle": ((1.7, 2.6), (0.6, 1.0), (1.0, 1.4)),
    "bicycle": ((1.5, 2.0), (0.4, 0.7), (0.9, 1.2)),
}


def test_enough_models_and_every_class():
    ms = models()
    assert len(ms) >= 35
    assert set(Counter(m.vehicle_class for m in ms)) == set(VEHICLE_CLASSES)
    assert {m.body_type for m in ms} == set(BODY_TYPES)
    assert len({m.blueprint_id for m in ms}) == len(ms)
    assert all(m.blueprint_id.startswith("vehicle.") for m in ms)
    assert [m.blueprint_id for m in models("bus")] == [
        "vehicle.mitsubishi.fusorosa", "vehicle.mercedes.citaro"]


@pytest.mark.parametrize("model", models(), ids=lambda m: m.blueprint_id)
def test_dimensions_plausible(model: VehicleModel):
    (l0, l1), (w0, w1), (h0, h1) = PLAUSIBLE[model.body_type]
    assert l0 <= model.length_m <= l1
    assert w0 <= model.width_m <= w1
    assert h0 <= model.height_m <= h1
    assert 0.4 * model.length_m <= model.wheelbase_m <= 0.75 * model.length_m
    assert 2 * model.wheel_radius_m < model.height_m
    assert 0.0 < model.ground_clearance_m < 0.5
    assert 0.0 <= model.hood_fraction <= model.cabin_start_fraction + 0.05
    assert 0.0 < model.beltline_fraction < 1.0


def test_class_rules_from_the_brief():
    for m in models("car"):
        assert m.body_type != "van" or m.height_m > 1.9
        assert 3.5 <= m.length_m <= 7.0
    assert get_model("vehicle.mercedes.sprinter").body_type == "van"
    assert get_model("vehicle.mercedes.sprinter").vehicle_class == "car"
    assert 2.5 <= get_model("vehicle.mercedes.sprinter").height_m <= 2.7
    assert all(m.length_m > 9.0 for m in models("bus"))
    assert all(m.length_m < 2.0 for m in models("bicycle"))


def test_body_type_must_match_class():
    with pytest.raises(ValueError, match="does not belong"):
        VehicleModel("vehicle.x.y", "X", "Y", "truck", "sedan", 4.5, 1.8, 1.4, 2.7,
                     0.3, 0.14, 0.3, 0.3, 0.8, 0.6)


def test_get_model_and_unknown_id():
    assert get_model("vehicle.tesla.model3").make == "Tesla"
    with pytest.raises(UnknownBlueprintError, match=re.escape("vehicle.audi.a2")):
        get_model("vehicle.tesla.roadster")


def test_palette():
    assert len(COLORS) >= 20
    for name in ("black", "light grey", "silver", "white", "red", "dark red", "green",
                 "dark green", "blue", "navy", "yellow", "orange", "brown", "beige"):
        assert name in COLORS
    assert len(set(COLORS.values())) == len(COLORS)
    assert all(0 <= c <= 255 for rgb in COLORS.values() for c in rgb)
    assert all(m.default_color in COLORS for m in models())


def test_identities_distinct_and_complete():
    ids = identities()
    assert len(ids) >= 700
    assert [i.identity_id for i in ids] == list(range(len(ids)))
    assert len({(i.model.blueprint_id, i.color_name) for i in ids}) == len(ids)
    assert len({i.key for i in ids}) == len(ids)
    n_recolorable = sum(m.recolorable for m in models())
    n_livery = len(models()) - n_recolorable
    assert len(ids) == n_recolorable * len(COLORS) + n_livery
    for i in ids:
        assert i.rgb == COLORS[i.color_name]
        if not i.model.recolorable:
            assert i.color_name == i.model.default_color


def test_identities_deterministic_and_varied_prefix():
    assert identities() == identities()
    first = identities(len(models()))
    assert {i.model.blueprint_id for i in first} == {m.blueprint_id for m in models()}
    assert identities(5) == identities()[:5]
    with pytest.raises(ValueError):
        identities(10_000)
    assert CATALOG_VERSION


def test_sample_identities():
    a = sample_identities(np.random.default_rng(7), 50)
    b = sample_identities(np.random.default_rng(7), 50)
    assert a == b and len({i.identity_id for i in a}) == 50
    bikes = sample_identities(np.random.default_rng(1), 10, classes=["bicycle", "motorcycle"])
    assert {i.model.vehicle_class for i in bikes} <= {"bicycle", "motorcycle"}
    buses = [i for i in identities() if i.model.vehicle_class == "bus"]
    with pytest.raises(ValueError, match="only"):
        sample_identities(np.random.default_rng(1), len(buses) + 1, classes=["bus"])
    with pytest.raises(ValueError, match="unknown vehicle classes"):
        sample_identities(np.random.default_rng(1), 1, classes=["tank"])


def test_models_of_a_similar_shape_differ_in_at_least_two_trim_features():
    """No two recolorable models of one class may look alike in one colour: where their
    dimensions lie within 15 cm of each other, their trims differ in two features or
    more (the T2 and T2 2021 share every dimension)."""
    def shape(m):
        return np.array([m.length_m, m.width_m, m.height_m, m.wheelbase_m, m.wheel_radius_m,
                         m.ground_clearance_m, m.hood_fraction * m.length_m,
                         m.cabin_start_fraction * m.length_m,
                         m.cabin_end_fraction * m.length_m, m.beltline_fraction * m.height_m])

    ms = [m for m in models() if m.recolorable]
    close = 0
    for i, a in enumerate(ms):
        for b in ms[i + 1:]:
            if a.vehicle_class == b.vehicle_class and \
                    np.abs(shape(a) - shape(b)).max() < 0.15:
                close += 1
                assert a.trim.differences(b.trim) >= 2, (a.blueprint_id, b.blueprint_id)
    assert close >= 15  # the rule is not vacuous


def test_trim_refuses_unknown_features():
    from dashtraj.world.catalog import Trim

    with pytest.raises(ValueError, match="trim roof 'chrome'"):
        Trim(roof="chrome")
    assert Trim().differences(Trim(rims="dark", tail="bar")) == 2
