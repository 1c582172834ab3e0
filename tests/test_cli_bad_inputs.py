"""Bad input anywhere in the CLI: exit code 2, ONE line on stderr naming the culprit, and no
output touched.

Each row of `CASES` is run in-process through `dashtraj.cli.main` in a fresh folder that
holds a pre-filled output folder (``OUT_DIR``) and a pre-filled output file
(``OUT_FILE``, ``OUT_PNG``); afterwards every file under that folder must be byte-for-byte
what it was, and nothing may have been added (no temporary sibling, no partial output).
The inputs (a small recording, sightings CSVs) live in a separate folder made once.

Also here: the happy-path counterparts the issue listed as tracebacks (``reconstruct -o
missing/dir/x.csv`` creates the folders), ``--overwrite`` replacing an output whole, an
interrupted ``simulate`` keeping its partial recording under its own new folder, and
``target_route.csv`` ending at the target's arrival.
"""

from __future__ import annotations

import csv
import hashlib
import sys
import warnings
from pathlib import Path

import pytest

from dashtraj.cli import main

# (id, argv with placeholders, fragment the one stderr line must contain)
CASES: list[tuple[str, list[str], str]] = [
    # --- the "Why" list
    ("simulate-agents-500-town01", ["simulate", "--town", "town01", "--agents", "500",
                                    "-o", "{OUT_DIR}", "--overwrite"], "room for about 236"),
    ("simulate-agents-500-new", ["simulate", "--town", "town01", "--agents", "500",
                                 "-o", "{NEW_DIR}"], "asked for 505"),
    ("simulate-duration-negative", ["simulate", "--duration", "-5", "-o", "{NEW_DIR}"],
     "argument --duration: expected a number > 0"),
    ("simulate-observers-negative", ["simulate", "--observers", "-1", "-o", "{NEW_DIR}"],
     "argument --observers: expected an integer >= 0"),
    ("simulate-step-zero", ["simulate", "--step", "0", "-o", "{NEW_DIR}"],
     "argument --step: expected a number > 0"),
    ("simulate-output-is-file", ["simulate", "--duration", "1", "-o", "{OUT_FILE}"],
     "is a file; this command writes a folder"),
    ("experiments-seeds-zero", ["experiments", "--seeds", "0", "-o", "{NEW_DIR}"],
     "argument --seeds: expected an integer >= 1 (a count)"),
    ("map-route-from-nan", ["map", "route", "town01", "--from=nan,20", "--to=100,60"],
     "argument --from: expected finite X,Y"),
    ("map-route-from-far", ["map", "route", "town01", "--from=1e6,1e6", "--to=100,60"],
     "--from (1e+06, 1e+06) is"),
    ("reconstruct-all-off-road", ["reconstruct", "--map", "town01", "--sightings",
                                  "{FAR_CSV}", "-o", "{NEW_FILE}"],
     "more than 50 m from every driving lane"),
    # --- an existing output is refused without --overwrite, for every writer
    ("simulate-exists", ["simulate", "--duration", "1", "-o", "{OUT_DIR}"], "--overwrite"),
    ("sightings-exists", ["sightings", "{REC}", "-o", "{OUT_FILE}"], "--overwrite"),
    ("reconstruct-exists", ["reconstruct", "--map", "town01", "--sightings", "{SIGHTINGS}",
                            "-o", "{OUT_FILE}"], "--overwrite"),
    ("map-route-exists", ["map", "route", "town01", "--from=150,60", "--to=100,60",
                          "-o", "{OUT_FILE}"], "--overwrite"),
    ("map-plot-exists", ["map", "plot", "town01", "-o", "{OUT_PNG}"], "--overwrite"),
    ("render-exists", ["render", "{REC}", "-o", "{OUT_DIR}"], "--overwrite"),
    ("detection-dataset-exists", ["detection-dataset", "{REC}", "-o", "{OUT_DIR}"],
     "--overwrite"),
    ("reid-dataset-exists", ["reid-dataset", "--ids", "3", "-o", "{OUT_DIR}"], "--overwrite"),
    ("experiments-exists", ["experiments", "--seeds", "1", "-o", "{OUT_DIR}"], "--overwrite"),
    ("demo-exists", ["demo", "-o", "{OUT_DIR}"], "--overwrite"),
    ("sightings-output-is-folder", ["sightings", "{REC}", "-o", "{OUT_DIR}", "--overwrite"],
     "is a folder; this command writes a file"),
    # --- simulate
    ("simulate-duration-nan", ["simulate", "--duration", "nan", "-o", "{NEW_DIR}"],
     "argument --duration: expected a finite number"),
    ("simulate-duration-inf", ["simulate", "--duration", "inf", "-o", "{NEW_DIR}"],
     "argument --duration"),
    ("simulate-duration-absurd", ["simulate", "--duration", "1e300", "-o", "{NEW_DIR}"],
     "argument --duration: expected at most 86400 s"),
    ("simulate-map-is-folder", ["simulate", "--town", "{TMP}", "-o", "{NEW_DIR}"],
     "is a folder, not an .xodr file"),
    ("simulate-step-longer-than-duration", ["simulate", "--duration", "1", "--step", "5",
                                            "-o", "{NEW_DIR}"], "--step 5 s is longer"),
    ("simulate-agents-fraction", ["simulate", "--agents", "1.5", "-o", "{NEW_DIR}"],
     "argument --agents: expected an integer"),
    ("simulate-seed-negative", ["simulate", "--seed", "-3", "-o", "{NEW_DIR}"],
     "argument --seed"),
    ("simulate-parked-fraction", ["simulate", "--parked-fraction", "2", "-o", "{NEW_DIR}"],
     "argument --parked-fraction"),
    ("simulate-identities", ["simulate", "--identities", "9-2", "-o", "{NEW_DIR}"],
     "argument --identities"),
    ("simulate-identities-too-few", ["simulate", "--identities", "650-652", "--agents", "3",
                                     "-o", "{NEW_DIR}"], "only 2 match"),
    ("simulate-unknown-town", ["simulate", "--town", "town99", "-o", "{NEW_DIR}"],
     "valid names: town01, town10"),
    ("simulate-missing-map-file", ["simulate", "--town", "{MISSING}.xodr", "-o", "{NEW_DIR}"],
     "does not exist"),
    ("simulate-no-output", ["simulate"], "the following arguments are required: -o/--output"),
    # --- sightings
    ("sightings-max-distance-zero", ["sightings", "{REC}", "--max-distance", "0",
                                     "-o", "{NEW_FILE}"], "argument --max-distance"),
    ("sightings-noise", ["sightings", "{REC}", "--noise", "loud", "-o", "{NEW_FILE}"],
     "argument --noise: invalid choice"),
    ("sightings-vehicle", ["sightings", "{REC}", "--vehicle", "999", "-o", "{NEW_FILE}"],
     "no vehicle 999"),
    ("sightings-export-csv-as-db", ["sightings", "export", "{SIGHTINGS}", "-o", "{NEW_FILE}"],
     "is not a sightings database"),
    ("sightings-detector-missing", ["sightings", "{REC}", "--detector", "{MISSING}.onnx",
                                    "-o", "{NEW_FILE}"], "no such model file"),
    ("sightings-sample-negative", ["sightings", "{REC}", "--sample", "-1", "-o", "{NEW_FILE}"],
     "argument --sample"),
    ("sightings-missing-recording", ["sightings", "{MISSING}", "-o", "{NEW_FILE}"],
     "is not a directory"),
    ("sightings-export-missing-db", ["sightings", "export", "{MISSING}.db", "-o", "{NEW_FILE}"],
     "does not exist"),
    ("sightings-export-foreign-db", ["sightings", "export", "{GARBAGE_XODR}", "-o",
                                     "{NEW_FILE}"], "is not a sightings database"),
    ("sightings-export-no-db", ["sightings", "export", "-o", "{NEW_FILE}"], "name the database"),
    ("sightings-export-exists", ["sightings", "export", "{GARBAGE_XODR}", "-o", "{OUT_FILE}"],
     "--overwrite"),
    # --- perceive
    ("perceive-every-zero", ["perceive", "{REC}", "--every", "0", "-o", "{NEW_FILE}"],
     "argument --every: expected a number > 0"),
    ("perceive-workers-zero", ["perceive", "{REC}", "--workers", "0", "-o", "{NEW_FILE}"],
     "argument --workers: expected an integer >= 1"),
    ("perceive-tracker", ["perceive", "{REC}", "--tracker", "bogus", "-o", "{NEW_FILE}"],
     "unknown tracker 'bogus'; valid: sort, ego"),
    ("perceive-localizer", ["perceive", "{REC}", "--localizer", "bogus", "-o", "{NEW_FILE}"],
     "valid: paper, ground, fused"),
    ("perceive-missing-model", ["perceive", "{REC}", "--detector", "{MISSING}.onnx", "-o",
                                "{NEW_FILE}"], "no such model file"),
    ("perceive-missing-recording", ["perceive", "{MISSING}", "-o", "{NEW_FILE}"],
     "is not a directory"),
    ("perceive-look", ["perceive", "{REC}", "--look", "neon", "-o", "{NEW_FILE}"],
     "unknown look preset 'neon'; valid:"),
    ("perceive-agnostic-nms", ["perceive", "{REC}", "--agnostic-nms", "0", "-o", "{NEW_FILE}"],
     "--agnostic-nms"),
    ("perceive-min-score", ["perceive", "{REC}", "--min-score", "1.5", "-o", "{NEW_FILE}"],
     "--min-score"),
    ("perceive-size", ["perceive", "{REC}", "--size", "4x4", "-o", "{NEW_FILE}"],
     "argument --size"),
    ("perceive-exists", ["perceive", "{REC}", "-o", "{OUT_FILE}"], "--overwrite"),
    ("perceive-append-overwrite", ["perceive", "{REC}", "-o", "{OUT_FILE}", "--append",
                                   "--overwrite"], "give one of them"),
    ("perceive-append-foreign", ["perceive", "{REC}", "-o", "{OUT_FILE}", "--append"],
     "is not a sightings database (not an SQLite file)"),
    ("perceive-pose-noise", ["perceive", "{REC}", "--pose-noise", "1", "-o", "{NEW_FILE}"],
     "argument --pose-noise: give XY_M,YAW_DEG"),
    ("tracker-eval-pose-noise", ["tracker", "eval", "{REC}", "--pose-noise", "1,x"],
     "argument --pose-noise: not numbers"),
    ("localization-eval-pose-noise", ["localization", "eval", "{REC}", "--pose-noise",
                                      "1,1,1,0"], "tau_s must be > 0"),
    ("experiments-pose-noise-ablation", ["experiments", "--ablation", "--pose-noise", "1,1",
                                         "-o", "{NEW_DIR}"], "--ablation with --pose-noise"),
    ("experiments-calibrate-pitch-ablation", ["experiments", "--ablation", "--calibrate-pitch",
                                              "-o", "{NEW_DIR}"],
     "--ablation with --calibrate-pitch"),
    ("experiments-calibrate-pitch-oracle", ["experiments", "--sightings", "oracle",
                                            "--calibrate-pitch", "-o", "{NEW_DIR}"],
     "--calibrate-pitch corrects the observers' poses in perception"),
    ("experiments-live-relink-ablation", ["experiments", "--ablation", "--live-relink",
                                           "-o", "{NEW_DIR}"],
     "--ablation with --live-relink"),
    ("experiments-live-relink-oracle", ["experiments", "--sightings", "oracle",
                                        "--live-relink", "-o", "{NEW_DIR}"],
     "--live-relink re-links the tracks of perception"),
    ("experiments-gallery-ablation", ["experiments", "--ablation", "--gallery-range", "30",
                                      "-o", "{NEW_DIR}"],
     "--ablation with --gallery-range"),
    ("experiments-gallery-oracle", ["experiments", "--sightings", "oracle", "--gallery-range",
                                    "30", "-o", "{NEW_DIR}"],
     "--gallery-range widens appearance ReID's gallery: it needs --sightings vision"),
    ("experiments-gallery-near", ["experiments", "--gallery-range", "10", "-o", "{NEW_DIR}"],
     "--gallery-range 10.0: must be a number of metres, at least the query's range (15 m)"),
    ("experiments-route-ablation", ["experiments", "--ablation", "--route-range", "20",
                                    "-o", "{NEW_DIR}"],
     "--ablation with --route-range"),
    ("experiments-route-near", ["experiments", "--route-range", "10", "-o", "{NEW_DIR}"],
     "--route-range 10.0: must be a number of metres, at least the gallery's range (15 m)"),
    ("perceive-live-relink-model", ["perceive", "{REC}", "--live-relink", "--reid-model",
                                    "{MISSING}.onnx", "-o", "{NEW_FILE}"],
     "no such file"),
    # --- tracker, localization
    ("tracker-eval-missing", ["tracker", "eval", "{MISSING}"], "is not a directory"),
    ("tracker-eval-unknown", ["tracker", "eval", "{REC}", "--trackers", "kalman"],
     "unknown tracker 'kalman'; valid: sort, ego"),
    ("tracker-eval-every", ["tracker", "eval", "{REC}", "--every", "0"],
     "argument --every: expected a number > 0"),
    ("tracker-eval-size", ["tracker", "eval", "{REC}", "--size", "4x4"], "argument --size"),
    ("tracker-eval-reid-model", ["tracker", "eval", "{REC}", "--reid-model", "{MISSING}"],
     "--reid-model"),
    ("tracker-eval-relink-model", ["tracker", "eval", "{REC}", "--relink-model", "{MISSING}"],
     "--relink-model"),
    ("tracker-eval-relink-cut", ["tracker", "eval", "{REC}", "--relink-cut", "-1"],
     "argument --relink-cut: expected a number > 0"),
    ("localization-eval-missing", ["localization", "eval", "{MISSING}"], "is not a directory"),
    ("localization-eval-mu-nan", ["localization", "eval", "{REC}", "--mu-h", "nan"],
     "argument --mu-h: expected a finite number"),
    ("localization-eval-plot-exists", ["localization", "eval", "{REC}", "--plot",
                                       "{OUT_PNG}"], "--overwrite"),
    ("localization-calibrate-n", ["localization", "calibrate", "{REC}", "-n", "0"],
     "argument -n: expected an integer >= 1"),
    ("localization-calibrate-far", ["localization", "calibrate", "{REC}", "--max-distance",
                                    "-3"], "argument --max-distance: expected a number > 0"),
    # --- reconstruct
    ("reconstruct-method", ["reconstruct", "--map", "town01", "--sightings", "{SIGHTINGS}",
                            "--method", "astar", "-o", "{NEW_FILE}"],
     "valid: hmm, shortest-path"),
    ("reconstruct-unknown-map", ["reconstruct", "--map", "town99", "--sightings",
                                 "{SIGHTINGS}", "-o", "{NEW_FILE}"],
     "--map 'town99' is neither a file nor a built-in town"),
    ("reconstruct-not-opendrive", ["reconstruct", "--map", "{GARBAGE_XODR}", "--sightings",
                                   "{SIGHTINGS}", "-o", "{NEW_FILE}"], "is not OpenDRIVE"),
    ("reconstruct-nan-cell", ["reconstruct", "--map", "town01", "--sightings", "{NAN_CSV}",
                              "-o", "{NEW_FILE}"], "line 3, column 'x'"),
    ("reconstruct-missing-sightings", ["reconstruct", "--map", "town01", "--sightings",
                                       "{MISSING}.csv", "-o", "{NEW_FILE}"], "cannot open"),
    ("reconstruct-max-off-road", ["reconstruct", "--map", "town01", "--sightings",
                                  "{SIGHTINGS}", "--max-off-road", "-1", "-o", "{NEW_FILE}"],
     "argument --max-off-road"),
    # --- map
    ("map-route-to-inf", ["map", "route", "town01", "--from=150,60", "--to=inf,0"],
     "argument --to"),
    ("map-route-three-numbers", ["map", "route", "town01", "--from=1,2,3", "--to=100,60"],
     "argument --from: expected X,Y"),
    ("map-route-to-far", ["map", "route", "town01", "--from=150,60", "--to=-500,-500"],
     "--to (-500, -500) is"),
    ("map-route-lane-change-cost", ["map", "route", "town01", "--from=150,60", "--to=100,60",
                                    "--lane-change-cost", "-1"],
     "argument --lane-change-cost"),
    ("map-plot-one-end", ["map", "plot", "town01", "-o", "{NEW_PNG}", "--route-from=150,60"],
     "give both --route-from and --route-to"),
    ("map-plot-far", ["map", "plot", "town01", "-o", "{NEW_PNG}", "--route-from=150,60",
                      "--route-to=1e5,0"], "--route-to (100000, 0) is"),
    ("map-plot-suffix", ["map", "plot", "town01", "-o", "{NEW_FILE}.txt"], "name a .png"),
    ("map-info-unknown", ["map", "info", "town99"], "neither a file nor a built-in town"),
    # --- render and the training sets
    ("render-every-zero", ["render", "{REC}", "-o", "{NEW_DIR}", "--every", "0"],
     "argument --every"),
    ("render-size", ["render", "{REC}", "-o", "{NEW_DIR}", "--size", "4x4"],
     "argument --size: expected each side of WxH in 8..8192"),
    ("render-size-huge", ["render", "{REC}", "-o", "{NEW_DIR}", "--size", "20000x20000"],
     "argument --size"),
    ("render-observer-unknown", ["render", "{REC}", "-o", "{NEW_DIR}", "--observer", "999"],
     "--observer 999: not an observer"),
    ("render-observer-negative", ["render", "{REC}", "-o", "{NEW_DIR}", "--observer", "-1"],
     "argument --observer"),
    ("detection-val-fraction", ["detection-dataset", "{REC}", "-o", "{NEW_DIR}",
                                "--val-fraction", "1.5"], "argument --val-fraction"),
    ("detection-max-occlusion-nan", ["detection-dataset", "{REC}", "-o", "{NEW_DIR}",
                                     "--max-occlusion", "nan"], "argument --max-occlusion"),
    ("detection-size", ["detection-dataset", "{REC}", "-o", "{NEW_DIR}", "--size", "big"],
     "argument --size: expected WxH in pixels"),
    ("reid-train-truncate", ["reid", "train", "{OUT_DIR}", "-o", "{NEW_DIR}", "--truncate",
                             "1.5"], "argument --truncate: expected a number in [0, 1]"),
    ("reid-train-erasing", ["reid", "train", "{OUT_DIR}", "-o", "{NEW_DIR}", "--erasing", "-0.1"],
     "argument --erasing: expected a number in [0, 1]"),
    ("reid-train-group-batches", ["reid", "train", "{OUT_DIR}", "-o", "{NEW_DIR}",
                                  "--group-batches", "2"],
     "argument --group-batches: expected a number in [0, 1]"),
    ("detection-same-recording-twice", ["detection-dataset", "{REC}", "{REC}", "-o",
                                        "{NEW_DIR}"], "is given twice"),
    ("detection-missing-recording", ["detection-dataset", "{MISSING}", "-o", "{NEW_DIR}"],
     "is not a directory"),
    ("reid-ids-zero", ["reid-dataset", "--ids", "0", "-o", "{NEW_DIR}"], "argument --ids"),
    ("reid-test-ids", ["reid-dataset", "--ids", "3", "--test-ids", "3", "-o", "{NEW_DIR}"],
     "--test-ids 3 must be fewer than --ids 3"),
    ("reid-size-tiny", ["reid-dataset", "--size", "1", "-o", "{NEW_DIR}"],
     "argument --size: expected an integer >= 16"),
    ("reid-workers-zero", ["reid-dataset", "--workers", "0", "-o", "{NEW_DIR}"],
     "argument --workers"),
    ("reid-unknown-town", ["reid-dataset", "--ids", "3", "--town", "town99", "-o",
                           "{OUT_DIR}", "--overwrite"], "valid names: town01, town10"),
    # --- perceive (recording → sightings database)
    ("perceive-mu-h-nan", ["perceive", "{REC}", "-o", "{NEW_FILE}", "--mu-h", "nan"],
     "argument --mu-h"),
    ("perceive-frames-exist", ["perceive", "{REC}", "-o", "{NEW_FILE}", "--save-frames",
                               "{OUT_DIR}"], "--overwrite"),
    ("perceive-observers", ["perceive", "{REC}", "-o", "{NEW_FILE}", "--observers", "99"],
     "not observers of"),
    # --- localization and tracker evaluation
    ("localization-eval-plot-suffix", ["localization", "eval", "{REC}", "--plot", "x.txt"],
     "argument --plot: name a .png"),
    ("localization-eval-localizer", ["localization", "eval", "{REC}", "--localizers", "lidar"],
     "valid: paper, ground, fused"),
    ("localization-calibrate-max-distance-nan", ["localization", "calibrate", "{REC}",
                                                 "--max-distance", "nan"],
     "argument --max-distance"),
    ("tracker-eval-peer", ["tracker", "eval", "{REC}", "--peers", "deepsort"],
     "valid: bytetrack, ocsort, botsort"),
    # --- experiments, demo, score, bench-reconstruct, the top level
    ("experiments-seeds-negative", ["experiments", "--seeds", "-1", "-o", "{NEW_DIR}"],
     "argument --seeds"),
    ("experiments-seeds-reversed", ["experiments", "--seeds", "4-2", "-o", "{NEW_DIR}"],
     "argument --seeds: expected a range A-B with A <= B"),
    ("experiments-seeds-repeated", ["experiments", "--seeds", "3,3", "-o", "{NEW_DIR}"],
     "argument --seeds: expected each seed once"),
    ("experiments-seeds-garbage", ["experiments", "--seeds", "a-b", "-o", "{NEW_DIR}"],
     "argument --seeds: expected a count N, a range A-B or a list"),
    ("experiments-unknown-town", ["experiments", "--towns", "town99", "-o", "{NEW_DIR}"],
     "--towns 'town99'"),
    ("experiments-vision-detector", ["experiments", "--sightings", "vision", "--detector",
                                     "yolo", "-o", "{NEW_DIR}"],
     "--detector 'yolo': expected shipped, gpu, oracle or an existing .onnx file"),
    ("experiments-min-score", ["experiments", "--min-score", "-0.1", "-o", "{NEW_DIR}"],
     "argument --min-score"),
    ("demo-agnostic-nms", ["demo", "--agnostic-nms", "1.5", "-o", "{NEW_DIR}"],
     "argument --agnostic-nms"),
    ("experiments-vision-reid-model", ["experiments", "--sightings", "vision", "--reid-model",
                                       "{MISSING}.onnx", "-o", "{NEW_DIR}"],
     "--reid-model"),
    ("experiments-vision-threshold-missing", ["experiments", "--sightings", "vision",
                                              "--reid-threshold", "{MISSING}", "-o",
                                              "{NEW_DIR}"], "--reid-threshold"),
    ("experiments-vision-threshold-foreign", ["experiments", "--sightings", "vision",
                                              "--reid-threshold", "{TRUTH}", "-o", "{NEW_DIR}"],
     "not a threshold file"),
    ("experiments-vision-look", ["experiments", "--sightings", "vision", "--look", "neon",
                                 "-o", "{NEW_DIR}"], "--look 'neon': unknown preset"),
    ("experiments-vision-localizer", ["experiments", "--localizer", "lidar", "-o", "{NEW_DIR}"],
     "--localizer 'lidar': valid: paper, ground, fused, tracked, smoothed, mapped"),
    ("demo-localizer", ["demo", "--localizer", "lidar", "-o", "{NEW_DIR}"],
     "--localizer 'lidar': valid:"),
    ("experiments-vision-size", ["experiments", "--sightings", "vision", "--size", "0x0",
                                 "-o", "{NEW_DIR}"], "argument --size"),
    ("experiments-vision-every", ["experiments", "--sightings", "vision", "--every", "-1",
                                  "-o", "{NEW_DIR}"], "argument --every"),
    ("experiments-vision-look-alike", ["experiments", "--sightings", "vision", "--reid",
                                       "look-alike", "-o", "{NEW_DIR}"],
     "reid mode 'look-alike' does not go with sightings 'vision'"),
    ("experiments-appearance-oracle", ["experiments", "--sightings", "oracle", "--reid",
                                       "appearance", "-o", "{NEW_DIR}"],
     "reid mode 'appearance' does not go with sightings 'oracle'"),
    ("experiments-ablation-identity", ["experiments", "--ablation", "--reid", "identity",
                                       "-o", "{NEW_DIR}"], "--ablation with --reid identity"),
    ("experiments-ablation-exists", ["experiments", "--ablation", "-o", "{OUT_DIR}"],
     "--overwrite"),
    ("demo-vision-detector", ["demo", "--sightings", "vision", "--detector", "{TRUTH}",
                              "-o", "{NEW_DIR}"],
     "expected shipped, gpu, oracle or an existing .onnx"),
    ("reid-threshold-not-db", ["reid-threshold", "{TRUTH}", "-o", "{NEW_FILE}"],
     "is not a sightings database"),
    ("reid-threshold-missing-model", ["reid-threshold", "{TRUTH}", "--model", "{MISSING}.onnx",
                                      "-o", "{NEW_FILE}"], "no such ONNX model"),
    ("reid-threshold-precision", ["reid-threshold", "{TRUTH}", "--target-precision", "1.5",
                                  "-o", "{NEW_FILE}"], "argument --target-precision"),
    ("reid-threshold-exists", ["reid-threshold", "{TRUTH}", "-o", "{OUT_FILE}"], "--overwrite"),
    ("demo-duration-zero", ["demo", "--duration", "0", "-o", "{NEW_DIR}"],
     "argument --duration"),
    ("demo-workers-zero", ["demo", "--workers", "0", "-o", "{NEW_DIR}"],
     "argument --workers: expected an integer >= 1"),
    ("reid-threshold-max-far", ["reid-threshold", "{TRUTH}", "--rule", "far", "--max-far", "2",
                                "-o", "{NEW_FILE}"], "argument --max-far"),
    ("reid-threshold-border-nan", ["reid-threshold", "{TRUTH}", "--border-px", "nan",
                                   "-o", "{NEW_FILE}"], "--border-px"),
    ("demo-observers-negative", ["demo", "--observers", "-2", "-o", "{NEW_DIR}"],
     "argument --observers"),
    ("demo-unknown-town", ["demo", "--town", "town99", "-o", "{OUT_DIR}", "--overwrite"],
     "valid names: town01, town10"),
    ("score-resample-zero", ["score", "--truth", "{TRUTH}", "--estimate", "{TRUTH}",
                             "--resample-m", "0"], "--resample-m"),
    ("score-resample-inf", ["score", "--truth", "{TRUTH}", "--estimate", "{TRUTH}",
                            "--resample-m", "inf"], "--resample-m must be a positive"),
    ("score-missing-file", ["score", "--truth", "{MISSING}.csv", "--estimate", "{TRUTH}"],
     "cannot open"),
    ("bench-reconstruct-trips-zero", ["bench-reconstruct", "--map", "town01", "--trips", "0"],
     "argument --trips"),
    ("bench-reconstruct-method", ["bench-reconstruct", "--map", "town01", "--trips", "1",
                                  "--methods", "astar"], "valid: hmm, shortest-path"),
    ("reid-eval-not-veri", ["reid", "eval", "--data", "{OUT_DIR}"],
     "not a VeRi-776 layout folder"),
    ("reid-eval-missing", ["reid", "eval", "--data", "{MISSING}"], "no such folder"),
    ("reid-moving-not-a-set", ["reid", "moving-queries", "{OUT_DIR}", "{REC}"], "no reid.json"),
    ("reid-moving-train-not-a-set", ["reid", "moving-train", "{OUT_DIR}", "{REC}"],
     "no reid.json"),
    # --- detect and detector
    ("detect-missing-source", ["detect", "{MISSING}", "-o", "{NEW_DIR}"],
     "no such image or folder"),
    ("detect-exists", ["detect", "{REC}", "-o", "{OUT_DIR}"], "--overwrite"),
    ("detect-conf", ["detect", "{REC}", "--conf", "2", "-o", "{NEW_DIR}"], "argument --conf"),
    ("detect-missing-model", ["detect", "{REC}", "--model", "{MISSING}.onnx", "-o",
                              "{NEW_DIR}"], "no such model file"),
    ("detector-eval-plot-no-output", ["detector", "eval", "{REC}", "--plot"],
     "--plot needs -o"),
    ("detector-eval-missing-model", ["detector", "eval", "{REC}", "--model",
                                     "{MISSING}.onnx"], "no such model file"),
    ("detector-train-recipe", ["detector", "train", "{REC}", "-o", "{NEW_DIR}", "--recipe",
                               "tpu"], "argument --recipe: invalid choice"),
    ("detector-train-not-a-set", ["detector", "train", "{REC}", "-o", "{NEW_DIR}"],
     "no images/train/"),
    ("detector-train-classifier-not-a-set", ["detector", "train-classifier", "{REC}", "-o",
                                             "{NEW_DIR}"], "no labels/train/"),
    ("detector-train-classifier-refine-missing", ["detector", "train-classifier", "{REC}",
                                                  "-o", "{NEW_DIR}", "--refine-with",
                                                  "{MISSING}.onnx"], "--refine-with"),
    ("detector-train-classifier-lowres", ["detector", "train-classifier", "{REC}", "-o",
                                          "{NEW_DIR}", "--lowres", "2"], "--lowres"),
    ("detect-refine-steps-zero", ["detect", "{REC}", "--classifier", "shipped",
                                  "--refine-steps", "0", "-o", "{NEW_DIR}"], "--refine-steps"),
    ("perceive-missing-classifier", ["perceive", "{REC}", "--classifier", "{MISSING}.onnx",
                                     "-o", "{NEW_FILE}"], "--classifier"),
    ("experiments-missing-classifier", ["experiments", "--seeds", "1", "--classifier",
                                        "{MISSING}.onnx", "-o", "{NEW_DIR}"], "--classifier"),
    ("detector-train-classifier-blocks", ["detector", "train-classifier", "{REC}", "-o",
                                          "{NEW_DIR}", "--blocks", "17"],
     "--blocks 17: EfficientNet-Lite0 has 16 blocks"),
    ("detector-eval-missing-classifier", ["detector", "eval", "{REC}", "--classifier",
                                          "{MISSING}.onnx"], "--classifier"),
    ("detect-missing-classifier", ["detect", "{REC}", "--classifier", "{MISSING}.onnx", "-o",
                                   "{NEW_DIR}"], "--classifier"),
    ("detector-eval-external-missing-classifier", ["detector", "eval-external", "{OUT_DIR}",
                                                   "--names", "vehicle", "--classifier",
                                                   "{MISSING}.onnx"], "--classifier"),
    ("detector-export-missing", ["detector", "export", "{MISSING}.pt", "-o", "{NEW_FILE}"],
     "no such checkpoint"),
    ("detector-eval-small-px-nan", ["detector", "eval", "{REC}", "--small-px", "nan"],
     "argument --small-px: expected a finite number"),
    ("detector-eval-every-zero", ["detector", "eval", "{REC}", "--every", "0"],
     "argument --every: expected a number > 0"),
    ("detector-eval-max-truncation", ["detector", "eval", "{REC}", "--max-truncation", "1.5"],
     "argument --max-truncation: expected a number in [0, 1]"),
    ("detector-train-seed", ["detector", "train", "{REC}", "-o", "{NEW_DIR}", "--seed", "-1"],
     "argument --seed: expected an integer >= 0"),
    ("detector-eval-external-missing", ["detector", "eval-external", "{MISSING}"],
     "no such folder"),
    ("detector-eval-external-no-names", ["detector", "eval-external", "{OUT_DIR}"],
     "no data.yaml or classes.txt"),
    ("detector-eval-external-class-map", ["detector", "eval-external", "{OUT_DIR}", "--names",
                                          "vehicle", "--class-map", "car:vehicle"],
     "--class-map: 'car:vehicle' is not OURS=THEIRS"),
    ("detector-eval-external-not-an-image", ["detector", "eval-external", "{OUT_DIR}",
                                             "--names", "vehicle"], "not a readable image"),
    ("detector-eval-external-exists", ["detector", "eval-external", "{OUT_DIR}", "--names",
                                       "vehicle", "-o", "{OUT_DIR}"], "--overwrite"),
    ("reid-train-lr", ["reid", "train", "{OUT_DIR}", "-o", "{NEW_DIR}", "--lr", "-1"],
     "argument --lr: expected a number > 0"),
    ("reid-train-epochs", ["reid", "train", "{OUT_DIR}", "-o", "{NEW_DIR}", "--epochs", "0"],
     "argument --epochs: expected an integer >= 1"),
    ("reid-train-size", ["reid", "train", "{OUT_DIR}", "-o", "{NEW_DIR}", "--size", "160"],
     "argument --size: expected WxH in pixels"),
    ("reid-eval-threads", ["reid", "eval", "--data", "{OUT_DIR}", "--threads", "0"],
     "argument --threads: expected an integer >= 1"),
    ("reid-eval-rerank-lambda", ["reid", "eval", "--data", "{OUT_DIR}", "--rerank-lambda", "2"],
     "argument --rerank-lambda: expected a number in [0, 1]"),
    # --- reid embed / query on a sightings database
    ("reid-embed-missing-db", ["reid", "embed", "{MISSING}.db"], "does not exist"),
    ("reid-embed-not-a-db", ["reid", "embed", "{GARBAGE_XODR}"], "is not a sightings database"),
    ("reid-embed-foreign-db", ["reid", "embed", "{FOREIGN_DB}"],
     "not a dashtraj sightings database"),
    ("reid-embed-no-crops", ["reid", "embed", "{EMPTY_DB}"], "has no crops"),
    ("reid-embed-dim-mismatch", ["reid", "embed", "{DIM_DB}"],
     "holds 8-d embeddings of model efficientnet_lite0_cpu.onnx"),
    ("reid-embed-batch-zero", ["reid", "embed", "{CROPS_DB}", "--batch", "0"],
     "argument --batch: expected an integer >= 1"),
    ("reid-embed-missing-model", ["reid", "embed", "{CROPS_DB}", "--model", "{MISSING}.onnx"],
     "no such ONNX model"),
    ("reid-embed-not-a-model", ["reid", "embed", "{CROPS_DB}", "--model", "{GARBAGE_XODR}"],
     "not a readable ONNX model"),
    ("reid-query-missing-db", ["reid", "query", "{MISSING}.db", "--track", "1"],
     "does not exist"),
    ("reid-query-not-a-db", ["reid", "query", "{GARBAGE_XODR}", "--track", "1"],
     "is not a sightings database"),
    ("reid-query-foreign-db", ["reid", "query", "{FOREIGN_DB}", "--track", "1"],
     "not a dashtraj sightings database"),
    ("reid-query-no-crops", ["reid", "query", "{EMPTY_DB}", "--track", "1"], "has no crops"),
    ("reid-query-not-embedded", ["reid", "query", "{CROPS_DB}", "--track", "1", "--observer",
                                 "1"], "run: dashtraj reid embed"),
    ("reid-query-unknown-track", ["reid", "query", "{QUERY_DB}", "--track", "99"],
     "--track 99: no such track"),
    ("reid-query-ambiguous-track", ["reid", "query", "{QUERY_DB}", "--track", "1"],
     "observers 1, 2 of"),
    ("reid-query-track-of-other-observer", ["reid", "query", "{QUERY_DB}", "--track", "3",
                                            "--observer", "2"], "observer 2 of"),
    ("reid-query-unknown-observer", ["reid", "query", "{QUERY_DB}", "--track", "1",
                                     "--observer", "9"], "--observer 9: not an observer"),
    ("reid-query-track-without-crops", ["reid", "query", "{QUERY_DB}", "--track", "3"],
     "has no embedded crops"),
    ("reid-query-unreadable-image", ["reid", "query", "{QUERY_DB}", "--image",
                                     "{GARBAGE_XODR}"], "not a readable image"),
    ("reid-query-missing-image", ["reid", "query", "{QUERY_DB}", "--image", "{MISSING}.jpg"],
     "no such file"),
    ("reid-query-k-zero", ["reid", "query", "{QUERY_DB}", "--track", "2", "--k", "0"],
     "argument --k: expected an integer >= 1"),
    ("reid-query-no-query", ["reid", "query", "{QUERY_DB}"],
     "one of the arguments --image --track is required"),
    ("reid-query-image-and-track", ["reid", "query", "{QUERY_DB}", "--image", "{QUERY_JPG}",
                                    "--track", "2"], "not allowed with argument"),
    ("reid-query-observer-alone", ["reid", "query", "{QUERY_DB}", "--image", "{QUERY_JPG}",
                                   "--observer", "1"], "--observer goes with --track"),
    ("reid-query-aggregate", ["reid", "query", "{QUERY_DB}", "--track", "2", "--aggregate",
                              "max"], "argument --aggregate: invalid choice"),
    ("reid-query-dim-mismatch", ["reid", "query", "{DIM_DB}", "--image", "{QUERY_JPG}"],
     "-d vectors but"),
    ("reid-query-sheet-exists", ["reid", "query", "{QUERY_DB}", "--track", "2", "-o",
                                 "{OUT_PNG}"], "--overwrite"),
    ("reid-query-sheet-suffix", ["reid", "query", "{QUERY_DB}", "--track", "2", "-o",
                                 "{NEW_FILE}"], "name a .png file"),
    # --- malformed files and values that used to end in a traceback or a silent answer
    ("map-info-length-not-a-number", ["map", "info", "{ABC_LENGTH_XODR}"],
     "line 1: <road> length='abc' is not a number"),
    ("map-info-width-not-a-number", ["map", "info", "{ABC_WIDTH_XODR}"],
     "<width> a='abc' is not a number"),
    ("simulate-xodr-named-by-path", ["simulate", "--town", "{GARBAGE_XODR}", "-o", "{NEW_DIR}"],
     "garbage.xodr is not OpenDRIVE"),
    ("bench-reconstruct-no-driving-lane", ["bench-reconstruct", "--map", "{SIDEWALK_XODR}",
                                           "--trips", "1"], "no driving lane"),
    ("score-not-utf8", ["score", "--truth", "{TRUTH}", "--estimate", "{LATIN_CSV}"],
     "latin.csv: not UTF-8 text"),
    ("reconstruct-not-utf8", ["reconstruct", "--map", "town01", "--sightings", "{LATIN_CSV}",
                              "-o", "{NEW_FILE}"], "latin.csv: not UTF-8 text"),
    ("score-resample-too-fine", ["score", "--truth", "{TRUTH}", "--estimate", "{TRUTH}",
                                 "--resample-m", "1e-300"], "--truth would become 1e+301 points"),
    ("reconstruct-turn-cost-huge", ["reconstruct", "--map", "town01", "--sightings",
                                    "{SIGHTINGS}", "-o", "{NEW_FILE}", "--turn-cost", "1e308"],
     "--turn-cost 1e+308 m per radian is more than 1000"),
    ("reconstruct-pose-sigma", ["reconstruct", "--map", "town01", "--sightings",
                                "{SIGHTINGS}", "-o", "{NEW_FILE}", "--pose-sigma", "1,-1"],
     "argument --pose-sigma: expected XY_M,YAW_DEG"),
    ("reconstruct-pose-sigma-method", ["reconstruct", "--map", "town01", "--sightings",
                                       "{SIGHTINGS}", "-o", "{NEW_FILE}", "--method",
                                       "shortest-path", "--pose-sigma", "1,1"],
     "--pose-sigma applies to --method hmm only"),
    ("simulate-step-tiny", ["simulate", "--duration", "2", "--step", "1e-9", "-o", "{NEW_DIR}"],
     "step_s must be at least 0.001 s"),
    ("simulate-classes-empty", ["simulate", "--vehicle-classes", "car,,bus", "-o", "{NEW_DIR}"],
     "has an empty class between commas"),
    ("sightings-meta-fov-text", ["sightings", "{REC_FOV_TEXT}", "-o", "{NEW_FILE}"],
     "camera fov_deg must be a number in [1, 179], got 'abc'"),
    ("sightings-meta-fov-negative", ["sightings", "{REC_FOV_NEGATIVE}", "-o", "{NEW_FILE}"],
     "camera fov_deg must be a number in [1, 179], got -90"),
    ("sightings-meta-version-text", ["sightings", "{REC_VERSION_TEXT}", "-o", "{NEW_FILE}"],
     "format_version must be an integer, got 'x'"),
    ("sightings-meta-array", ["sightings", "{REC_META_ARRAY}", "-o", "{NEW_FILE}"],
     "is not a dashtraj-recording meta file"),
    ("sightings-meta-map-text", ["sightings", "{REC_MAP_TEXT}", "-o", "{NEW_FILE}"],
     "map must be an object"),
    ("sightings-meta-observers-text", ["sightings", "{REC_OBSERVERS_TEXT}", "-o", "{NEW_FILE}"],
     "observer_ids must be a list of integers"),
    ("sightings-vehicles-not-utf8", ["sightings", "{REC_VEHICLES_LATIN}", "-o", "{NEW_FILE}"],
     "vehicles.csv: not UTF-8 text"),
    ("sightings-oracle-tracker", ["sightings", "{REC}", "--tracker", "sort", "-o", "{NEW_FILE}"],
     "--tracker applies to the camera pipeline"),
    ("sightings-oracle-sample", ["sightings", "{REC}", "--sample", "1", "-o", "{NEW_FILE}"],
     "--sample applies to the camera pipeline"),
    ("sightings-export-folder", ["sightings", "export", "{OUT_DIR}", "-o", "{NEW_FILE}"],
     "is a folder, not a file"),
    ("sightings-export-bad-run-row", ["sightings", "export", "{BAD_RUN_DB}", "-o",
                                      "{NEW_FILE}"], "the run row's camera is not a JSON object"),
    ("reid-threshold-no-image-size", ["reid-threshold", "{QUERY_DB}", "-o", "{NEW_FILE}"],
     "the run's camera has no image size"),
    ("reid-eval-data-is-file", ["reid", "eval", "--data", "{TRUTH}"], "a file, not a folder"),
    ("reid-eval-no-cross-camera-match", ["reid", "eval", "--data", "{VERI_ONE_CAMERA}"],
     "nothing to rank"),
    ("reid-moving-bad-json", ["reid", "moving-queries", "{REID_BAD_JSON}", "{REC}"],
     "reid.json is not valid JSON"),
    ("reid-moving-train-no-config", ["reid", "moving-train", "{REID_NO_CONFIG}", "{REC}"],
     'has no "config" object'),
    ("reid-query-image-is-folder", ["reid", "query", "{QUERY_DB}", "--image", "{OUT_DIR}"],
     "a folder, not an image file"),
    ("detector-eval-size-huge", ["detector", "eval", "{REC}", "--size", "100000x100000"],
     "argument --size: expected each side of WxH in 8..8192 pixels"),
    ("reid-dataset-image-size-huge", ["reid-dataset", "--image-size", "100000x100000", "-o",
                                      "{NEW_DIR}"],
     "argument --image-size: expected each side of WxH in 8..8192 pixels"),
    ("detector-eval-external-label-outside", ["detector", "eval-external", "{EXT_OUTSIDE}",
                                              "--names", "vehicle"],
     "normalised to 0..1, got '0 5 5 0.2 0.2'"),
    ("detector-eval-external-names-not-utf8", ["detector", "eval-external", "{EXT_LATIN}"],
     "classes.txt: not UTF-8 text"),
    ("no-command", [], "the following arguments are required: COMMAND"),
    ("unknown-command", ["frobnicate"], "invalid choice: 'frobnicate'"),
    # --- reidentify
    ("reidentify-track-format", ["reidentify", "{CROPS_DB}", "--track", "1-2", "--map",
                                 "town01", "-o", "{NEW_FILE}"],
     "argument --track: expected OBSERVER:TRACK"),
    ("reidentify-missing-db", ["reidentify", "{MISSING}.db", "--track", "1:2", "--map",
                               "town01", "-o", "{NEW_FILE}"], "does not exist"),
    ("reidentify-bad-map", ["reidentify", "{CROPS_DB}", "--track", "1:2", "--map", "town99",
                            "-o", "{NEW_FILE}"], "--map 'town99' is neither a file"),
    ("reidentify-exists", ["reidentify", "{CROPS_DB}", "--track", "1:2", "--map", "town01",
                           "-o", "{OUT_FILE}"], "--overwrite"),
    # --- the CARLA bridge (no server here: refused before connecting, or unreachable)
    ("carla-record-every-big", ["carla-record", "-o", "{NEW_DIR}", "--every", "0.5"],
     "--every 0.5: CARLA's physics needs a step of at most 0.1 s"),
    ("carla-record-fov", ["carla-record", "-o", "{NEW_DIR}", "--fov", "200"],
     "camera fov_deg must be a number in [1, 179]"),
    ("carla-record-exists", ["carla-record", "-o", "{OUT_DIR}"], "--overwrite"),
    ("carla-record-no-server", ["carla-record", "-o", "{NEW_DIR}", "--port", "2999",
                                "--timeout", "0.3"], "no CARLA server answered at localhost:2999"),
    # --- PostgreSQL targets (no server needed: refused before connecting, or unreachable)
    ("sightings-copy-missing-src", ["sightings-copy", "{MISSING}.db", "-o", "{NEW_FILE}"],
     "does not exist"),
    ("sightings-copy-exists", ["sightings-copy", "{CROPS_DB}", "-o", "{OUT_FILE}"],
     "--overwrite"),
    ("sightings-copy-foreign", ["sightings-copy", "{FOREIGN_DB}", "-o", "{NEW_FILE}"],
     "not a dashtraj sightings database"),
    ("sightings-copy-bad-schema", ["sightings-copy", "{CROPS_DB}", "-o",
                                   "postgresql:///x?schema=Bad-Name"],
     "schema 'Bad-Name' must be lower-case letters"),
    ("perceive-pg-schema-digit", ["perceive", "{REC}", "-o", "postgresql:///x?schema=1run"],
     "schema '1run' must be lower-case letters"),
    ("perceive-pg-schema-long", ["perceive", "{REC}", "-o", "postgresql:///x?schema=" + "r" * 50],
     "at most 48 characters"),
    ("perceive-pg-unreachable", ["perceive", "{REC}", "-o",
                                 "postgresql://u:secret@/db?host={MISSING}&schema=r"],
     "postgresql://u:***@/db?host="),
    ("sightings-export-pg-unreachable", ["sightings", "export", "postgresql:///db?host={MISSING}",
                                         "-o", "{NEW_FILE}"], "cannot connect"),
]


def _tree(root: Path) -> dict[str, str]:
    """Every path under root → sha256 of its bytes ("dir" for folders)."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        out[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, str]:
    """A small complete recording and sightings CSVs made from it (read-only inputs)."""
    root = tmp_path_factory.mktemp("inputs")
    rec = root / "rec"
    assert main(["simulate", "--town", "town01", "--duration", "20", "--agents", "4",
                 "--seed", "1", "-q", "-o", str(rec)]) == 0
    sightings = root / "sightings.csv"
    rows = [
        "t,observer_id,observer_x,observer_y,observer_yaw,x,y,orientation,vehicle_class",
        "0.0,1,150.0,55.0,0.0,160.0,55.5,back,car",
        "1.0,1,155.0,55.0,0.0,165.0,55.5,back,car",
    ]
    sightings.write_text("\n".join(rows) + "\n")
    far = root / "far.csv"
    far.write_text("\n".join([rows[0], "0.0,1,1e6,1e6,0.0,1e6,1e6,back,car"]) + "\n")
    nan = root / "nan.csv"
    nan.write_text("\n".join([rows[0], rows[1], "1.0,1,155.0,55.0,0.0,nan,55.5,back,car"])
                   + "\n")
    truth = root / "truth.csv"
    truth.write_text("x,y\n0,0\n10,0\n")
    garbage = root / "garbage.xodr"
    garbage.write_text("not xml at all")
    dbs = _sightings_dbs(root)
    return {"REC": str(rec), "SIGHTINGS": str(sightings), "FAR_CSV": str(far),
            "NAN_CSV": str(nan), "TRUTH": str(truth), "GARBAGE_XODR": str(garbage),
            **dbs, **_broken_inputs(root, rec, Path(dbs["QUERY_DB"]))}


ONE_ROAD_XODR = (
    '<OpenDRIVE><header/><road id="1" length="{length}" junction="-1"><planView>'
    '<geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry></planView><lanes>'
    '<laneSection s="0"><center><lane id="0" type="none"/></center><right>'
    '<lane id="-1" type="{lane}"><width sOffset="0" a="{width}" b="0" c="0" d="0"/></lane>'
    '</right></laneSection></lanes></road></OpenDRIVE>')


def _broken_inputs(root: Path, rec: Path, query_db: Path) -> dict[str, str]:
    """Inputs that are broken in one way each: maps with a non-numeric attribute or no
    driving lane, a Latin-1 CSV, copies of the recording with a bad meta.json entry or
    vehicles.csv, a sightings database whose run row is not JSON, ReID and detection sets
    that cannot be scored."""
    import json
    import shutil
    import sqlite3

    from PIL import Image

    out: dict[str, Path] = {}
    for key, kw in (("ABC_LENGTH_XODR", {"length": "abc", "lane": "driving", "width": "3.5"}),
                    ("ABC_WIDTH_XODR", {"length": "100", "lane": "driving", "width": "abc"}),
                    ("SIDEWALK_XODR", {"length": "100", "lane": "sidewalk", "width": "3.5"})):
        out[key] = root / f"{key.lower()}.xodr"
        out[key].write_text(ONE_ROAD_XODR.format(**kw))
    out["LATIN_CSV"] = root / "latin.csv"
    out["LATIN_CSV"].write_bytes(b"x,y\n0,0\n10,0\n# caf\xe9\n")
    meta = json.loads((rec / "meta.json").read_text())

    def broken(key: str, change) -> None:
        out[key] = root / key.lower()
        shutil.copytree(rec, out[key])
        m = json.loads(json.dumps(meta))
        m = change(m)
        (out[key] / "meta.json").write_text(json.dumps(m))

    def camera(value):
        def change(m):
            m["config"]["camera"]["fov_deg"] = value
            return m
        return change

    broken("REC_FOV_TEXT", camera("abc"))
    broken("REC_FOV_NEGATIVE", camera(-90))
    broken("REC_VERSION_TEXT", lambda m: {**m, "format_version": "x"})
    broken("REC_META_ARRAY", lambda m: [1, 2])
    broken("REC_MAP_TEXT", lambda m: {**m, "map": "town10"})
    broken("REC_OBSERVERS_TEXT", lambda m: {**m, "observer_ids": "abc"})
    broken("REC_VEHICLES_LATIN", lambda m: m)
    vehicles = out["REC_VEHICLES_LATIN"] / "vehicles.csv"
    vehicles.write_bytes(vehicles.read_bytes() + b"# caf\xe9\n")
    out["BAD_RUN_DB"] = root / "bad_run.db"
    shutil.copy(query_db, out["BAD_RUN_DB"])
    con = sqlite3.connect(out["BAD_RUN_DB"])
    con.execute("UPDATE run SET camera = 'not json'")
    con.commit()
    con.close()
    out["VERI_ONE_CAMERA"] = root / "veri_one_camera"
    for split, name in (("image_query", "0001_c001_a.jpg"), ("image_test", "0001_c001_b.jpg")):
        (out["VERI_ONE_CAMERA"] / split).mkdir(parents=True)
        Image.new("RGB", (32, 32), (90, 40, 20)).save(out["VERI_ONE_CAMERA"] / split / name)
    out["REID_BAD_JSON"] = root / "reid_bad_json"
    out["REID_BAD_JSON"].mkdir()
    (out["REID_BAD_JSON"] / "reid.json").write_text("{")
    out["REID_NO_CONFIG"] = root / "reid_no_config"
    out["REID_NO_CONFIG"].mkdir()
    (out["REID_NO_CONFIG"] / "reid.json").write_text("[1]")
    for key, label, names in (("EXT_OUTSIDE", b"0 5 5 0.2 0.2\n", b"vehicle\n"),
                              ("EXT_LATIN", b"0 0.5 0.5 0.2 0.2\n", b"v\xe9hicle\n")):
        out[key] = root / key.lower()
        (out[key] / "images").mkdir(parents=True)
        (out[key] / "labels").mkdir()
        Image.new("RGB", (64, 48), (90, 90, 90)).save(out[key] / "images" / "a.jpg")
        (out[key] / "labels" / "a.txt").write_bytes(label)
        (out[key] / "classes.txt").write_bytes(names)
    return {k: str(v) for k, v in out.items()}


def _sightings_dbs(root: Path) -> dict[str, str]:
    """Sightings databases for `reid embed` / `reid query`: without crops, with crops (two
    observers, each with a track 1 and a track 2; observer 1 also a track 3 seen beyond
    the crop range), the same embedded, one with 8-d vectors under the shipped model's
    sha256, a foreign SQLite file, and a query JPEG."""
    import io
    import shutil
    import sqlite3

    import numpy as np
    from PIL import Image

    from dashtraj.reid.database import embed_database, file_sha256
    from dashtraj.reid.embed import ReidEmbedder, shipped_model_path
    from dashtraj.store import CropRow, DetectionRow, PoseRow, SightingsDB, TrackRow

    def jpeg(colour) -> bytes:
        buf = io.BytesIO()
        Image.new("RGB", (40, 30), colour).save(buf, format="JPEG")
        return buf.getvalue()

    def write(path: Path, with_crops: bool) -> None:
        with SightingsDB.create(path) as db:
            db.write_run("rec", "town01", None, {}, {}, [(1, None), (2, None)])
            for o in (1, 2):
                poses = [PoseRow(o, f, f * 0.1, 0, 0, 0, 0, 0, 0, 1.6, 0, 0) for f in range(3)]
                dets = [DetectionRow(o, f, i, f * 0.1, i + 1, 0, 0, 40, 30, 0.9, 1, "car",
                                     "back", 30.0 if i == 2 else 8.0, 0, 0, 0, 0, None, None,
                                     None, None, None, None)
                        for f in range(3) for i in range(3 if o == 1 else 2)]
                crops = [CropRow(o, f, i, jpeg((80 * i, 200 - 60 * o, 40 * f)), 40, 30)
                         for f in range(3) for i in range(2)] if with_crops else []
                tracks = [TrackRow(o, i + 1, "car", 0.0, 0.2, 3, None)
                          for i in range(3 if o == 1 else 2)]
                db.add_frames(poses, dets, crops, tracks)

    out = {"EMPTY_DB": root / "empty.db", "CROPS_DB": root / "crops.db",
           "QUERY_DB": root / "query.db", "DIM_DB": root / "dim.db",
           "FOREIGN_DB": root / "foreign.db", "QUERY_JPG": root / "query.jpg"}
    write(out["EMPTY_DB"], False)
    write(out["CROPS_DB"], True)
    shutil.copy(out["CROPS_DB"], out["QUERY_DB"])
    with SightingsDB.open(out["QUERY_DB"], writable=True) as db:
        embed_database(db, ReidEmbedder())
    shutil.copy(out["CROPS_DB"], out["DIM_DB"])
    with SightingsDB.open(out["DIM_DB"], writable=True) as db:
        db.add_embeddings(shipped_model_path().name, file_sha256(shipped_model_path()),
                          [(1, 0, 0), (1, 0, 1)], np.eye(2, 8, dtype=np.float32))
    con = sqlite3.connect(out["FOREIGN_DB"])
    con.execute("CREATE TABLE t (a)")
    con.commit()
    con.close()
    out["QUERY_JPG"].write_bytes(jpeg((0, 140, 40)))
    return {k: str(v) for k, v in out.items()}


def _run(argv: list[str], capsys) -> tuple[int, str]:
    capsys.readouterr()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            rc = main(argv)
    except SystemExit as exc:  # argparse's usage errors
        rc = exc.code
    return rc, capsys.readouterr().err


@pytest.mark.parametrize("argv,fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_exits_2_with_one_line_and_touches_nothing(argv, fragment, inputs, tmp_path,
                                                             capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    work = tmp_path / "work"
    (work / "out_dir" / "sub").mkdir(parents=True)
    (work / "out_dir" / "meta.json").write_text('{"complete": true, "old": 1}\n')
    (work / "out_dir" / "sub" / "000001.jpg").write_bytes(bytes(range(256)))
    (work / "out_file.csv").write_text("x,y\n1,2\n")
    (work / "out.png").write_bytes(b"\x89PNG old picture")
    places = {**inputs,
              "OUT_DIR": str(work / "out_dir"), "OUT_FILE": str(work / "out_file.csv"),
              "OUT_PNG": str(work / "out.png"), "NEW_DIR": str(work / "new_dir"),
              "NEW_FILE": str(work / "new_file.csv"), "NEW_PNG": str(work / "new.png"),
              "MISSING": str(tmp_path / "missing"), "TMP": str(tmp_path)}
    argv = [a.format(**places) for a in argv]
    before = _tree(work)

    rc, err = _run(argv, capsys)

    lines = err.splitlines()
    assert rc == 2, err
    assert len(lines) == 1, err
    assert fragment in lines[0], lines[0]
    assert "Traceback" not in err
    assert _tree(work) == before  # byte for byte, and nothing added beside it


def test_the_table_covers_every_command_that_takes_arguments():
    from dashtraj.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    covered = {c[1][0] for c in CASES if c[1]}
    missing = sorted(set(sub.choices) - covered)
    assert not missing, (f"add bad-input rows to CASES in tests/test_cli_bad_inputs.py for "
                         f"the new command(s) {', '.join(missing)}")


def test_reconstruct_creates_missing_parent_folders(inputs, tmp_path, capsys):
    out = tmp_path / "missing" / "dir" / "x.csv"
    rc, err = _run(["reconstruct", "--map", "town01", "--sightings", inputs["SIGHTINGS"],
                    "-o", str(out)], capsys)
    assert rc == 0, err
    assert out.read_text().startswith("x,y,t\n")
    assert [p.name for p in out.parent.iterdir()] == ["x.csv"]  # no temporary left


def test_reconstruct_drops_off_road_sightings_and_says_which(inputs, tmp_path, capsys):
    src = Path(inputs["SIGHTINGS"]).read_text().splitlines()
    mixed = tmp_path / "mixed.csv"
    mixed.write_text("\n".join([src[0], src[1], "", "0.5,1,150,55,0,1e6,1e6,back,car",
                                src[2]]) + "\n")
    out = tmp_path / "t.csv"
    rc, err = _run(["reconstruct", "--map", "town01", "--sightings", str(mixed), "-o", str(out),
                    "--json"], capsys)
    assert rc == 0, err
    assert err.splitlines() == [err.strip()]
    assert err.startswith("warning: ")
    assert "dropped 1 of 3 sightings" in err and "line 4 (1e+06, 1e+06) 14137" in err
    with_far = out.read_text()
    clean = tmp_path / "clean.csv"
    assert main(["reconstruct", "--map", "town01", "--sightings", inputs["SIGHTINGS"], "-o",
                 str(clean)]) == 0
    assert with_far == clean.read_text()  # the far sighting did not bend the route


def test_overwrite_replaces_an_output_whole(inputs, tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "stale.jpg").write_bytes(b"old frame")
    (out / "meta.json").write_text("{}")
    rc, err = _run(["simulate", "--town", "town01", "--duration", "1", "--agents", "2", "-q",
                    "-o", str(out), "--overwrite"], capsys)
    assert rc == 0, err
    names = sorted(p.name for p in out.iterdir())
    assert names == ["map.xodr", "meta.json", "states.parquet", "target_route.csv",
                     "truth.parquet", "vehicles.csv"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_interrupted_simulate_keeps_partial_in_its_own_folder(tmp_path, capsys, monkeypatch):
    from dashtraj.world import traffic
    from dashtraj.world.recording import IncompleteRecordingWarning, Recording

    out = tmp_path / "run"
    out.mkdir()
    (out / "meta.json").write_text('{"complete": true}\n')
    before = _tree(out)
    real_step = traffic.TrafficSim.step
    calls = [0]

    def step(self):  # Ctrl-C after 15 simulated seconds (300 steps of 0.05 s)
        calls[0] += 1
        if calls[0] > 300:
            raise KeyboardInterrupt
        return real_step(self)

    monkeypatch.setattr(traffic.TrafficSim, "step", step)
    rc, err = _run(["simulate", "--town", "town01", "--duration", "60", "--agents", "4",
                    "--no-until-target-arrives", "-q", "-o", str(out), "--overwrite"], capsys)
    assert rc == 130
    partial = tmp_path / "run.partial-1"
    assert f"kept the partial output in {partial}" in err
    assert _tree(out) == before  # the older recording is untouched
    with pytest.warns(IncompleteRecordingWarning):
        rec = Recording.open(partial)
    assert rec.meta["complete"] is False
    assert rec.meta["simulated_to_t"] == pytest.approx(15.0)
    assert rec.states.num_rows > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "run.partial-1"]


def test_sigterm_is_handled_as_ctrl_c(tmp_path):
    """`kill`, `timeout` and job schedulers send SIGTERM: the command stops as on Ctrl-C
    (exit 143, one line), the older output is untouched, the partial recording is kept in
    its own folder and no temporary folder is left behind."""
    import signal
    import subprocess
    import time

    out = tmp_path / "run"
    out.mkdir()
    (out / "meta.json").write_text('{"complete": true}\n')
    before = _tree(out)
    proc = subprocess.Popen(
        [sys.executable, "-m", "dashtraj", "simulate", "--town", "town01", "--duration", "3000",
         "--agents", "4", "--no-until-target-arrives", "-q", "-o", str(out), "--overwrite"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not any(p.name.startswith(".run.") for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(1.0)  # some simulated time
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert "dashtraj: terminated; outputs are written whole or not at all" in err
    assert _tree(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "run.partial-1"]


def test_target_route_ends_at_arrival_when_the_run_goes_on(tmp_path, capsys):
    from dashtraj.world.recording import Recording

    out = tmp_path / "run"
    rc, err = _run(["simulate", "--town", "town01", "--duration", "200", "--agents", "2",
                    "--seed", "3", "--no-until-target-arrives", "-q", "-o", str(out)], capsys)
    assert rc == 0, err
    rec = Recording.open(out)
    arrived = rec.meta["target_arrived_t"]
    assert arrived is not None and arrived < 190
    assert rec.meta["simulated_to_t"] == pytest.approx(200.0)
    assert rec.target_route.t[-1] == pytest.approx(arrived)
    with open(out / "target_route.csv", newline="") as fh:
        assert len(list(csv.reader(fh))) - 1 == len(rec.target_route)


def test_simulate_stops_at_arrival_by_default(tmp_path, capsys):
    from dashtraj.world.recording import Recording

    out = tmp_path / "run"
    rc, err = _run(["simulate", "--town", "town01", "--duration", "200", "--agents", "2",
                    "--seed", "3", "-q", "-o", str(out)], capsys)
    assert rc == 0, err
    rec = Recording.open(out)
    assert rec.meta["simulated_to_t"] == pytest.approx(rec.meta["target_arrived_t"])


def test_warnings_print_in_one_clean_style(tmp_path, capsys):
    bad = tmp_path / "s.csv"
    bad.write_text("x,y,colour\n0,0,red\n10,0,red\n")
    rc, err = _run(["score", "--truth", str(bad), "--estimate", str(bad)], capsys)
    assert rc == 0
    assert err == "warning: s.csv: ignoring unknown column(s) 'colour'\n" * 2  # both files


def test_a_recording_with_another_runs_map_is_refused(inputs, tmp_path, capsys):
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(inputs["REC"], rec)
    (rec / "map.xodr").write_bytes((rec / "map.xodr").read_bytes() + b"\n")
    rc, err = _run(["sightings", str(rec), "-o", str(tmp_path / "s.csv")], capsys)
    assert rc == 2
    assert err.count("\n") == 1 and "is not the map meta.json names" in err
    assert not (tmp_path / "s.csv").exists()
