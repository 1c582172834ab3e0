"""Vehicle re-identification (layer after perception).

- ``models``: the paper's six backbones and the small OSNets by name (torch, ``.[train]``);
- ``train``: recipes and the resumable training loop (torch); ``export``: ONNX export;
- ``evaluate``: the VeRi-776 protocol (CMC, mAP, mINP; numpy);
- ``preprocess`` / ``embed``: crops → L2-normalised embeddings (512-d; an ensemble's longer) on
  onnxruntime;
- ``gallery``: nearest-neighbour search over embeddings (faiss flat/IVF/HNSW, numpy);
- ``database``: embedding every crop of a sightings database into its ``embeddings``
  table (``dashtraj reid embed DB``; idempotent, committed page by page).

Run time (``embed``, ``gallery``, ``evaluate``) needs no torch. ``embed`` and
``gallery`` take crops and arrays, so the sightings database can feed them directly.
"""
