"""sha256 digests of files: what identifies a model file (embeddings, thresholds) and the
source of a perception run (`dashtraj.perception.pipeline.source_sha256`)."""

from __future__ import annotations

import hashlib
from pathlib import Path


def file_sha256(path: str | Path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def files_sha256(root: str | Path, names: tuple[str, ...]) -> str:
    """Hex sha256 over the files ``names`` of the folder ``root`` that exist: each one's
    name and its own sha256 in the order given (a missing one counts as absent, so a folder
    with a file and one without it differ)."""
    h = hashlib.sha256()
    for name in names:
        p = Path(root) / name
        h.update(name.encode() + b"\0")
        h.update((file_sha256(p) if p.is_file() else "-").encode() + b"\n")
    return h.hexdigest()
