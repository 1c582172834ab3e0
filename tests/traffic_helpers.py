"""Helpers shared by the traffic tests: a vehicle mix and an exact box-overlap test."""

from __future__ import annotations

import numpy as np

from dashtraj.world.catalog import sample_identities
from dashtraj.world.traffic import VehicleSpec


def traffic_vehicles(rng: np.random.Generator, n_obs: int = 4,
                     n_agents: int = 20) -> list[VehicleSpec]:
    ids = sample_identities(rng, 1 + n_obs + n_agents,
                            classes=("car", "truck", "bus", "motorcycle"))
    roles = ["target"] + ["observer"] * n_obs + ["agent"] * n_agents
    return [VehicleSpec(i, r, d.model.length_m, d.model.width_m, d.model.height_m)
            for i, (r, d) in enumerate(zip(roles, ids, strict=True))]


def obb_overlap(x, y, yaw_deg, length, width) -> np.ndarray:
    """(N, N) bool: do the 2-D oriented boxes of vehicles i and j overlap?

    Separating-axis theorem on the four edge normals of the two rectangles: two
    convex rectangles are disjoint iff their projections onto one of these axes are
    disjoint. Exact for rectangles, no tolerance.
    """
    h = np.radians(yaw_deg)
    axes = np.stack([np.stack([np.cos(h), np.sin(h)], -1),
                     np.stack([-np.sin(h), np.cos(h)], -1)], 1)  # (N, 2, 2)
    half = np.stack([0.5 * np.asarray(length), 0.5 * np.asarray(width)], -1)  # (N, 2)
    d = np.stack([x[None, :] - x[:, None], y[None, :] - y[:, None]], -1)  # (N, N, 2)
    n = len(x)
    separated = np.zeros((n, n), dtype=bool)
    for axis in [axes[:, None, 0], axes[:, None, 1], axes[None, :, 0], axes[None, :, 1]]:
        axis = np.broadcast_to(axis, (n, n, 2))
        dist = np.abs((d * axis).sum(-1))
        ri = (half[:, None, :] * np.abs(np.einsum("ikc,ijc->ijk", axes, axis))).sum(-1)
        rj = (half[None, :, :] * np.abs(np.einsum("jkc,ijc->ijk", axes, axis))).sum(-1)
        separated |= dist > ri + rj
    out = ~separated
    np.fill_diagonal(out, False)
    return out
