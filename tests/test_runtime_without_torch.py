"""The run time needs numpy + onnxruntime only: importing the CLI, its commands and the
run-time layers never imports torch (training code lives in `dashtraj.train` and is
imported inside the training commands)."""

from __future__ import annotations

import subprocess
import sys

RUNTIME = ["dashtraj.cli", "dashtraj.experiments", "dashtraj.perception.pipeline",
           "dashtraj.perception.detect", "dashtraj.perception.detector_eval",
           "dashtraj.reid.embed", "dashtraj.reid.models", "dashtraj.reid.train",
           "dashtraj.reidentify.vision", "dashtraj.train"]


def test_runtime_modules_do_not_import_torch():
    import pkgutil

    import dashtraj.cli

    cmds = [f"dashtraj.cli.{m.name}" for m in pkgutil.iter_modules(dashtraj.cli.__path__)]
    code = ("import importlib, sys\n"
            f"for m in {RUNTIME + cmds!r}: importlib.import_module(m)\n"
            "print(sorted({k.split('.')[0] for k in sys.modules} "
            "& {'torch', 'ultralytics', 'torchvision'}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]", out
