"""Rendered scenes for the detector's tests (the detector alone and with its box
classifier): single cars of known orientation on the straight test road, and the frames
of an unseen recording (town10, seed 950: never used in training) scored for recall."""

from __future__ import annotations

# camera in the right-hand lane of the straight test road (CARLA frame: y to the right;
# traffic at y = +1.75 drives +x, at y = -1.75 drives -x), 1.6 m high, looking along +x
ORIENTATION_CAM = (-60.0, 1.75, 1.6, 0.0, 0.0, 0.0)
ORIENTATION_SCENES = {
    "car_back": (-45.0, 1.75, 0.0),     # 15 m ahead in our lane, driving away
    "car_front": (-38.0, -1.75, 180.0),  # 22 m ahead in the other lane, coming at us
    "car_side": (-42.0, 0.0, 90.0),      # 18 m ahead, crossing the road
}


def catalog_car(model_id: str = "vehicle.tesla.model3", color: str = "blue"):
    """The catalog identity of a model in a colour."""
    from dashtraj.world.catalog import identities

    for ident in identities():
        if ident.model.blueprint_id == model_id and ident.color_name == color:
            return ident
    raise LookupError(model_id)


def heldout_frames(tmp_path, gl_ctx, look: str):
    """Frames every 2 s (1280 x 720, render look ``look``) of a 4 s town10 recording, seed
    950, six observers, 40 agents of every vehicle class."""
    from dashtraj.datasets.frames import open_renderer, recording_frames
    from dashtraj.render.look import preset
    from dashtraj.world.catalog import VEHICLE_CLASSES
    from dashtraj.world.recording import Recording, RunConfig, simulate

    cfg = RunConfig(map="town10", seed=950, duration_s=4.0, n_observers=6, n_agents=40,
                    vehicle_mix="balanced", vehicle_classes=VEHICLE_CLASSES,
                    until_target_arrives=False)
    simulate(cfg, tmp_path / "rec")
    rec = Recording.open(tmp_path / "rec")
    renderer = open_renderer(rec.map_path, 1280, 720, rec.config.camera.fov_deg, ctx=gl_ctx)
    renderer.set_look(preset(look))
    try:
        return list(recording_frames(rec, 2.0, (1280, 720), renderer=renderer))
    finally:
        renderer.release()


def found_boxes(frames, dets, min_px: float = 24.0) -> tuple[int, int, int]:
    """(labelled boxes at least ``min_px`` tall, those a detection overlaps at IoU 0.5,
    those a detection of their class overlaps) over the frames and their detections."""
    from dashtraj.perception.detect import box_iou
    from dashtraj.perception.detector_eval import frame_ground_truth

    total = found = found_cls = 0
    for f, d in zip(frames, dets, strict=True):
        gt = frame_ground_truth(f.frame_data.labels, 20.0, 0.7, 1.0)
        gt = gt[(gt[:, 5] == 0) & (gt[:, 3] - gt[:, 1] >= min_px)]
        total += len(gt)
        if not len(gt) or not len(d):
            continue
        iou = box_iou(gt[:, :4], d.boxes) >= 0.5
        same = d.class_ids[None, :] == gt[:, 4:5].astype(int)
        found += int(iou.any(1).sum())
        found_cls += int((iou & same).any(1).sum())
    return total, found, found_cls
