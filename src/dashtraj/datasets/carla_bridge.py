"""The CARLA bridge: record a drive (`dashtraj.datasets.drive`) from a running CARLA server.

``dashtraj carla-record -o DIR`` connects to a CARLA 0.9.x server with its ``carla``
client (``pip install carla==0.9.16``, in the dev extra; any 0.9.x client matching the
server works), and in synchronous mode with a fixed step (``every_s``):

- spawns ``observers`` vehicles, each with an RGB camera mounted as ``camera`` says
  (`CameraSpec`: x_m forward, y_m right, z_m up from the vehicle's origin, pitched by
  pitch_deg; image size and horizontal FOV), and ``agents`` vehicles (the first is the
  *target*), at spawn points drawn with ``seed``, all driven by CARLA's Traffic Manager
  (seeded too);
- every step saves each camera's image as ``<observer_id>/<frame:06d>.jpg`` with the
  camera's world transform at capture (``image.transform``) in ``poses.csv``, a depth
  camera's image at the same mount as ``<frame:06d>.depth.png`` (CARLA's own 24-bit
  encoding; ``depth``, on by default: it tightens the truth boxes), and the
  truth of every vehicle in ``truth.csv`` (`dashtraj.datasets.drive_truth`: its box's
  footprint, yaw and half extents, class from the blueprint: evaluation only, it fills
  the database's truth columns and lets ``--detector oracle`` run on the drive);
- writes ``drive.json`` (the camera, the map as ``map.xodr`` from
  ``world.get_map().to_opendrive()``) and the target's route as ``target_route.csv``
  (dashtraj's trajectory CSV: ``dashtraj score`` takes it);
- and always restores the server's settings and destroys what it spawned.

So ``dashtraj perceive DIR --detector M.onnx`` runs the pipeline on CARLA's own images,
and ``dashtraj score`` measures a route rebuilt from them against ``target_route.csv``.
Actor ids are CARLA's, so observer ids are too. Frames are the step index from the first
saved step; t is the simulation time from then.

CARLA cannot run on this project's machines (no server, no GPU for Unreal): the loop that
talks to a server is not exercised by the tests; the conversions it relies on (a
``carla.Transform`` to a camera pose, a ``carla.Image``'s BGRA bytes to RGB) and the files
it writes are, with the ``carla`` client's own types and `write_drive`.
"""

from __future__ import annotations

import math
import queue
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dashtraj.datasets.drive import DrivePose, write_drive
from dashtraj.datasets.drive_truth import write_truth
from dashtraj.datasets.frames import DatasetError
from dashtraj.world.camera import CameraSpec


class CarlaBridgeError(DatasetError):
    """No CARLA client, no server, or a server that cannot give what was asked."""


@dataclass(frozen=True)
class CarlaDriveConfig:
    """What to record (see the module docstring)."""

    town: str | None = None
    observers: int = 4
    agents: int = 20
    duration_s: float = 60.0
    every_s: float = 0.1
    camera: CameraSpec = field(default_factory=CameraSpec)
    seed: int = 0
    jpeg_quality: int = 95
    tm_port: int = 8000
    depth: bool = True


@dataclass(frozen=True)
class CarlaDriveSummary:
    out_dir: Path
    observers: list[int]
    target: int
    frames: int
    town: str


def camera_pose(transform) -> tuple[float, float, float, float, float]:
    """(x, y, z, yaw, pitch) of a ``carla.Transform`` (CARLA world: metres, degrees; the
    coordinates dashtraj uses, so nothing is flipped)."""
    loc, rot = transform.location, transform.rotation
    return (float(loc.x), float(loc.y), float(loc.z), float(rot.yaw), float(rot.pitch))


def image_rgb(raw_data, width: int, height: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a ``carla.Image``'s ``raw_data`` (BGRA, row-major)."""
    a = np.frombuffer(bytes(raw_data), dtype=np.uint8)
    if a.size != width * height * 4:
        raise CarlaBridgeError(f"a CARLA image of {width}x{height} holds {a.size} bytes, not "
                               f"{width * height * 4} (BGRA)")
    return a.reshape(height, width, 4)[:, :, 2::-1].copy()


def image_of_frame(q: queue.Queue, frame_id: int, timeout_s: float = 60.0):
    """The image a camera's ``listen`` queue holds for the server frame ``frame_id``
    (older ones, from steps before the recording, are dropped). CarlaBridgeError when
    none comes within ``timeout_s`` or the queue is past that frame."""
    while True:
        try:
            img = q.get(timeout=timeout_s)
        except queue.Empty:
            raise CarlaBridgeError(f"no camera image for server frame {frame_id} within "
                                   f"{timeout_s:g} s") from None
        if img.frame == frame_id:
            return img
        if img.frame > frame_id:
            raise CarlaBridgeError(f"a camera sent frame {img.frame} while frame {frame_id} "
                                   "was expected (is another client ticking the server?)")


def connect(host: str, port: int, timeout_s: float):
    """A ``carla.Client`` that answered; CarlaBridgeError naming the address otherwise."""
    try:
        import carla
    except ImportError:
        raise CarlaBridgeError("the CARLA bridge needs the carla client: pip install "
                               "carla==0.9.16 (or the version of your server)") from None
    client = carla.Client(host, int(port))
    client.set_timeout(float(timeout_s))
    try:
        client.get_server_version()
    except RuntimeError as exc:
        raise CarlaBridgeError(f"no CARLA server answered at {host}:{port} within "
                               f"{timeout_s:g} s ({str(exc).splitlines()[0]})") from None
    return client


_BICYCLES = ("crossbike", "century", "omafiets")


def vehicle_class_of(type_id: str, attributes: dict) -> str:
    """dashtraj's class of a CARLA vehicle blueprint: its ``base_type`` attribute (CARLA
    0.9.14+: car, truck, van, bus, motorcycle, bicycle; van counts as car), else by its
    wheels (two: a bicycle when the blueprint is one of CARLA's bicycles, else a
    motorcycle) and otherwise car."""
    base = str(attributes.get("base_type", "")).strip().lower()
    base = {"van": "car"}.get(base, base)
    if base in ("car", "truck", "bus", "motorcycle", "bicycle"):
        return base
    if str(attributes.get("number_of_wheels", "4")) == "2":
        return "bicycle" if any(b in type_id for b in _BICYCLES) else "motorcycle"
    return "car"


def truth_row(vehicle_id: int, role: str, type_id: str, vehicle_class: str, t: float,
              transform, bounding_box) -> tuple:
    """One ``truth.csv`` row (`dashtraj.datasets.drive_truth`) of a CARLA vehicle: the
    centre of its bounding box's bottom face in the world (the box is offset from the
    actor's origin by ``bounding_box.location``), its yaw and half extents."""
    import carla

    bb, ext = bounding_box.location, bounding_box.extent
    foot = transform.transform(carla.Location(x=bb.x, y=bb.y, z=bb.z - ext.z))
    return (t, int(vehicle_id), role, type_id, vehicle_class, float(foot.x), float(foot.y),
            float(foot.z), float(transform.rotation.yaw), float(ext.x), float(ext.y),
            float(ext.z))


def record_drive(client, out_dir: str | Path, config: CarlaDriveConfig,
                 progress: Callable[[int], None] | None = None) -> CarlaDriveSummary:
    """Record a drive from the server ``client`` is connected to (module docstring) into
    ``out_dir`` (created). Raises CarlaBridgeError when the map has too few spawn points."""
    import carla
    from PIL import Image

    from dashtraj.trajectory.io import write_trajectory
    from dashtraj.trajectory.records import Trajectory

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    world = client.load_world(config.town) if config.town else client.get_world()
    town = world.get_map().name.split("/")[-1]
    original = world.get_settings()
    tm = client.get_trafficmanager(config.tm_port)
    rng = random.Random(config.seed)
    actors: list = []
    cameras: list = []
    try:
        settings = world.get_settings()
        settings.synchronous_mode = True
        settings.fixed_delta_seconds = float(config.every_s)
        world.apply_settings(settings)
        tm.set_synchronous_mode(True)
        tm.set_random_device_seed(int(config.seed))
        spawn = list(world.get_map().get_spawn_points())
        need = config.observers + config.agents
        if len(spawn) < need:
            raise CarlaBridgeError(f"{town} has {len(spawn)} spawn points; {need} vehicles "
                                   "asked for")
        rng.shuffle(spawn)
        bps = sorted(world.get_blueprint_library().filter("vehicle.*"), key=lambda bp: bp.id)
        roles: dict[int, str] = {}
        for sp in spawn:
            if len(actors) == need:
                break
            bp = rng.choice(bps)
            if bp.has_attribute("color"):
                bp.set_attribute("color", rng.choice(
                    bp.get_attribute("color").recommended_values))
            a = world.try_spawn_actor(bp, sp)
            if a is None:
                continue
            n = len(actors)
            roles[a.id] = ("observer" if n < config.observers
                           else "target" if n == config.observers else "agent")
            actors.append(a)
            a.set_autopilot(True, tm.get_port())
        if len(actors) < need:
            raise CarlaBridgeError(f"{town}: only {len(actors)} of {need} vehicles could be "
                                   "spawned (occupied spawn points)")
        cam = config.camera
        cbp = world.get_blueprint_library().find("sensor.camera.rgb")
        cbp.set_attribute("image_size_x", str(cam.width_px))
        cbp.set_attribute("image_size_y", str(cam.height_px))
        cbp.set_attribute("fov", str(cam.fov_deg))
        mount = carla.Transform(carla.Location(x=cam.x_m, y=cam.y_m, z=cam.z_m),
                                carla.Rotation(pitch=cam.pitch_deg))
        observers = [a for a in actors if roles[a.id] == "observer"]
        queues: dict[int, queue.Queue] = {}
        depth_queues: dict[int, queue.Queue] = {}
        dbp = None
        if config.depth:  # the same camera's depth, for the truth boxes
            dbp = world.get_blueprint_library().find("sensor.camera.depth")
            for k, v in (("image_size_x", cam.width_px), ("image_size_y", cam.height_px),
                         ("fov", cam.fov_deg)):
                dbp.set_attribute(k, str(v))
        for a in observers:
            for bp, qs in ((cbp, queues), (dbp, depth_queues)):
                if bp is None:
                    continue
                c = world.spawn_actor(bp, mount, attach_to=a)
                q: queue.Queue = queue.Queue()
                c.listen(q.put)
                cameras.append(c)
                qs[a.id] = q
        target = next(a for a in actors if roles[a.id] == "target")
        poses: list[DrivePose] = []
        route: list[tuple[float, float, float]] = []
        t0 = None
        n_steps = math.floor(config.duration_s / config.every_s + 1e-9) + 1
        classes = {a.id: vehicle_class_of(a.type_id, dict(a.attributes)) for a in actors}
        truth: list[tuple] = []
        world.tick()  # the first step places the vehicles; images from the next
        for frame in range(n_steps):
            frame_id = world.tick()
            snap_t = world.get_snapshot().timestamp.elapsed_seconds
            t0 = snap_t if t0 is None else t0
            t = snap_t - t0
            for a in observers:
                img = image_of_frame(queues[a.id], frame_id)
                x, y, z, yaw, pitch = camera_pose(img.transform)
                poses.append(DrivePose(a.id, frame, t, x, y, z, yaw, pitch))
                p = out / str(a.id) / f"{frame:06d}.jpg"
                p.parent.mkdir(parents=True, exist_ok=True)
                Image.fromarray(image_rgb(img.raw_data, img.width, img.height)).save(
                    p, format="JPEG", quality=config.jpeg_quality)
                if config.depth:  # raw: CARLA's 24-bit depth encoding, as a PNG
                    d = image_of_frame(depth_queues[a.id], frame_id)
                    Image.fromarray(image_rgb(d.raw_data, d.width, d.height)).save(
                        p.with_suffix(".depth.png"), format="PNG")
            for a in actors:
                truth.append(truth_row(a.id, roles[a.id], a.type_id, classes[a.id], t,
                                       a.get_transform(), a.bounding_box))
            loc = target.get_transform().location
            route.append((t, float(loc.x), float(loc.y)))
            if progress is not None:
                progress(1)
        xodr = out / "map.xodr.tmp"
        xodr.write_text(world.get_map().to_opendrive(), encoding="utf-8")
        write_drive(out, xodr, cam, poses, {str(a.id): "observer" for a in observers})
        write_truth(out / "truth.csv", truth)
        xodr.unlink()
        arr = np.array(route)
        write_trajectory(out / "target_route.csv", Trajectory(arr[:, 1:], arr[:, 0]))
        return CarlaDriveSummary(out, [a.id for a in observers], target.id, n_steps, town)
    finally:
        for c in cameras:
            c.stop()
        client.apply_batch([carla.command.DestroyActor(x) for x in cameras + actors])
        tm.set_synchronous_mode(False)
        world.apply_settings(original)
