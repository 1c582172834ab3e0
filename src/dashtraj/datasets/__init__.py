"""datasets: image datasets rendered from the built-in world.

Modules (import them directly; nothing is built or rendered on import):

- ``dashtraj.datasets.frames``: a recording's observer frames (camera pose from the
  observer's state and the recording's ``CameraSpec``, every other vehicle at its
  state) and the ``dashtraj render`` export (JPEGs + a labels table).
- ``dashtraj.datasets.detection``: a YOLO detection set (15 classes, class ×
  orientation) from recordings, split by recording.
- ``dashtraj.datasets.reid``: a VeRi-776-layout re-identification set after the
  paper's CARLA ReID dataset (§II.B): every identity alone on a straight road seen by
  a fixed ring of cameras, plus an optional query set from moving observers.
- ``dashtraj.datasets.preview``: boxes-and-labels PNGs and per-identity contact sheets
  for a person to check the labels and crops.
"""
