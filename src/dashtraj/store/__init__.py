"""store: the sightings database (layer 3; imports roads and trajectory only).

One database per perception run: an SQLite file by default, or one schema of a
PostgreSQL database for many writers (a ``postgresql://`` URL wherever a database path
is taken; `dashtraj.store.backend`). The SQL is written once over DB-API. See
`dashtraj.store.db` for the tables, the embeddings API and `SightingsDB` for the
repository, `dashtraj.store.pg_output` for how a run is published into PostgreSQL whole.
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
    copy_database,
)

__all__ = ["FORMAT", "SCHEMA_VERSION", "CropRow", "DetectionRow", "EmbeddingModel",
           "EmbeddingSet", "LocationUpdate",
           "PoseRow", "SightingsDB", "StoreError", "TrackRow", "copy_database"]
