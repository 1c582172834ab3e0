"""Embedding the crops of a sightings database (``dashtraj reid embed DB``).

`embed_database` adds, for every crop of the database that has no vector of the model
yet, the model's L2-normalised embedding (`dashtraj.reid.embed`), keyed by the crop and
the sha256 of the model file (`dashtraj.store.SightingsDB.add_embeddings`):

- idempotent: a rerun with the same model adds nothing; another model file (another
  sha256) adds its own rows beside the first;
- crash-safe: crops are read in pages of ``batch_size`` in key order and each page's
  vectors are committed in one transaction before the next page is read; a run killed
  at any point leaves whole committed pages (never a half-written one), and a rerun
  embeds only what is still missing.

Example:
    >>> with SightingsDB.open("run.db", writable=True) as db:  # doctest: +SKIP
    ...     s = embed_database(db, ReidEmbedder())
    >>> s.added, s.crops_per_s  # doctest: +SKIP
    (812, 310.4)
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from dataclasses import dataclass

from dashtraj.digest import file_sha256
from dashtraj.errors import DashtrajError
from dashtraj.reid.embed import ReidEmbedder
from dashtraj.store import SightingsDB, StoreError


class EmbedError(DashtrajError):
    """A database that cannot be embedded (no crops, a crop that is not an image)."""


def model_dim(embedder: ReidEmbedder) -> int | None:
    """The embedding size the ONNX model declares (None when its output is dynamic)."""
    shape = embedder.session.get_outputs()[0].shape
    return shape[-1] if len(shape) == 2 and isinstance(shape[-1], int) else None


@dataclass(frozen=True, slots=True)
class EmbedSummary:
    """What one `embed_database` call did.

    Attributes:
        model, model_sha256, dim: the model (file name, file sha256, vector size).
        crops: crops in the database. already: those that had a vector of the model
            before the call. added: vectors written by the call. batches: transactions.
        wall_s: seconds spent decoding, embedding and writing.
    """

    model: str
    model_sha256: str
    dim: int
    crops: int
    already: int
    added: int
    batches: int
    wall_s: float

    @property
    def crops_per_s(self) -> float:
        return self.added / self.wall_s if self.wall_s > 0 else 0.0


def decode_crop(jpeg: bytes, key: tuple[int, int, int]):
    """A crop's JPEG bytes → Pillow RGB image; `EmbedError` naming the crop otherwise."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(jpeg)) as im:
            return im.convert("RGB")
    except (UnidentifiedImageError, OSError) as exc:
        raise EmbedError(f"crop (observer {key[0]}, frame {key[1]}, idx {key[2]}) is not a "
                         f"readable image: {exc}") from exc


def check_model_fits(db: SightingsDB, embedder: ReidEmbedder, sha: str) -> int | None:
    """The model's declared dim, after checking it against its rows already in ``db``.

    Raises:
        StoreError: the database holds vectors of this model file with another size.
    """
    dim = model_dim(embedder)
    for m in db.embedding_models():
        if m.model_sha256 == sha and dim is not None and m.dim != dim:
            raise StoreError(f"{db.path} holds {m.dim}-d embeddings of model {m.model} "
                             f"(sha256 {sha[:12]}...) but {embedder.path.name} outputs "
                             f"{dim}-d vectors; the file was written by another tool")
    return dim


def embed_database(db: SightingsDB, embedder: ReidEmbedder, batch_size: int = 64,
                   progress: Callable[[int], None] | None = None) -> EmbedSummary:
    """Add the model's vector to every crop of ``db`` that lacks one (module docstring).

    Args:
        db: a database opened with ``writable=True``.
        embedder: the ONNX model (its file's sha256 keys the rows).
        batch_size: crops per page and per transaction.
        progress: called with the number of crops embedded after each committed page.

    Raises:
        EmbedError: the database has no crops; a crop is not a readable image.
        StoreError: the database holds vectors of this model with another size.
        ValueError: ``batch_size`` < 1, or an embedder with ``flip`` (its vectors would
            share the model's rows with plain ones).
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if getattr(embedder, "flip", False):
        raise ValueError(f"{embedder.path.name}: the embeddings table keys rows by the model "
                         "file alone; embed without flip test-time augmentation")
    n_crops = db.count("crops")
    if n_crops == 0:
        raise EmbedError(f"{db.path} has no crops (perceive keeps crops of detections within "
                         "its --reid-range); nothing to embed")
    sha = file_sha256(embedder.path)
    name = embedder.path.name
    dim = check_model_fits(db, embedder, sha)
    missing = db.count_missing_embeddings(sha)
    added = batches = 0
    after = None
    t0 = time.perf_counter()
    while True:
        page = db.crops_missing_embedding(sha, limit=batch_size, after=after)
        if not page:
            break
        keys = [(c.observer_id, c.frame, c.idx) for c in page]
        images = [decode_crop(c.jpeg, k) for c, k in zip(page, keys, strict=True)]
        vecs = embedder.embed(images, batch_size=batch_size)
        dim = int(vecs.shape[1])
        added += db.add_embeddings(name, sha, keys, vecs)
        batches += 1
        after = keys[-1]
        if progress is not None:
            progress(len(page))
    wall = time.perf_counter() - t0
    if dim is None:
        dim = next(m.dim for m in db.embedding_models() if m.model_sha256 == sha)
    return EmbedSummary(model=name, model_sha256=sha, dim=int(dim), crops=n_crops,
                        already=n_crops - missing, added=added, batches=batches, wall_s=wall)

