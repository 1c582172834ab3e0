"""Training-only code: the torch networks (needs the ``.[train]`` extra).

Nothing of the run time (perception, ReID embedding, the demo, experiments) imports this
package: it runs on numpy + onnxruntime and the ONNX files these networks export.

- `dashtraj.train.detector_model`: the vehicle detector (EfficientNet-Lite0 + PAN + an
  anchor-free head), trained by `dashtraj.train.detector_train` with a recipe of
  `dashtraj.train.detector_recipes` (a module without torch).
- `dashtraj.train.reid_nets`: the ReID backbones; build them by name with
  `dashtraj.reid.models.build_model`.
- `dashtraj.train.reid_ensemble`: exported ReID models joined into one ONNX and taken apart
  again (`dashtraj reid ensemble`, `reid member`; onnx, no torch).
"""
