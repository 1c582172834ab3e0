"""Benchmark of dashtraj.perception.detect: frames per second per observer on 1280×720 frames.

Per frame: letterbox to the model's input, onnxruntime inference (2 intra-op threads),
decoding and class-aware NMS, boxes back to frame pixels — everything `YoloDetector.detect`
does. "Per observer" = frames arrive one at a time (batch 1); batch 4 is timed too.

Peer, in the same run: ultralytics' own ONNX export of YOLO11n at 384×640 (the shipped
input size; from ``yolo11n.yaml``: the speed of a graph does not depend on its weights, and
no weights can be downloaded here) through the same pipeline — only when ``ultralytics`` is
installed (it is not in ``.[bench]``: it pulls a 6 GB CUDA torch). Without it the ratio is
against the figure recorded on this machine in ``../shared/VISION_FACTS.md`` (YOLO11n,
384×640, onnxruntime, 2 threads: 44 ms a frame, inference only) and says so.

The detector with its second stage, the shipped box classifier (``--classifier shipped``),
is timed on the same frames too, with one refining step (the default) and with four.

Frames: the synthetic straight town of `dashtraj.render.synthetic` with 20 vehicles when a
GL context can be made, otherwise noise frames (NMS then sees fewer candidates).

Usage:
    .venv/bin/python bench/bench_detector.py [--frames 40] [--model M.onnx] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

RECORDED_YOLO11N_MS = 44.0
"""VISION_FACTS.md: YOLO11n 384×640 through onnxruntime on 2 cores, ms a frame."""


def frames_1280x720(n: int) -> tuple[list[np.ndarray], str]:
    """``n`` 1280×720 RGB frames of the synthetic town (or noise without GL)."""
    try:
        from dashtraj.render.scene import Renderer
        from dashtraj.render.synthetic import BIKE, BUS, MOTO, SEDAN, STRAIGHT_XODR, TRUCK, identity
        from dashtraj.roads import RoadMap

        r = Renderer(RoadMap.from_string(STRAIGHT_XODR.encode(), name="straight"), 1280, 720,
                     90.0, msaa=4, threads=0)
    except Exception as exc:  # no EGL: noise frames
        rng = np.random.default_rng(0)
        return [rng.integers(0, 255, (720, 1280, 3), dtype=np.uint8) for _ in range(n)], \
            f"noise (no renderer: {type(exc).__name__})"
    rng = np.random.default_rng(0)
    models = [SEDAN, TRUCK, BUS, MOTO, BIKE]
    lanes = [(-5.25, 0.0), (-1.75, 0.0), (1.75, 180.0), (5.25, 180.0)]
    out = []
    try:
        for k in range(min(n, 8)):
            vs = []
            for i in range(20):
                y, yaw = lanes[i % 4]
                x = -85.0 + 4.0 * (i // 4) * (1 + k % 3) + rng.uniform(-1, 1)
                vs.append((i + 1, identity(models[i % 5], tuple(int(c) for c in
                                                                  rng.integers(20, 235, 3)),
                                           i + 1), x, y, 0.0, yaw))
            out.append(r.render((-95.0, -1.75, 1.6, 0.0, 0.0, 0.0), vs, labels=False,
                                depth=False).rgb)
    finally:
        r.release()
    return [out[i % len(out)] for i in range(n)], "synthetic town, 20 vehicles"


def time_detector(det, frames, batch: int) -> tuple[float, float]:
    """(wall-clock, CPU) seconds per frame of ``det.detect`` over ``frames`` in batches.

    CPU time counts every thread of the process: on a machine whose cores are shared with
    other jobs, the wall clock also counts waiting for a core, CPU time does not.
    """
    det.detect(frames[:batch])  # warm-up
    t, c = time.perf_counter(), time.process_time()
    for i in range(0, len(frames), batch):
        det.detect(frames[i:i + batch])
    return ((time.perf_counter() - t) / len(frames), (time.process_time() - c) / len(frames))


def yolo11n_onnx(tmp: Path) -> Path | None:
    """ultralytics' ONNX export of yolo11n (384×640), or None without ultralytics."""
    os.environ.setdefault("YOLO_OFFLINE", "1")
    os.environ.setdefault("YOLO_AUTOINSTALL", "0")
    os.environ.setdefault("YOLO_CONFIG_DIR", str(tmp))
    try:
        from ultralytics import YOLO
    except ImportError:
        return None
    model = YOLO("yolo11n.yaml")
    return Path(model.export(format="onnx", imgsz=(384, 640), simplify=False, dynamic=False))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads (2)")
    ap.add_argument("--json", type=Path, help="write the results here")
    args = ap.parse_args(argv)

    from dashtraj.perception.detect import YoloDetector

    frames, kind = frames_1280x720(args.frames)
    det = YoloDetector(args.model, conf=0.25, threads=args.threads, batch=1)
    res = {"frames": args.frames, "frame_size": [1280, 720], "content": kind,
           "model": str(det.path), "input_hw": list(det.input_hw), "threads": args.threads}
    s1, c1 = time_detector(det, frames, 1)
    det4 = YoloDetector(args.model, conf=0.25, threads=args.threads, batch=4)
    s4, c4 = time_detector(det4, frames, 4)
    res.update({"ours_wall_ms_b1": round(s1 * 1e3, 2), "ours_cpu_ms_b1": round(c1 * 1e3, 2),
                "ours_fps_wall_b1": round(1 / s1, 1), "ours_fps_wall_b4": round(1 / s4, 1),
                "ours_cpu_ms_b4": round(c4 * 1e3, 2),
                # a frame costs c1 CPU-seconds over all threads: 2 / c1 frames/s if the two
                # threads kept two free cores busy, 1 / c1 if only one were free
                "ours_fps_2cores_from_cpu": round(args.threads / c1, 1),
                "load_average_1min": round(os.getloadavg()[0], 2)})
    print(f"dashtraj detector {det.input_hw[1]}x{det.input_hw[0]} on 1280x720 {kind}, "
          f"{args.threads} threads: wall {s1 * 1e3:.1f} ms/frame ({1 / s1:.1f} frames/s per "
          f"observer, batch 1; {1 / s4:.1f} at batch 4), CPU {c1 * 1e3:.1f} ms/frame (all "
          f"threads) -> {args.threads / c1:.1f} frames/s on {args.threads} free cores "
          f"(target >= 20); load average {os.getloadavg()[0]:.1f}")
    # the second stage: the shipped box classifier on the same frames' boxes (opt-in)
    from dashtraj.perception.detect import BoxClassifier

    detc = YoloDetector(args.model, conf=0.25, threads=args.threads, batch=1,
                        classifier=BoxClassifier(threads=args.threads, flip=False))
    sc, cc = time_detector(detc, frames, 1)
    boxes = sum(len(d) for d in det.detect(frames)) / len(frames)
    res.update({"with_classifier_wall_ms_b1": round(sc * 1e3, 2),
                "with_classifier_cpu_ms_b1": round(cc * 1e3, 2),
                "with_classifier_fps_2cores_from_cpu": round(args.threads / cc, 1),
                "boxes_per_frame": round(boxes, 1)})
    print(f"with the box classifier (--classifier shipped --no-classifier-flip): wall "
          f"{sc * 1e3:.1f} ms/frame, CPU "
          f"{cc * 1e3:.1f} ms/frame -> {args.threads / cc:.1f} frames/s on {args.threads} free "
          f"cores ({boxes:.1f} boxes a frame)")
    detc.refine_steps = 4
    s4c, c4c = time_detector(detc, frames, 1)
    res.update({"with_classifier_4_steps_wall_ms_b1": round(s4c * 1e3, 2),
                "with_classifier_4_steps_cpu_ms_b1": round(c4c * 1e3, 2)})
    print(f"  with --refine-steps 4: wall {s4c * 1e3:.1f} ms/frame, CPU {c4c * 1e3:.1f} ms/frame "
          f"-> {args.threads / c4c:.1f} frames/s on {args.threads} free cores")
    # the default since 2026-12-06: each crop read mirrored too (CLASSIFIER_FLIP)
    detc.classifier.flip = True
    flips = {}
    for steps in (1, 2, 4):
        detc.refine_steps = steps
        sf, cf = time_detector(detc, frames, 1)
        flips[steps] = (sf, cf)
        res.update({f"with_classifier_flip_{steps}_steps_wall_ms_b1": round(sf * 1e3, 2),
                    f"with_classifier_flip_{steps}_steps_cpu_ms_b1": round(cf * 1e3, 2)})
    print("  with --classifier-flip (the default): " + ", ".join(
        f"wall {w * 1e3:.1f} ms/frame ({1 / w:.1f} frames/s per observer), CPU {c * 1e3:.1f} "
        f"({args.threads / c:.1f} frames/s on {args.threads} free cores) with {k} "
        f"step{'s' if k > 1 else ''}" for k, (w, c) in flips.items()))
    with tempfile.TemporaryDirectory() as tmp:
        peer = yolo11n_onnx(Path(tmp))
        if peer is not None:
            pdet = YoloDetector(peer, conf=0.25, threads=args.threads, batch=1)
            sp, cp = time_detector(pdet, frames, 1)
            res["yolo11n_cpu_ms_b1"] = round(cp * 1e3, 2)
            res["yolo11n_wall_ms_b1"] = round(sp * 1e3, 2)
            res["speedup_vs_yolo11n"] = round(cp / c1, 2)
            res["peer"] = "ultralytics yolo11n ONNX export 384x640, same run, same pipeline"
            print(f"yolo11n (ultralytics export, same run): CPU {cp * 1e3:.1f} ms/frame, "
                  f"wall {sp * 1e3:.1f}; ours is {cp / c1:.2f}x as fast (CPU time)")
        else:
            res["yolo11n_wall_ms_b1"] = RECORDED_YOLO11N_MS
            res["speedup_vs_yolo11n"] = round(RECORDED_YOLO11N_MS / (s1 * 1e3), 2)
            res["peer"] = ("recorded figure (VISION_FACTS.md, inference only), NOT this run: "
                           "ultralytics is not installed")
            print(f"yolo11n: ultralytics not installed; against the recorded "
                  f"{RECORDED_YOLO11N_MS:.0f} ms/frame (inference only, VISION_FACTS.md) ours "
                  f"is {RECORDED_YOLO11N_MS / (s1 * 1e3):.2f}x as fast (wall clock, "
                  "this run's load included)")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
