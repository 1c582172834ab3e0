"""store: the sightings database (layer 3; imports roads and trajectory only).

One database per perception run (SQLite by default, one file; the SQL is plain DB-API
so that a PostgreSQL connection can take the same repository later). See
`dashtraj.store.db` for the tables, the embeddings API and `SightingsDB` for the
repository.
"""

from dashtraj.store.db import (
    FORMAT,
    SCHEMA_VERSION,
    CropRow,
    DetectionRow,
    EmbeddingModel,
    EmbeddingSet,
    LocationUpdate,
    PoseRow,
    SightingsDB,
    StoreError,
    TrackRow,
)

__all__ = ["FORMAT", "SCHEMA_VERSION", "CropRow", "DetectionRow", "EmbeddingModel",
           "EmbeddingSet", "LocationUpdate",
           "PoseRow", "SightingsDB", "StoreError", "TrackRow"]
