"""The render tests' synthetic scene: now `dashtraj.render.synthetic` (shared with
``bench/bench_render.py``); re-exported here for the tests that import ``render_scene``."""

from dashtraj.render.synthetic import (  # noqa: F401
    BIKE,
    BUS,
    MOTO,
    SEDAN,
    STRAIGHT_XODR,
    SUV,
    TRUCK,
    VAN,
    Identity,
    Model,
    identity,
)
