"""Benchmark of dashtraj.perception: frames/s of each stage alone and of the whole
``perceive`` per observer; tracker updates/s against BoxMOT's in the same run.

A 20 s town01 recording (seed 0, 4 observers, 20 agents, the paper's 1280 x 720
camera) is simulated; observer frames at 10 fps. Stages, timed on one observer's
frames: render (with exact labels), detect (``--detector``: oracle, or an ONNX model
such as the shipped ``src/dashtraj/data/detector/detector.onnx``, timed as its own
stage ``detect_model`` beside the oracle), localize (fused; and smoothed, the whole
sequence forward then both directions, per frame), track (sort, ego),
map-match, crops (JPEG of the detections within 15 m), relink (`tracker eval`'s offline
re-linking of ego's tracks: every box >= 10 px high embedded by the shipped ReID model,
then `Relink.apply`; live_relink_update: `LiveRelink.update` on those embeddings, the
online re-linking without the embedding), and the database write. Then
`perceive` with that detector of one observer (one process; pipelined, the default, and in
turn on one thread, ``parallel_frames=0``, with their ratio) and of two observers with
2 workers, frames/s per observer (render included). Trackers: updates/s on the cached detections
of all four observers, BoxMOT's ByteTrack / OC-SORT / BoT-SORT (ECC) when importable.

Usage:
    .venv/bin/python bench/bench_perception.py [--duration 20] [--detector M.onnx]
        [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def stages(rec, observer: int, model: str | None = None) -> tuple[dict, list]:
    from dashtraj.datasets.frames import crop_vehicle, encode_jpeg, open_renderer, recording_frames
    from dashtraj.perception.detections import OracleDetector
    from dashtraj.perception.localize import build_localizer
    from dashtraj.perception.mapmatch import map_match
    from dashtraj.perception.pipeline import camera_pose_of, image_camera
    from dashtraj.perception.track import LiveRelink, Relink, build_tracker
    from dashtraj.reid.embed import ReidEmbedder
    from dashtraj.roads import RoadMap

    spec = image_camera(rec, None)
    embedder, relink, live = ReidEmbedder(), Relink(), LiveRelink()
    road_map = RoadMap.from_file(rec.map_path)
    r = open_renderer(rec.map_path, spec.width_px, spec.height_px, spec.fov_deg, msaa=0)
    det, loc = OracleDetector(), build_localizer("fused")
    trk = {n: build_tracker(n, spec) for n in ("sort", "ego")}
    t = dict.fromkeys(("render", "detect", "localize", "track_sort", "track_ego", "mapmatch",
                       "crops", "relink", "live_relink_update"), 0.0)
    mdet = None
    if model is not None:
        from dashtraj.perception.detections import build_detector

        mdet = build_detector(model)
        t["detect_model"] = 0.0
    frames, ego_ids = [], []
    it = recording_frames(rec, 0.1, None, [observer], msaa=0, renderer=r)
    n = 0
    while True:
        t0 = time.perf_counter()
        rf = next(it, None)
        t["render"] += time.perf_counter() - t0
        if rf is None:
            break
        n += 1
        pose = camera_pose_of(rf, spec)
        t0 = time.perf_counter()
        d = det.detect(rf)
        t["detect"] += time.perf_counter() - t0
        if mdet is not None:
            t0 = time.perf_counter()
            mdet.detect(rf)
            t["detect_model"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        lz = loc.localize(d.boxes, d.class_ids, spec, pose)
        t["localize"] += time.perf_counter() - t0
        reported = {}
        for name, tr in trk.items():
            t0 = time.perf_counter()
            reported[name] = tr.update(d, rf.t, pose)
            t[f"track_{name}"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        map_match(road_map, lz.x, lz.y)
        t["mapmatch"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        for i in np.flatnonzero(lz.distance_m <= 15.0):
            encode_jpeg(np.asarray(crop_vehicle(rf.frame_data.rgb, d.boxes[i], 0.1)), 90)
        t["crops"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        emb = embedder.embed_boxes(rf.frame_data.rgb, d.boxes, relink.min_box_px)
        relink.add(rf.t, d.class_ids, trk["ego"].positions, emb)
        ego_ids.append(trk["ego"].track_of.copy())
        t["relink"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        eg = trk["ego"]
        live.update(rf.t, eg.track_of, reported["ego"], d.class_ids, eg.positions, emb)
        t["live_relink_update"] += time.perf_counter() - t0
        frames.append((rf.t, pose, d))
    r.release()
    t0 = time.perf_counter()
    relink.apply(ego_ids)
    t["relink"] += time.perf_counter() - t0
    sm = build_localizer("smoothed")  # offline: every frame forward, then both directions
    t0 = time.perf_counter()
    for ft, pose, d in frames:
        sm.localize(d.boxes, d.class_ids, spec, pose, t=ft)
    sm.smoothed()
    t["localize_smoothed"] = time.perf_counter() - t0
    return {k: round(n / v, 1) if v > 0 else None for k, v in t.items()} | {"frames": n}, frames


def whole(rec, root: Path, observers, workers: int, detector: str = "oracle",
          parallel_frames: int | None = None) -> dict:
    from dashtraj.perception.pipeline import PerceiveConfig, perceive

    db = root / f"run{workers}_{parallel_frames}.db"
    t0 = time.perf_counter()
    s = perceive(rec, db, PerceiveConfig(detector=detector, observers=tuple(observers),
                                         parallel_frames=parallel_frames), workers=workers)
    wall = time.perf_counter() - t0
    return {"detector": detector, "observers": len(observers), "workers": workers,
            "parallel_frames": parallel_frames, "frames": s.frames,
            "wall_s": round(wall, 2),
            "frames_per_s_per_observer": round(s.frames / wall / min(workers, len(observers)),
                                               1)}


def trackers(rec, seqs) -> dict:
    from dashtraj.perception.peers import boxmot_peers
    from dashtraj.perception.pipeline import image_camera
    from dashtraj.perception.track import build_tracker

    spec = image_camera(rec, None)
    out = {}
    for name in ("sort", "ego"):
        n, dt = 0, 0.0
        for frames in seqs:
            tr = build_tracker(name, spec)
            for t, pose, d in frames:
                t0 = time.perf_counter()
                tr.update(d, t, pose)
                dt += time.perf_counter() - t0
                n += 1
        out[name] = round(n / dt, 1)
    peers, why = boxmot_peers()
    blank = np.zeros((spec.height_px, spec.width_px, 3), np.uint8)
    for name, make in peers.items():
        n, dt = 0, 0.0
        for frames in seqs:
            tr = make(spec)
            for t, pose, d in frames:
                t0 = time.perf_counter()
                tr.update(d, t, pose, blank)  # ECC on a blank image: the cost floor
                dt += time.perf_counter() - t0
                n += 1
        out[name] = round(n / dt, 1)
    if why:
        out["boxmot_skipped"] = why
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--detector", default="oracle",
                    help="detector of the perceive runs: oracle or an .onnx model")
    ap.add_argument("--json", metavar="PATH")
    args = ap.parse_args(argv)
    model = None if args.detector == "oracle" else str(Path(args.detector).resolve())
    from dashtraj.datasets.frames import observer_ids
    from dashtraj.world.recording import Recording, RunConfig, simulate

    with tempfile.TemporaryDirectory() as td:
        root = Path(td)
        simulate(RunConfig(map="town01", seed=0, duration_s=args.duration, n_observers=4,
                           n_agents=20), root / "rec")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = Recording.open(root / "rec")
        obs = observer_ids(rec)
        st, first = stages(rec, obs[0], model)
        seqs = [first] + [stages(rec, o)[1] for o in obs[1:]]
        det = model or "oracle"
        res = {"stages_frames_per_s": st,
               "perceive_1_worker_serial": whole(rec, root, obs[:1], 1, det, 0),
               "perceive_1_worker": whole(rec, root, obs[:1], 1, det),
               "perceive_2_workers": whole(rec, root, obs[:2], 2, det),
               "tracker_updates_per_s": trackers(rec, seqs)}
    tu = res["tracker_updates_per_s"]
    print("stage frames/s (one observer):",
          ", ".join(f"{k} {v}" for k, v in st.items() if k != "frames"))
    for k in ("perceive_1_worker_serial", "perceive_1_worker", "perceive_2_workers"):
        r = res[k]
        how = "in turn on one thread" if r["parallel_frames"] == 0 else "pipelined"
        print(f"perceive ({Path(r['detector']).name}), {r['observers']} observers / "
              f"{r['workers']} workers, {how}: "
              f"{r['frames_per_s_per_observer']} frames/s per observer (target >= 15)")
    a, b = res["perceive_1_worker"], res["perceive_1_worker_serial"]
    print(f"  pipelined / in turn (one observer): "
          f"{a['frames_per_s_per_observer'] / b['frames_per_s_per_observer']:.2f}x")
    print("tracker updates/s:", ", ".join(f"{k} {v}" for k, v in tu.items()
                                          if not k.endswith("skipped")))
    for peer in ("bytetrack", "ocsort", "botsort"):
        if peer in tu:
            print(f"  ego / {peer}: {tu['ego'] / tu[peer]:.2f}x")
    if "boxmot_skipped" in tu:
        print(f"  BoxMOT peers skipped: {tu['boxmot_skipped']}")
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
