"""Recordings of simulated drives: the run config, the simulation loop, the files.

A recording is a directory:

``meta.json``
    format ("dashtraj-recording") and format_version (1); map (source as given,
    "map.xodr", sha256 of the .xodr bytes); seed; step_s; duration_s asked for;
    simulated_to_t (s); complete (false until the run ended normally);
    target_arrived_t (s or null); target_vehicle_id (0); observer_ids;
    twin_vehicle_ids (agents of the target's exact identity, `RunConfig.n_twins`);
    camera (the `CameraSpec`); catalog_version;
    observer_roles ({vehicle id: "oncoming" | "following" | "crossing" | "parked"}
    with "meet" placement, empty otherwise); parked_observer_ids (the observers
    that stand still at the roadside for the whole run, with either placement;
    see `TrafficConfig.parked_fraction`); config (the whole `RunConfig`, enough to
    repeat the run).
``vehicles.csv``
    vehicle_id, identity_id, blueprint_id, vehicle_class, body_type, color,
    length_m, width_m, height_m, role (target / observer / agent).
``states.parquet``
    one row per vehicle and step: t (s), vehicle_id, x, y, z (box centre at road
    level, CARLA world, m), yaw (deg), speed (m/s), road_id, section_id, lane_id,
    s (m) — the lane the vehicle follows (the target's wobble moves it off the
    centre by up to `TrafficConfig.target_wobble_m`; a parked observer stands
    beside that lane, off the road's driving lanes, with speed 0 at every step).
``truth.parquet``
    one row per observer, camera frame and vehicle seen (see `dashtraj.world.camera`):
    t, observer_id, vehicle_id, cam_x, cam_y, cam_z, cam_yaw (the camera),
    box_x, box_y, box_z (3-D box centre), box_ext_x, box_ext_y, box_ext_z (half
    length, width, height), box_yaw, u_min, v_min, u_max, v_max (pixels),
    truncation, distance_m, bearing_deg, orientation, label.
``target_route.csv``
    the target's true trajectory, columns x, y, t (`dashtraj.trajectory.io`), from
    t = 0 to its arrival (or the end of the run if it did not arrive).
``map.xodr``
    a copy of the map.

Both parquet files are written a row group at a time (every `RunConfig.chunk_s`
simulated seconds) and closed in a ``finally``: a run stopped by Ctrl-C or an
exception leaves a readable recording with ``complete: false``, and
`Recording.open` warns that it is incomplete. Writing is deterministic: the same
config gives byte-identical files (no wall-clock times are stored anywhere).
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from dashtraj.errors import DashtrajError, InputFormatError, read_utf8
from dashtraj.world.camera import MAX_IMAGE_SIDE_PX, MIN_IMAGE_SIDE_PX, CameraSpec, visible_boxes
from dashtraj.world.traffic import CAPACITY_SPACING_M as CAPACITY_HINT_M
from dashtraj.world.traffic import LaneNetwork, TrafficConfig, TrafficSim, VehicleSpec

FORMAT = "dashtraj-recording"
FORMAT_VERSION = 1

VEHICLE_COLUMNS = ("vehicle_id", "identity_id", "blueprint_id", "vehicle_class", "body_type",
                   "color", "length_m", "width_m", "height_m", "role")

STATES_SCHEMA = pa.schema([
    ("t", pa.float64()), ("vehicle_id", pa.int32()), ("x", pa.float64()), ("y", pa.float64()),
    ("z", pa.float64()), ("yaw", pa.float64()), ("speed", pa.float64()),
    ("road_id", pa.int32()), ("section_id", pa.int32()), ("lane_id", pa.int32()),
    ("s", pa.float64()),
])

TRUTH_SCHEMA = pa.schema([
    ("t", pa.float64()), ("observer_id", pa.int32()), ("vehicle_id", pa.int32()),
    ("cam_x", pa.float64()), ("cam_y", pa.float64()), ("cam_z", pa.float64()),
    ("cam_yaw", pa.float64()),
    ("box_x", pa.float64()), ("box_y", pa.float64()), ("box_z", pa.float64()),
    ("box_ext_x", pa.float64()), ("box_ext_y", pa.float64()), ("box_ext_z", pa.float64()),
    ("box_yaw", pa.float64()),
    ("u_min", pa.float64()), ("v_min", pa.float64()), ("u_max", pa.float64()),
    ("v_max", pa.float64()), ("truncation", pa.float64()), ("distance_m", pa.float64()),
    ("bearing_deg", pa.float64()), ("orientation", pa.string()), ("label", pa.string()),
])


class RecordingError(DashtrajError):
    """A recording is missing a part or a part is corrupt; the message names the file."""


class IncompleteRecordingWarning(UserWarning):
    """The recording's run was interrupted; it holds the drive up to `simulated_to_t`."""


@dataclass(frozen=True, slots=True)
class RunConfig:
    """Everything that defines a simulated drive; round-trips through JSON.

    Attributes:
        map: a built-in town name ("town01", "town10") or a path to an .xodr file.
        seed: seed of every random choice.
        duration_s: simulated time, seconds (the longest, with `until_target_arrives`).
        n_observers, n_agents: vehicle counts (plus one target).
        n_twins: extra agents of the target's exact catalog identity (model and
            colour): look-alikes that appearance alone cannot tell apart. They come
            after the other vehicles (the last ids), drive as agents, and are listed
            in meta.json's ``twin_vehicle_ids``; the others' identities are the same
            as with no twins (drawn first, from the same seed).
        until_target_arrives: stop as soon as the target reaches its destination.
        truth_step_s: camera frame period for the ground truth, seconds.
        max_range_m: truth is kept for vehicles this close to a camera, metres.
        chunk_s: simulated seconds per parquet row group.
        vehicle_classes: classes drawn for every vehicle.
        vehicle_mix: "catalog" draws identities uniformly from the catalog (cars
            dominate: most identities are recolourable cars); "balanced" gives every class
            of ``vehicle_classes`` an equal share of the vehicles (within ±1), then
            draws identities uniformly inside each class and shuffles the roles, so a
            detection set sees every class (``dashtraj simulate --vehicle-mix balanced``).
        identity_range: draw identities with identity_id in [lo, hi) only, or None for
            the whole catalog (e.g. the ReID set's test identities, so that
            `dashtraj reid-dataset --from-recordings` finds them).
        target_route: ((x, y), (x, y)) origin and destination, CARLA world metres, or None.
        camera, traffic: the camera and the traffic model (``traffic.observer_placement``:
            "meet", the default, places the observers where the target passes;
            "random" anywhere; ``traffic.parked_fraction`` makes some of them
            parked cars at the roadside).
    """

    map: str = "town01"
    seed: int = 0
    duration_s: float = 180.0
    n_observers: int = 4
    n_agents: int = 20
    n_twins: int = 0
    until_target_arrives: bool = False
    truth_step_s: float = 0.1
    max_range_m: float = 60.0
    chunk_s: float = 10.0
    vehicle_classes: tuple[str, ...] = ("car", "truck", "bus", "motorcycle")
    vehicle_mix: str = "catalog"
    identity_range: tuple[int, int] | None = None
    target_route: tuple[tuple[float, float], tuple[float, float]] | None = None
    camera: CameraSpec = field(default_factory=CameraSpec)
    traffic: TrafficConfig = field(default_factory=TrafficConfig)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["vehicle_classes"] = list(self.vehicle_classes)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict) -> RunConfig:
        d = dict(d)
        d["camera"] = CameraSpec.from_dict(d.get("camera", {}))
        d["traffic"] = TrafficConfig.from_dict(d.get("traffic", {}))
        if "vehicle_classes" in d:
            d["vehicle_classes"] = tuple(d["vehicle_classes"])
        if d.get("identity_range") is not None:
            d["identity_range"] = tuple(d["identity_range"])
        if d.get("target_route") is not None:
            (a, b) = d["target_route"]
            d["target_route"] = (tuple(a), tuple(b))
        return cls(**d)

    @classmethod
    def from_json(cls, text: str) -> RunConfig:
        return cls.from_dict(json.loads(text))


@dataclass(frozen=True, slots=True)
class RunSummary:
    """What a run produced: vehicles, state frames, truth rows, simulated time (s)."""

    path: Path
    vehicles: int
    frames: int
    truth_rows: int
    simulated_to_t: float
    target_arrived_t: float | None
    complete: bool


def resolve_map(source: str) -> Path:
    """The .xodr file of a built-in town name or a path. Raises RecordingError."""
    from dashtraj.errors import OpenDriveError
    from dashtraj.world.towns import resolve_map as resolve

    try:
        return resolve(source)
    except OpenDriveError as exc:
        raise RecordingError(str(exc)) from exc
    except (DashtrajError, ValueError) as exc:
        raise RecordingError(f"{source!r} is neither an .xodr file nor a built-in town: "
                             f"{exc}") from exc


VEHICLE_MIXES = ("catalog", "balanced")
"""How `simulate` draws the vehicles' classes (see `RunConfig.vehicle_mix`)."""


def balanced_class_counts(rng: np.random.Generator, n: int, classes,
                          available: dict[str, int] | None = None) -> dict[str, int]:
    """Vehicles per class for the "balanced" mix: as equal as the catalog allows.

    Every class gets n // k (k = classes left), the n % k left over go to distinct
    classes drawn with ``rng``; a class with fewer distinct identities than its share
    (``available[c]``, e.g. the two bus liveries) keeps all it has and the rest is
    shared out again among the other classes. Raises ValueError when the classes
    together have fewer than n identities.
    """
    classes = list(classes)
    avail = {c: (available or {}).get(c, n) for c in classes}
    if sum(avail.values()) < n:
        raise ValueError(f"asked for {n} distinct identities; only {sum(avail.values())} "
                         f"match classes {', '.join(classes)}")
    counts = dict.fromkeys(classes, 0)
    left = n
    open_ = [c for c in classes if avail[c] > 0]
    while left > 0:
        k = len(open_)
        share = dict.fromkeys(open_, left // k)
        for i in rng.permutation(k)[: left % k]:
            share[open_[int(i)]] += 1
        for c in open_:
            take = min(share[c], avail[c] - counts[c])
            counts[c] += take
            left -= take
        open_ = [c for c in open_ if counts[c] < avail[c]]
    return counts


def _identities(rng: np.random.Generator, n: int, classes, id_range=None, mix="catalog"):
    """n distinct catalog identities as rows for vehicles.csv (without id/role)."""
    from dashtraj.world.catalog import CATALOG_VERSION, sample_identities

    if mix not in VEHICLE_MIXES:
        raise RecordingError(f"unknown vehicle mix {mix!r}; valid: {', '.join(VEHICLE_MIXES)}")
    if mix == "balanced":
        from dashtraj.world.catalog import identities

        pool = [i for i in identities()
                if id_range is None or id_range[0] <= i.identity_id < id_range[1]]
        available = {c: sum(i.model.vehicle_class == c for i in pool) for c in classes}
        picks = []
        try:
            for cls, k in balanced_class_counts(rng, n, classes, available).items():
                picks += sample_identities(rng, k, classes=[cls], id_range=id_range)
        except ValueError as exc:
            raise RecordingError(f"vehicle mix 'balanced': {exc}") from exc
        picks = [picks[int(i)] for i in rng.permutation(len(picks))]
    else:
        try:
            picks = sample_identities(rng, n, classes=classes, id_range=id_range)
        except ValueError as exc:  # too few identities in the range / classes asked for
            where = f"identities {id_range[0]}-{id_range[1]}" if id_range else "the catalog"
            raise RecordingError(f"{where} of classes {', '.join(classes)}: {exc} (one per "
                                 f"vehicle: target, observers and agents)") from None
    out = []
    for ident in picks:
        m = ident.model
        out.append({"identity_id": ident.identity_id, "blueprint_id": m.blueprint_id,
                    "vehicle_class": m.vehicle_class, "body_type": m.body_type,
                    "color": ident.color_name, "length_m": m.length_m, "width_m": m.width_m,
                    "height_m": m.height_m})
    return out, CATALOG_VERSION


class _ChunkWriter:
    """Buffers column chunks and writes them as parquet row groups."""

    def __init__(self, path: Path, schema: pa.Schema):
        self.path, self.schema = path, schema
        self.buf: list[dict] = []
        self.rows = 0
        self.writer = pq.ParquetWriter(str(path), schema, compression="zstd",
                                       store_schema=False)

    def add(self, cols: dict) -> None:
        self.buf.append(cols)

    def flush(self) -> None:
        if not self.buf:
            return
        cols = {f.name: np.concatenate([b[f.name] for b in self.buf]) for f in self.schema}
        table = pa.table({f.name: pa.array(cols[f.name], type=f.type) for f in self.schema},
                         schema=self.schema)
        self.writer.write_table(table)
        self.rows += table.num_rows
        self.buf = []

    def close(self) -> None:
        try:
            self.flush()
        finally:
            self.writer.close()


MIN_STEP_S = 0.001
"""The shortest simulation step (1 kHz): a step of nanoseconds would run for ever."""


def _check_config(config: RunConfig) -> None:
    """Refuse a run that cannot mean anything (RecordingError naming the field)."""
    for name in ("duration_s", "truth_step_s", "chunk_s", "max_range_m"):
        v = getattr(config, name)
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise RecordingError(f"run config: {name} must be a finite number > 0, got {v!r}")
    step = config.traffic.step_s
    if not (isinstance(step, int | float) and math.isfinite(step)
            and MIN_STEP_S <= step <= config.duration_s):
        raise RecordingError(f"run config: step_s must be at least {MIN_STEP_S:g} s and at "
                             f"most duration_s ({config.duration_s:g} s), got {step!r}")
    for name in ("n_observers", "n_agents", "n_twins"):
        v = getattr(config, name)
        if not (isinstance(v, int) and v >= 0):
            raise RecordingError(f"run config: {name} must be an integer >= 0, got {v!r}")
    check_camera(config.camera, "run config")


def check_camera(cam: CameraSpec, where: str, error: type[Exception] = RecordingError) -> None:
    """Refuse a camera that cannot mean anything: sides `MIN_IMAGE_SIDE_PX` to
    `MAX_IMAGE_SIDE_PX`, FOV 1–179°, pitch ±89°, mount within ±50 m (``error`` naming
    ``where`` and the field)."""
    for name in ("width_px", "height_px"):
        v = getattr(cam, name)
        if not (isinstance(v, int) and not isinstance(v, bool)
                and MIN_IMAGE_SIDE_PX <= v <= MAX_IMAGE_SIDE_PX):
            raise error(f"{where}: camera {name} must be an integer in [{MIN_IMAGE_SIDE_PX}, "
                        f"{MAX_IMAGE_SIDE_PX}], got {v!r}")
    for name, lo, hi in (("fov_deg", 1.0, 179.0), ("pitch_deg", -89.0, 89.0),
                         ("x_m", -50.0, 50.0), ("y_m", -50.0, 50.0), ("z_m", -50.0, 50.0)):
        v = getattr(cam, name)
        if not (isinstance(v, int | float) and not isinstance(v, bool) and lo <= v <= hi):
            raise error(f"{where}: camera {name} must be a number in [{lo:g}, {hi:g}], "
                        f"got {v!r}")


def simulate(config: RunConfig, out_dir: str | Path,
             progress: Callable[[float], None] | None = None) -> RunSummary:
    """Simulate a drive and write it as a recording in `out_dir` (created; emptied parts
    are overwritten; the CLI writes into a fresh temporary folder, see `dashtraj.outputs`).

    ``target_route.csv`` covers the target's trip only: from t = 0 to its arrival (or
    to the end of the run when it does not arrive), even when the run goes on after it.

    Args:
        config: the run.
        out_dir: the recording directory.
        progress: called with the simulated time (s) after every step, or None.

    Returns:
        A `RunSummary`. On KeyboardInterrupt or an exception the recording is closed
        with ``complete: false`` and the exception propagates.
    """
    from dashtraj.roads import RoadMap
    from dashtraj.world.traffic import vehicle_capacity

    _check_config(config)
    out = Path(out_dir)
    map_path = resolve_map(config.map)
    xodr = map_path.read_bytes()
    # a built-in town is named as the user named it, not by its cache file
    name = map_path.stem if map_path == Path(config.map) else str(config.map).lower()
    road_map = RoadMap.from_string(xodr, name=str(map_path))  # errors name the file
    road_map.name = name
    seeds = np.random.SeedSequence(config.seed).spawn(2)
    rng_ids, rng_traffic = (np.random.default_rng(s) for s in seeds)
    n_own = 1 + config.n_observers + config.n_agents
    rows, catalog_version = _identities(rng_ids, n_own, config.vehicle_classes,
                                        config.identity_range, config.vehicle_mix)
    rows += [dict(rows[0]) for _ in range(config.n_twins)]  # the target's identity again
    n = len(rows)
    roles = (["target"] + ["observer"] * config.n_observers
             + ["agent"] * (config.n_agents + config.n_twins))
    for vid, (row, role) in enumerate(zip(rows, roles, strict=True)):
        row["vehicle_id"] = vid
        row["role"] = role
    specs = [VehicleSpec(r["vehicle_id"], r["role"], r["length_m"], r["width_m"], r["height_m"])
             for r in rows]
    length = np.array([r["length_m"] for r in rows])
    width = np.array([r["width_m"] for r in rows])
    height = np.array([r["height_m"] for r in rows])
    classes = np.array([r["vehicle_class"] for r in rows])
    net = LaneNetwork(road_map, max_vehicle_length_m=max(12.5, float(length.max())),
                      max_vehicle_width_m=max(2.6, float(width.max())))
    capacity = vehicle_capacity(net)
    if n > capacity:
        raise RecordingError(
            f"{name} has room for about {capacity} vehicles (one per "
            f"{CAPACITY_HINT_M:g} m of lane outside junctions); asked for {n} (1 target + "
            f"{config.n_observers} observers + {config.n_agents} agents"
            f"{f' + {config.n_twins} twins' if config.n_twins else ''}): ask for fewer agents")
    sim = TrafficSim(net, specs, config.traffic, rng_traffic, target_route=config.target_route)
    out.mkdir(parents=True, exist_ok=True)
    (out / "map.xodr").write_bytes(xodr)
    with open(out / "vehicles.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=VEHICLE_COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    obs_idx = np.array([i for i, r in enumerate(roles) if r == "observer"], dtype=np.int64)
    step = config.traffic.step_s
    n_steps = round(config.duration_s / step)
    truth_every = max(1, round(config.truth_step_s / step))
    chunk_every = max(1, round(config.chunk_s / step))
    meta = {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "map": {"source": config.map, "file": "map.xodr",
                "sha256": hashlib.sha256(xodr).hexdigest()},
        "seed": config.seed, "step_s": step, "duration_s": config.duration_s,
        "simulated_to_t": 0.0, "complete": False, "target_arrived_t": None,
        "target_vehicle_id": 0, "observer_ids": obs_idx.tolist(),
        "twin_vehicle_ids": list(range(n_own, n)),
        "observer_roles": {str(int(sim.ids[i])): role
                           for i, role in sorted(sim.meet_roles.items())},
        "parked_observer_ids": [int(sim.ids[i]) for i in np.flatnonzero(sim.parked)],
        "camera": config.camera.to_dict(), "catalog_version": catalog_version,
        "config": config.to_dict(),
    }
    _write_meta(out, meta)
    states_w = _ChunkWriter(out / "states.parquet", STATES_SCHEMA)
    truth_w = _ChunkWriter(out / "truth.parquet", TRUTH_SCHEMA)
    route_xy: list[tuple[float, float, float]] = []
    frames = 0
    truth_rows = 0
    complete = False
    t = 0.0
    try:
        for k in range(n_steps + 1):
            if k > 0:
                sim.step()
            t = round(k * step, 9)
            f = sim.frame()
            states_w.add({"t": np.full(n, t), **f})
            frames += 1
            if sim.target_arrived_t is None or t <= sim.target_arrived_t + 1e-9:
                route_xy.append((float(f["x"][0]), float(f["y"][0]), t))
            if k % truth_every == 0 and len(obs_idx):
                g = visible_boxes(config.camera, f["x"][obs_idx], f["y"][obs_idx],
                                  f["z"][obs_idx], f["yaw"][obs_idx], f["x"], f["y"], f["z"],
                                  f["yaw"], length, width, height, obs_index=obs_idx,
                                  max_range_m=config.max_range_m)
                m = len(g["obs"])
                if m:
                    veh = g["veh"]
                    truth_w.add({
                        "t": np.full(m, t), "observer_id": obs_idx[g["obs"]], "vehicle_id": veh,
                        "cam_x": g["cam_x"], "cam_y": g["cam_y"], "cam_z": g["cam_z"],
                        "cam_yaw": g["cam_yaw"], "box_x": g["cx"], "box_y": g["cy"],
                        "box_z": g["cz"], "box_ext_x": 0.5 * length[veh],
                        "box_ext_y": 0.5 * width[veh], "box_ext_z": 0.5 * height[veh],
                        "box_yaw": f["yaw"][veh], "u_min": g["u_min"], "v_min": g["v_min"],
                        "u_max": g["u_max"], "v_max": g["v_max"],
                        "truncation": g["truncation"], "distance_m": g["distance_m"],
                        "bearing_deg": g["bearing_deg"], "orientation": g["orientation"],
                        "label": np.char.add(np.char.add(classes[veh], "_"), g["orientation"]),
                    })
                    truth_rows += m
            if progress is not None:
                progress(t)
            if k % chunk_every == 0:
                states_w.flush()
                truth_w.flush()
                meta["simulated_to_t"] = t
                _write_meta(out, meta)
            if config.until_target_arrives and sim.target_arrived_t is not None:
                break
        complete = True
    finally:
        try:
            states_w.close()
        finally:
            truth_w.close()
        _write_route(out / "target_route.csv", route_xy)
        meta.update(simulated_to_t=t, complete=complete, target_arrived_t=sim.target_arrived_t)
        _write_meta(out, meta)
    return RunSummary(out, n, frames, truth_rows, t, sim.target_arrived_t, complete)


def _check_meta(meta: dict, path: Path) -> None:
    """Refuse a meta.json whose entries have the wrong types (RecordingError naming the
    key): every reader below trusts them."""
    def bad(key: str, want: str) -> RecordingError:
        return RecordingError(f"{path}: {key} must be {want}, got {meta[key]!r}")

    def is_int(v) -> bool:
        return isinstance(v, int) and not isinstance(v, bool)

    if "format_version" in meta and not is_int(meta["format_version"]):
        raise bad("format_version", "an integer")
    if "config" in meta and not isinstance(meta["config"], dict):
        raise bad("config", "an object")
    m = meta.get("map")
    if m is not None and not (isinstance(m, dict) and isinstance(m.get("file", ""), str)
                              and isinstance(m.get("sha256") or "", str)):
        raise bad("map", 'an object {"file": name, "sha256": hex digest}')
    for key in ("step_s", "duration_s", "simulated_to_t"):
        v = meta.get(key)
        if v is not None and not (isinstance(v, int | float) and not isinstance(v, bool)
                                  and math.isfinite(v) and (v > 0 or key == "simulated_to_t")):
            raise bad(key, "a finite number" + ("" if key == "simulated_to_t" else " > 0"))
    if "target_vehicle_id" in meta and not is_int(meta["target_vehicle_id"]):
        raise bad("target_vehicle_id", "an integer")
    for key in ("observer_ids", "twin_vehicle_ids", "parked_observer_ids"):
        v = meta.get(key)
        if v is not None and not (isinstance(v, list) and all(is_int(i) for i in v)):
            raise bad(key, "a list of integers")


def _write_meta(out: Path, meta: dict) -> None:
    tmp = out / ".meta.json.tmp"
    tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    tmp.replace(out / "meta.json")


def _write_route(path: Path, rows) -> None:
    from dashtraj.trajectory.io import write_trajectory
    from dashtraj.trajectory.records import Trajectory

    if not rows:
        return
    a = np.array(rows, dtype=float)
    write_trajectory(path, Trajectory(a[:, :2], a[:, 2]))


@dataclass(frozen=True, slots=True, eq=False)
class Recording:
    """A recording read back; open with `Recording.open(path)`.

    Attributes:
        path: the directory. meta: meta.json as a dict. config: the `RunConfig`.
        vehicles: rows of vehicles.csv (dicts, numbers parsed).
        states, truth: pyarrow Tables (columns in the module docstring).
        target_route: the target's true `Trajectory` (x, y, t).
    """

    path: Path
    meta: dict
    config: RunConfig
    vehicles: tuple[dict, ...]
    states: pa.Table
    truth: pa.Table
    target_route: object

    @property
    def complete(self) -> bool:
        return bool(self.meta.get("complete"))

    @property
    def map_path(self) -> Path:
        return self.path / self.meta["map"]["file"]

    def vehicle(self, vehicle_id: int) -> dict:
        for v in self.vehicles:
            if v["vehicle_id"] == vehicle_id:
                return v
        raise RecordingError(f"{self.path / 'vehicles.csv'}: no vehicle {vehicle_id}")

    @classmethod
    def open(cls, path: str | Path) -> Recording:
        """Read a recording directory. Raises RecordingError naming a missing or
        corrupt file; warns `IncompleteRecordingWarning` for an interrupted run."""
        from dashtraj.trajectory.io import read_trajectory

        root = Path(path)
        if not root.is_dir():
            raise RecordingError(f"recording {root} is not a directory")
        if (root / "drive.json").is_file() and not (root / "meta.json").is_file():
            raise RecordingError(f"{root} is a drive (images and camera poses), not a "
                                 "simulated recording: this command needs a recording "
                                 "(dashtraj perceive reads drives; tracker, localization "
                                 "and detector eval drives with truth.csv)")

        def need(name: str) -> Path:
            p = root / name
            if not p.is_file():
                raise RecordingError(f"recording {root} has no {name} ({p} is missing)")
            return p

        try:
            meta = json.loads(need("meta.json").read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise RecordingError(f"{root / 'meta.json'} is not valid JSON: {exc}") from exc
        if not isinstance(meta, dict) or meta.get("format") != FORMAT:
            raise RecordingError(f"{root / 'meta.json'} is not a {FORMAT} meta file")
        _check_meta(meta, root / "meta.json")
        if meta.get("format_version", 0) > FORMAT_VERSION:
            raise RecordingError(f"{root / 'meta.json'}: format version "
                                 f"{meta['format_version']} is newer than this dashtraj reads "
                                 f"({FORMAT_VERSION}); upgrade dashtraj")
        try:
            config = RunConfig.from_dict(meta["config"])
        except (KeyError, TypeError, ValueError) as exc:
            raise RecordingError(f"{root / 'meta.json'}: bad config: {exc}") from exc
        try:
            _check_config(config)
        except RecordingError as exc:
            raise RecordingError(f"{root / 'meta.json'}: {exc}") from None
        vehicles = []
        text = read_utf8(need("vehicles.csv"), RecordingError)
        with io.StringIO(text, newline="") as fh:
            for line, row in enumerate(csv.DictReader(fh), start=2):
                try:
                    for k in ("vehicle_id", "identity_id"):
                        row[k] = int(row[k])
                    for k in ("length_m", "width_m", "height_m"):
                        row[k] = float(row[k])
                except (KeyError, TypeError, ValueError) as exc:
                    raise InputFormatError(f"{root / 'vehicles.csv'} line {line}: {exc}") from exc
                vehicles.append(row)
        tables = {}
        for name in ("states.parquet", "truth.parquet"):
            p = need(name)
            try:
                tables[name] = pq.read_table(p)
            except (pa.ArrowInvalid, OSError) as exc:
                raise RecordingError(f"{p} is corrupt or not parquet: {exc}") from exc
        want = (meta.get("map") or {}).get("sha256")
        map_file = root / (meta.get("map") or {}).get("file", "map.xodr")
        if want and map_file.is_file() and \
                hashlib.sha256(map_file.read_bytes()).hexdigest() != want:
            raise RecordingError(f"{map_file} is not the map meta.json names (sha256 differs): "
                                 f"the folder mixes files of two runs; simulate it again")
        route = read_trajectory(need("target_route.csv"))
        if not meta.get("complete"):
            warnings.warn(f"recording {root} is incomplete: simulated to "
                          f"t={meta.get('simulated_to_t', math.nan):g} s",
                          IncompleteRecordingWarning, stacklevel=2)
        return cls(root, meta, config, tuple(vehicles), tables["states.parquet"],
                   tables["truth.parquet"], route)
