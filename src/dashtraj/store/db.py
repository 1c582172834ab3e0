"""The sightings database: tables, the repository that writes and reads them.

Tables (units: seconds, CARLA world metres, degrees, image pixels):

``meta``        key, value: ``format`` = "dashtraj-sightings", ``schema_version``;
                ``source_sha256`` (the recording's or drive's defining files) and
                ``detector_sha256`` (the model file, or "oracle"), written by
                ``perceive`` since appending observers (`dashtraj.store.append`).
``run``         one row: recording (path as given), map_name, map_sha256, camera (JSON
                `CameraSpec` of the images), config (JSON of the perception config),
                complete (1 once every observer finished).
``observers``   observer_id, role, frames written, complete.
``poses``       observer_id, frame, t, x, y, z, yaw (observer ground point), cam_x,
                cam_y, cam_z, cam_yaw, cam_pitch (its camera) — every processed frame.
``tracks``      observer_id, track_id, vehicle_class (majority of its detections),
                first_t, last_t, n_detections, truth_vehicle_id (the renderer's vehicle
                id the track's detections mostly belong to; evaluation only, NULL when
                unknown).
``detections``  observer_id, frame, idx (index in the frame), t, track_id (NULL while
                the tracker had not confirmed it), x0, y0, x1, y1, score, class_id,
                vehicle_class, orientation, distance_m, bearing_deg (signed, + right),
                x, y, z (estimated position), road_id, section_id, lane_id, s,
                lateral_m (map-matched waypoint and offset from its lane centre),
                truth_vehicle_id (the truth box it matches one to one at IoU >= 0.5,
                the detection protocol), depicted_vehicle_id (that match, else the
                vehicle most of its box shows: a duplicate or a part box of a vehicle
                included; what its crop is of);
                both evaluation only, NULL when unknown. The observer's
                pose is the ``poses`` row of the same (observer_id, frame).
``crops``       observer_id, frame, idx, jpeg (bytes), width, height: the image crop of
                each detection within the ReID range (15 m by default).
``embeddings``  observer_id, frame, idx (the crop), model (name), model_sha256 (of the
                model file), dim, vector (``dim`` little-endian float32, as the embedder
                returned them: L2-normalised for `dashtraj.reid.embed`); one row per crop
                and model, key (model_sha256, observer_id, frame, idx). Schema version 2.

Crops live in the database, not in files beside it: a crop is written in the same
transaction as its detection, so a run killed mid-way never has a detection without
its crop or an orphan file; one file per run is one thing to copy, check and replace
whole; crops are small (≈5–30 kB), where SQLite reads blobs as fast as a file system;
and PostgreSQL stores them the same way (``bytea``).

In PostgreSQL (`dashtraj.store.backend`) a run is a schema holding the same tables
(DOUBLE PRECISION for REAL, BYTEA for BLOB); every method below reads and writes it the
same way, and several processes may write one run at once (each its own observers).

Writing: `SightingsDB.create` (WAL journal) and one transaction per batch of frames
(`add_frames`): a killed run leaves every committed frame readable. A batch may also carry
`LocationUpdate` rows that rewrite the position columns of detections written before
(``perceive``'s offline ``smoothed`` localizer, in each observer's last batch: an observer
whose ``complete`` is 0 still has its forward estimates). Reading:
`SightingsDB.open` checks the file (SQLite header, integrity, format, schema
version) and raises `StoreError` naming it.

Schema versions and migration: ``meta.schema_version`` is 3 (1 had no ``embeddings``,
2 no ``detections.depicted_vehicle_id``). `SightingsDB.open` reads every version
read-only (a version-1 file simply has no embeddings, a version-2 file reads
``depicted_vehicle_id`` as None); ``SightingsDB.open(path, writable=True)`` upgrades an
older file in place, in one transaction (`_MIGRATIONS`). A newer version than this
dashtraj knows is refused.

Embeddings API (appearance vectors of the crops, written by ``dashtraj reid embed``):

- ``db = SightingsDB.open(path, writable=True)``: open to add embeddings (migrates).
- ``db.count_missing_embeddings(model_sha256) -> int``: crops without a vector of
  that model.
- ``db.crops_missing_embedding(model_sha256, limit=None, after=None) -> list[CropRow]``:
  those crops in key order (observer_id, frame, idx), at most ``limit``, keys after the
  key ``after`` (page through them: pass the last key of the previous page).
- ``db.add_embeddings(model, model_sha256, keys, vectors) -> int``: one transaction;
  ``keys`` [(observer_id, frame, idx)], ``vectors`` (N, dim) float32; a crop that has
  a vector of that model keeps it (returns the rows added). `StoreError` when a key
  has no crop, the vectors are not finite, or ``dim`` differs from the model's rows.
- ``db.embedding_models() -> list[EmbeddingModel]``: (model, model_sha256, dim, count)
  of every model with vectors in the file.
- ``db.embeddings(model_sha256, observer_id=None, track_id=None) -> EmbeddingSet``:
  the vectors with their detection's observer, frame, idx, track id, time, box,
  class, distance and truth (columns as arrays; `StoreError` naming the models
  present when the model has none).
- ``db.crops(keys=None)``: the crops (all, or those of the given keys, in key order).
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
from collections.abc import Iterable, Sequence
from dataclasses import astuple, dataclass, fields
from pathlib import Path

import numpy as np

from dashtraj.store.backend import (
    Dialect,
    PgDialect,
    StoreError,
    connect_pg,
    insert_sql,
    is_url,
    parse_url,
    quote_ident,
)
from dashtraj.trajectory.records import Sighting

FORMAT = "dashtraj-sightings"
SCHEMA_VERSION = 3
_SQLITE_MAGIC = b"SQLite format 3\x00"


@dataclass(frozen=True, slots=True)
class PoseRow:
    """One processed frame of one observer (units in the module docstring)."""

    observer_id: int
    frame: int
    t: float
    x: float
    y: float
    z: float
    yaw: float
    cam_x: float
    cam_y: float
    cam_z: float
    cam_yaw: float
    cam_pitch: float


@dataclass(frozen=True, slots=True)
class DetectionRow:
    """One detection (columns of ``detections``; None where unknown)."""

    observer_id: int
    frame: int
    idx: int
    t: float
    track_id: int | None
    x0: float
    y0: float
    x1: float
    y1: float
    score: float
    class_id: int
    vehicle_class: str
    orientation: str
    distance_m: float
    bearing_deg: float
    x: float
    y: float
    z: float
    road_id: int | None
    section_id: int | None
    lane_id: int | None
    s: float | None
    lateral_m: float | None
    truth_vehicle_id: int | None
    depicted_vehicle_id: int | None = None


@dataclass(frozen=True, slots=True)
class TrackRow:
    """One track of one observer (columns of ``tracks``)."""

    observer_id: int
    track_id: int
    vehicle_class: str
    first_t: float
    last_t: float
    n_detections: int
    truth_vehicle_id: int | None


@dataclass(frozen=True, slots=True)
class LocationUpdate:
    """A new position of a written detection (observer_id, frame, idx): the ``detections``
    columns distance_m … lateral_m (an offline localizer's smoothed estimate)."""

    observer_id: int
    frame: int
    idx: int
    distance_m: float
    bearing_deg: float
    x: float
    y: float
    z: float
    road_id: int | None
    section_id: int | None
    lane_id: int | None
    s: float | None
    lateral_m: float | None


@dataclass(frozen=True, slots=True)
class CropRow:
    """The JPEG crop of one detection (``crops``)."""

    observer_id: int
    frame: int
    idx: int
    jpeg: bytes
    width: int
    height: int


@dataclass(frozen=True, slots=True)
class EmbeddingModel:
    """A model with vectors in the file: name, sha256 of its file, vector size, rows."""

    model: str
    model_sha256: str
    dim: int
    count: int


@dataclass(frozen=True, eq=False)
class EmbeddingSet:
    """The vectors of one model with their detections' columns (row i = one crop).

    Attributes:
        model, model_sha256, dim: the model (name, sha256 of its file, vector size).
        observer_id, frame, idx: (N,) int64, the crop's (and its detection's) key.
        track_id: (N,) int64, the detection's track; -1 where the tracker had not
            confirmed it.
        t: (N,) float64, seconds. box: (N, 4) float64 x0, y0, x1, y1, image pixels.
        vehicle_class: N class names. distance_m: (N,) float64, estimated range.
        truth_vehicle_id: (N,) int64, the renderer's vehicle (-1 unknown; evaluation
            only). vectors: (N, dim) float32.
    Rows are in key order (observer_id, frame, idx).
    """

    model: str
    model_sha256: str
    dim: int
    observer_id: np.ndarray
    frame: np.ndarray
    idx: np.ndarray
    track_id: np.ndarray
    t: np.ndarray
    box: np.ndarray
    vehicle_class: tuple[str, ...]
    distance_m: np.ndarray
    truth_vehicle_id: np.ndarray
    vectors: np.ndarray

    def __len__(self) -> int:
        return len(self.observer_id)

    def keys(self) -> list[tuple[int, int, int]]:
        """[(observer_id, frame, idx)] of the rows."""
        return list(zip(self.observer_id.tolist(), self.frame.tolist(), self.idx.tolist(),
                        strict=True))


def _cols(cls) -> tuple[str, ...]:
    return tuple(f.name for f in fields(cls))


_DDL = (
    "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    "CREATE TABLE run (id INTEGER PRIMARY KEY CHECK (id = 1), recording TEXT NOT NULL, "
    "map_name TEXT, map_sha256 TEXT, camera TEXT NOT NULL, config TEXT NOT NULL, "
    "complete INTEGER NOT NULL DEFAULT 0)",
    "CREATE TABLE observers (observer_id INTEGER PRIMARY KEY, role TEXT, "
    "frames INTEGER NOT NULL DEFAULT 0, complete INTEGER NOT NULL DEFAULT 0)",
    "CREATE TABLE poses (observer_id INTEGER NOT NULL, frame INTEGER NOT NULL, t REAL NOT NULL, "
    "x REAL, y REAL, z REAL, yaw REAL, cam_x REAL, cam_y REAL, cam_z REAL, cam_yaw REAL, "
    "cam_pitch REAL, PRIMARY KEY (observer_id, frame))",
    "CREATE TABLE tracks (observer_id INTEGER NOT NULL, track_id INTEGER NOT NULL, "
    "vehicle_class TEXT, first_t REAL, last_t REAL, n_detections INTEGER, "
    "truth_vehicle_id INTEGER, PRIMARY KEY (observer_id, track_id))",
    "CREATE TABLE detections (observer_id INTEGER NOT NULL, frame INTEGER NOT NULL, "
    "idx INTEGER NOT NULL, t REAL NOT NULL, track_id INTEGER, x0 REAL, y0 REAL, x1 REAL, "
    "y1 REAL, score REAL, class_id INTEGER, vehicle_class TEXT, orientation TEXT, "
    "distance_m REAL, bearing_deg REAL, x REAL, y REAL, z REAL, road_id INTEGER, "
    "section_id INTEGER, lane_id INTEGER, s REAL, lateral_m REAL, truth_vehicle_id INTEGER, "
    "depicted_vehicle_id INTEGER, PRIMARY KEY (observer_id, frame, idx))",
    "CREATE INDEX detections_track ON detections (observer_id, track_id)",
    "CREATE TABLE crops (observer_id INTEGER NOT NULL, frame INTEGER NOT NULL, "
    "idx INTEGER NOT NULL, jpeg BLOB NOT NULL, width INTEGER, height INTEGER, "
    "PRIMARY KEY (observer_id, frame, idx))",
)
_EMBEDDINGS_DDL = (
    "CREATE TABLE embeddings (observer_id INTEGER NOT NULL, frame INTEGER NOT NULL, "
    "idx INTEGER NOT NULL, model TEXT NOT NULL, model_sha256 TEXT NOT NULL, "
    "dim INTEGER NOT NULL CHECK (dim > 0), vector BLOB NOT NULL "
    "CHECK (length(vector) = 4 * dim), PRIMARY KEY (model_sha256, observer_id, frame, idx), "
    "FOREIGN KEY (observer_id, frame, idx) REFERENCES crops (observer_id, frame, idx))",
)
_DDL = _DDL + _EMBEDDINGS_DDL
_MIGRATIONS: dict[int, tuple[str, ...]] = {
    2: _EMBEDDINGS_DDL,
    3: ("ALTER TABLE detections ADD COLUMN depicted_vehicle_id INTEGER",),
}
"""Statements that take a file from version v - 1 to v."""
_TABLES = ("meta", "run", "observers", "poses", "tracks", "detections", "crops", "embeddings")
_TABLES_V1 = _TABLES[:-1]
_VECTOR = np.dtype("<f4")


def _pg_types(cls) -> tuple[str, ...]:
    """PostgreSQL type names of a row class's columns, from its annotations (the DDL's
    INTEGER, REAL → DOUBLE PRECISION, TEXT, BLOB → BYTEA)."""
    names = {"int": "int4", "float": "float8", "str": "text", "bytes": "bytea"}
    return tuple(names[str(f.type).split(" | ")[0]] for f in fields(cls))


def _migrate(dialect: Dialect, path, version: int) -> None:
    """Upgrade an open file from ``version`` to `SCHEMA_VERSION` in one transaction."""
    try:
        if dialect.name == "sqlite":  # sqlite3 opens no transaction before DDL by itself
            dialect.execute("BEGIN IMMEDIATE")
        with dialect.transaction():
            for v in range(version + 1, SCHEMA_VERSION + 1):
                for stmt in _MIGRATIONS[v]:
                    dialect.execute(dialect.ddl(stmt))
            dialect.execute("UPDATE meta SET value = ? WHERE key = 'schema_version'",
                            (str(SCHEMA_VERSION),))
    except dialect.errors as exc:
        raise StoreError(f"{path}: cannot upgrade schema version {version} to "
                         f"{SCHEMA_VERSION}: {exc}") from exc


class SightingsDB:
    """Repository of one run's sightings database over a DB-API connection.

    Create with `SightingsDB.create(target)` (a new file, or a new schema of a PostgreSQL
    database: `dashtraj.store.backend`) or `SightingsDB.open(target)` (an existing one,
    read-only; ``writable=True`` to add embeddings); use as a context manager or call
    `close`. ``path`` is the file, or the URL without its password, for messages.
    """

    def __init__(self, dialect: Dialect, path, writable: bool, version: int = SCHEMA_VERSION):
        self.dialect = dialect
        self.conn = dialect.conn
        self.path = path
        self.writable = writable
        self.version = version  # the file's schema version (read-only files stay as they are)

    # ------------------------------------------------------------------ opening
    @classmethod
    def create(cls, target: str | Path) -> SightingsDB:
        """A new, empty database at ``target`` (must not exist): a file (WAL journal) or a
        PostgreSQL schema; tables and meta."""
        if is_url(target):
            return cls._create_pg(target)
        p = Path(target)
        if p.exists():
            raise StoreError(f"{p} exists; a sightings database is written whole into a new "
                             "file")
        conn = sqlite3.connect(str(p))
        conn.execute("PRAGMA foreign_keys=ON")
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
        db = cls(Dialect(conn), p, True)
        db._create_tables()
        return db

    @classmethod
    def _create_pg(cls, url: str) -> SightingsDB:
        target = parse_url(url)
        dialect = PgDialect(connect_pg(target), target.schema)
        try:
            with dialect.transaction():
                if dialect.schema_exists():
                    raise StoreError(f"{target.display} exists; a sightings database is written "
                                     "whole into a new schema")
                dialect.execute(f"CREATE SCHEMA {quote_ident(target.schema)}")
            dialect.use_schema()
            db = cls(dialect, target.display, True)
            db._create_tables()
        except BaseException:
            dialect.close()
            raise
        return db

    def _create_tables(self) -> None:
        with self.dialect.transaction():
            for stmt in _DDL:
                self.dialect.execute(self.dialect.ddl(stmt))
            self.dialect.many(insert_sql("meta", ("key", "value")),
                              [("format", FORMAT), ("schema_version", str(SCHEMA_VERSION))])

    @classmethod
    def open(cls, target: str | Path, check: bool = True, writable: bool = False) -> SightingsDB:
        """Open an existing database (a file, or a PostgreSQL URL), read-only unless
        ``writable``.

        ``writable`` is for adding embeddings: an older file is upgraded to the current
        schema first (one transaction; module docstring).

        Raises:
            StoreError: no such file or schema; not an SQLite file; truncated or corrupt
                (integrity check fails); not a dashtraj sightings database; a newer schema.
        """
        if is_url(target):
            pg = parse_url(target)
            dialect: Dialect = PgDialect(connect_pg(pg), pg.schema)
            where = pg.display
            try:
                if not dialect.schema_exists():
                    raise StoreError(f"{where}: no such schema; a run is written there by "
                                     "dashtraj perceive RUN -o URL")
                dialect.use_schema()
                if not writable:
                    dialect.execute("SET default_transaction_read_only = on")
            except BaseException:
                dialect.close()
                raise
        else:
            p = Path(target)
            where = p
            if not p.is_file():
                raise StoreError(f"sightings database {p} "
                                 + ("is a folder, not a file" if p.is_dir()
                                    else "does not exist"))
            with open(p, "rb") as fh:
                head = fh.read(len(_SQLITE_MAGIC))
            if head != _SQLITE_MAGIC:
                raise StoreError(f"{p} is not a sightings database (not an SQLite file)")
            dialect = Dialect(sqlite3.connect(
                f"{p.resolve().as_uri()}?mode={'rw' if writable else 'ro'}", uri=True))
        try:
            return cls._checked(dialect, where, check, writable)
        except BaseException:
            dialect.close()
            raise

    @classmethod
    def _checked(cls, dialect: Dialect, where, check: bool, writable: bool) -> SightingsDB:
        kind = "an SQLite file" if dialect.name == "sqlite" else "a PostgreSQL schema"
        try:
            if check and dialect.name == "sqlite":
                res = dialect.execute("PRAGMA quick_check").fetchone()
                if res is None or res[0] != "ok":
                    raise StoreError(f"{where} is corrupt: integrity check says {res[0]!r}")
            tables = dialect.tables()
            if "meta" not in tables:
                raise StoreError(f"{where} is {kind} but not a dashtraj sightings database "
                                 "(no meta table)")
            meta = dict(dialect.execute("SELECT key, value FROM meta").fetchall())
        except dialect.errors as exc:
            raise StoreError(f"{where} is truncated or corrupt: {exc}") from exc
        if meta.get("format") != FORMAT:
            raise StoreError(f"{where} is not a dashtraj sightings database (format "
                             f"{meta.get('format')!r})")
        try:
            version = int(meta.get("schema_version", ""))
        except ValueError:
            raise StoreError(f"{where}: bad schema_version "
                             f"{meta.get('schema_version')!r}") from None
        if version > SCHEMA_VERSION:
            raise StoreError(f"{where}: schema version {version} is newer than this dashtraj "
                             f"reads ({SCHEMA_VERSION}); upgrade dashtraj")
        missing = [t for t in (_TABLES if version >= 2 else _TABLES_V1) if t not in tables]
        if missing:
            raise StoreError(f"{where}: missing table {missing[0]!r}; the file is damaged")
        if writable:
            if dialect.name == "sqlite":
                dialect.execute("PRAGMA foreign_keys=ON")
            if version < SCHEMA_VERSION:
                _migrate(dialect, where, version)
                version = SCHEMA_VERSION
        return cls(dialect, where, writable, version)

    def close(self) -> None:
        """Commit nothing further, fold the WAL into the file and close.

        A writer leaves an SQLite file in its rollback-journal mode, one self-contained
        file: WAL is for the run while it is written (readers see every committed frame,
        a killed writer loses nothing committed), and a reader of a WAL file leaves its
        ``-wal`` and ``-shm`` files beside the user's database. (Another connection still
        open keeps the file in WAL mode: SQLite refuses the switch then.)"""
        if self.conn is None:
            return
        if self.writable and self.dialect.name == "sqlite":
            self.conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            with contextlib.suppress(sqlite3.OperationalError):  # a reader is still open
                self.conn.execute("PRAGMA journal_mode=DELETE")
        self.dialect.close()
        self.conn = None

    def __enter__(self) -> SightingsDB:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _need_writable(self) -> None:
        if not self.writable:
            raise StoreError(f"{self.path} was opened read-only")

    def _query(self, sql: str, args: Sequence = ()) -> list[tuple]:
        try:
            return self.dialect.execute(sql, tuple(args)).fetchall()
        except self.dialect.errors as exc:
            raise StoreError(f"{self.path} is truncated or corrupt: {exc}") from exc

    # ------------------------------------------------------------------ writing
    def write_run(self, recording: str, map_name: str | None, map_sha256: str | None,
                  camera: dict, config: dict, observers: Iterable[tuple[int, str | None]]) -> None:
        """The run row and one row per observer (id, role)."""
        self._need_writable()
        d = self.dialect
        with d.transaction():
            d.execute(insert_sql("run", ("id", "recording", "map_name", "map_sha256", "camera",
                                      "config")),
                      (1, str(recording), map_name, map_sha256,
                       json.dumps(camera, sort_keys=True), json.dumps(config, sort_keys=True)))
            d.many(insert_sql("observers", ("observer_id", "role")),
                   [(int(o), r) for o, r in observers])

    def add_frames(self, poses: Sequence[PoseRow], detections: Sequence[DetectionRow],
                   crops: Sequence[CropRow] = (), tracks: Sequence[TrackRow] = (),
                   updates: Sequence[LocationUpdate] = ()) -> None:
        """Write a batch of frames in one transaction (tracks are inserted or replaced;
        ``updates`` rewrite the positions of detections written before or in the batch;
        `StoreError` names one that has no detection)."""
        self._need_writable()
        d = self.dialect
        with d.transaction():
            for table, cls, rows in (("poses", PoseRow, poses),
                                     ("detections", DetectionRow, detections),
                                     ("crops", CropRow, crops)):
                d.insert(table, _cols(cls), [astuple(r) for r in rows], _pg_types(cls))
            d.many(insert_sql("tracks", _cols(TrackRow), key=("observer_id", "track_id")),
                   [astuple(r) for r in tracks])
            if updates:
                cols = _cols(LocationUpdate)[3:]
                sql = (f"UPDATE detections SET {', '.join(c + ' = ?' for c in cols)} "
                       "WHERE observer_id = ? AND frame = ? AND idx = ?")
                changed = d.many(sql, [astuple(r)[3:] + astuple(r)[:3] for r in updates])
                if changed != len(updates):
                    raise StoreError(f"{self.path}: a location update names a detection "
                                     "that is not in the file")
            by_obs: dict[int, int] = {}
            for r in poses:
                by_obs[r.observer_id] = by_obs.get(r.observer_id, 0) + 1
            d.many("UPDATE observers SET frames = frames + ? WHERE observer_id = ?",
                   [(n, o) for o, n in sorted(by_obs.items())])

    def finish_observer(self, observer_id: int) -> None:
        self._need_writable()
        with self.dialect.transaction():
            self.dialect.execute("UPDATE observers SET complete = 1 WHERE observer_id = ?",
                                 (int(observer_id),))

    def finish_run(self) -> None:
        self._need_writable()
        with self.dialect.transaction():
            self.dialect.execute("UPDATE run SET complete = 1 WHERE id = 1")

    def set_meta(self, items: dict[str, str]) -> None:
        """Add or replace ``meta`` rows (key, value) in one transaction."""
        self._need_writable()
        with self.dialect.transaction():
            self.dialect.many(insert_sql("meta", ("key", "value"), key=("key",)),
                              sorted(items.items()))

    # ------------------------------------------------------------------ reading
    def meta(self) -> dict[str, str]:
        """The ``meta`` rows as a dict (format, schema_version, and what a run adds:
        ``source_sha256``, ``detector_sha256``; `dashtraj.store.append`)."""
        return dict(self._query("SELECT key, value FROM meta"))

    def run_info(self) -> dict:
        """The run row as a dict (camera and config parsed)."""
        rows = self._query("SELECT recording, map_name, map_sha256, camera, config, complete "
                           "FROM run WHERE id = 1")
        if not rows:
            raise StoreError(f"{self.path} has no run row (written by a run that stopped "
                             "before it started)")
        r = rows[0]
        parsed = {}
        for key, text in (("camera", r[3]), ("config", r[4])):
            try:
                parsed[key] = json.loads(text)
            except (TypeError, json.JSONDecodeError):
                parsed[key] = None
            if not isinstance(parsed[key], dict):
                raise StoreError(f"{self.path}: the run row's {key} is not a JSON object "
                                 f"({str(text)[:40]!r})")
        return {"recording": r[0], "map_name": r[1], "map_sha256": r[2],
                "camera": parsed["camera"], "config": parsed["config"], "complete": bool(r[5])}

    def observers(self) -> list[dict]:
        return [{"observer_id": o, "role": r, "frames": n, "complete": bool(c)}
                for o, r, n, c in self._query("SELECT observer_id, role, frames, complete "
                                              "FROM observers ORDER BY observer_id")]

    def poses(self, observer_id: int | None = None) -> list[PoseRow]:
        sql = f"SELECT {', '.join(_cols(PoseRow))} FROM poses"
        args: tuple = ()
        if observer_id is not None:
            sql += " WHERE observer_id = ?"
            args = (int(observer_id),)
        return [PoseRow(*r) for r in self._query(sql + " ORDER BY observer_id, frame", args)]

    def detections(self, observer_id: int | None = None) -> list[DetectionRow]:
        cols = [c if c != "depicted_vehicle_id" or self.version >= 3 else "NULL"
                for c in _cols(DetectionRow)]  # version 2 files have no depicted_vehicle_id
        sql = f"SELECT {', '.join(cols)} FROM detections"
        args: tuple = ()
        if observer_id is not None:
            sql += " WHERE observer_id = ?"
            args = (int(observer_id),)
        return [DetectionRow(*r) for r in self._query(sql + " ORDER BY observer_id, frame, idx",
                                                      args)]

    def tracks(self, observer_id: int | None = None) -> list[TrackRow]:
        where, args = ("", ()) if observer_id is None else (" WHERE observer_id = ?",
                                                            (int(observer_id),))
        return [TrackRow(*r) for r in self._query(
            f"SELECT {', '.join(_cols(TrackRow))} FROM tracks{where} "
            "ORDER BY observer_id, track_id", args)]

    def crops(self, keys: Iterable[tuple[int, int, int]] | None = None,
              observer_id: int | None = None) -> list[CropRow]:
        """All crops (of one observer), or those of ``keys`` [(observer_id, frame, idx)]
        (missing keys are skipped), in key order."""
        sql = f"SELECT {', '.join(_cols(CropRow))} FROM crops"
        if keys is None:
            where, args = ("", ()) if observer_id is None else (" WHERE observer_id = ?",
                                                                (int(observer_id),))
            return [CropRow(*r) for r in self._query(
                sql + where + " ORDER BY observer_id, frame, idx", args)]
        out: list[CropRow] = []
        ks = sorted({(int(o), int(f), int(i)) for o, f, i in keys})
        for a in range(0, len(ks), 300):  # SQLite's host-parameter limit
            part = ks[a:a + 300]
            cond = " OR ".join(["(observer_id = ? AND frame = ? AND idx = ?)"] * len(part))
            out += [CropRow(*r) for r in self._query(
                f"{sql} WHERE {cond} ORDER BY observer_id, frame, idx",
                [v for k in part for v in k])]
        return out

    # --------------------------------------------------------------- embeddings
    def _has_embeddings(self) -> bool:
        try:
            return "embeddings" in self.dialect.tables()
        except self.dialect.errors as exc:
            raise StoreError(f"{self.path} is truncated or corrupt: {exc}") from exc

    def count_missing_embeddings(self, model_sha256: str) -> int:
        """Number of crops without a vector of the model ``model_sha256``."""
        if not self._has_embeddings():
            return self.count("crops")
        return int(self._query(
            "SELECT COUNT(*) FROM crops c WHERE NOT EXISTS (SELECT 1 FROM embeddings e WHERE "
            "e.model_sha256 = ? AND e.observer_id = c.observer_id AND e.frame = c.frame AND "
            "e.idx = c.idx)", (model_sha256,))[0][0])

    def crops_missing_embedding(self, model_sha256: str, limit: int | None = None,
                                after: tuple[int, int, int] | None = None) -> list[CropRow]:
        """Crops without a vector of the model, in key order (observer_id, frame, idx).

        Args:
            model_sha256: the model's file sha256 (hex).
            limit: at most this many (None: all).
            after: only keys greater than this (observer_id, frame, idx): the last key of
                the previous page, to page through a large file.
        """
        cols = ", ".join(f"c.{c}" for c in _cols(CropRow))
        sql = f"SELECT {cols} FROM crops c"
        where, args = [], []
        if self._has_embeddings():
            where.append("NOT EXISTS (SELECT 1 FROM embeddings e WHERE e.model_sha256 = ? AND "
                         "e.observer_id = c.observer_id AND e.frame = c.frame AND "
                         "e.idx = c.idx)")
            args.append(model_sha256)
        if after is not None:
            where.append("(c.observer_id, c.frame, c.idx) > (?, ?, ?)")
            args += [int(v) for v in after]
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY c.observer_id, c.frame, c.idx"
        if limit is not None:
            sql += " LIMIT ?"
            args.append(int(limit))
        return [CropRow(*r) for r in self._query(sql, args)]

    def add_embeddings(self, model: str, model_sha256: str,
                       keys: Sequence[tuple[int, int, int]], vectors) -> int:
        """Write vectors of the model for crops, in one transaction; returns rows added.

        Args:
            model: the model's name (e.g. its file name). model_sha256: its file's sha256.
            keys: N crop keys (observer_id, frame, idx).
            vectors: (N, dim) float, stored as float32.

        A crop that already has a vector of this model keeps it (a rerun adds nothing).

        Raises:
            StoreError: read-only; shapes disagree; non-finite values; ``dim`` differs
                from the vectors of this model already in the file; a key without a crop.
        """
        self._need_writable()
        v = np.asarray(vectors, dtype=np.float32)
        keys = [(int(o), int(f), int(i)) for o, f, i in keys]
        if v.ndim != 2 or v.shape[0] != len(keys) or v.shape[1] < 1:
            raise StoreError(f"{self.path}: add_embeddings: {len(keys)} keys and vectors of "
                             f"shape {v.shape}; expected ({len(keys)}, dim)")
        if not np.isfinite(v).all():
            raise StoreError(f"{self.path}: add_embeddings: vectors of {model} hold NaN or "
                             "infinite values")
        dim = int(v.shape[1])
        have = self._query("SELECT dim, model FROM embeddings WHERE model_sha256 = ? LIMIT 1",
                           (model_sha256,))
        if have and int(have[0][0]) != dim:
            raise StoreError(f"{self.path} holds {have[0][0]}-d embeddings of model "
                             f"{have[0][1]} (sha256 {model_sha256[:12]}...), the new vectors "
                             f"are {dim}-d")
        le = v.astype(_VECTOR, copy=False)
        rows = [(o, f, i, model, model_sha256, dim, le[n].tobytes())
                for n, (o, f, i) in enumerate(keys)]
        try:
            with self.dialect.transaction():
                return self.dialect.many(
                    "INSERT INTO embeddings (observer_id, frame, idx, model, model_sha256, dim, "
                    "vector) VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT DO NOTHING", rows)
        except self.dialect.integrity_errors as exc:
            raise StoreError(f"{self.path}: add_embeddings: a key has no crop ({exc})") from exc

    def embedding_models(self) -> list[EmbeddingModel]:
        """Every model with vectors in the file, by name then sha256."""
        if not self._has_embeddings():
            return []
        return [EmbeddingModel(m, s, int(d), int(n)) for m, s, d, n in self._query(
            "SELECT MIN(model), model_sha256, MIN(dim), COUNT(*) FROM embeddings "
            "GROUP BY model_sha256 ORDER BY 1, 2")]

    def embeddings(self, model_sha256: str, observer_id: int | None = None,
                   track_id: int | None = None) -> EmbeddingSet:
        """The vectors of the model with their detections' columns (`EmbeddingSet`).

        Args:
            model_sha256: the model's file sha256.
            observer_id, track_id: keep only that observer's / that track's rows.

        Raises:
            StoreError: the file has no vectors of that model (the message lists those
                it has).
        """
        models = {m.model_sha256: m for m in self.embedding_models()}
        if model_sha256 not in models:
            have = ", ".join(f"{m.model} ({m.model_sha256[:12]}...)" for m in models.values())
            have = f"models: {have}" if have else "it has no embeddings yet"
            raise StoreError(f"{self.path} has no embeddings of model sha256 "
                             f"{model_sha256[:12]}... ({have}); run: dashtraj reid embed DB "
                             "--model M.onnx")
        m = models[model_sha256]
        sql = ("SELECT e.observer_id, e.frame, e.idx, COALESCE(d.track_id, -1), d.t, d.x0, "
               "d.y0, d.x1, d.y1, d.vehicle_class, d.distance_m, "
               "COALESCE(d.truth_vehicle_id, -1), e.vector FROM embeddings e "
               "JOIN detections d ON d.observer_id = e.observer_id AND d.frame = e.frame AND "
               "d.idx = e.idx WHERE e.model_sha256 = ?")
        args: list = [model_sha256]
        if observer_id is not None:
            sql += " AND e.observer_id = ?"
            args.append(int(observer_id))
        if track_id is not None:
            sql += " AND d.track_id = ?"
            args.append(int(track_id))
        rows = self._query(sql + " ORDER BY e.observer_id, e.frame, e.idx", args)
        n = len(rows)
        cols = list(zip(*rows, strict=True)) if rows else [()] * 13

        def col(j: int, dtype) -> np.ndarray:  # None becomes NaN in the float columns
            return np.array(cols[j], dtype=dtype).reshape(n)

        vecs = (np.frombuffer(b"".join(cols[12]), _VECTOR).reshape(n, m.dim).astype(np.float32)
                if rows else np.zeros((0, m.dim), np.float32))
        return EmbeddingSet(
            model=m.model, model_sha256=m.model_sha256, dim=m.dim,
            observer_id=col(0, np.int64), frame=col(1, np.int64), idx=col(2, np.int64),
            track_id=col(3, np.int64), t=col(4, np.float64),
            box=np.array(cols[5:9], np.float64).reshape(4, n).T.copy(),
            vehicle_class=tuple(cols[9]), distance_m=col(10, np.float64),
            truth_vehicle_id=col(11, np.int64), vectors=vecs)

    def count(self, table: str) -> int:
        if table not in _TABLES:
            raise StoreError(f"unknown table {table!r}; tables: {', '.join(_TABLES)}")
        if table == "embeddings" and not self._has_embeddings():
            return 0  # a version-1 file
        return int(self._query(f"SELECT COUNT(*) FROM {table}")[0][0])

    def sightings(self, vehicle: int | None = None, max_distance_m: float | None = None,
                  sample_s: float | None = None, tracked_only: bool = True) -> list[Sighting]:
        """The detections as `Sighting` records, sorted by (t, observer_id, frame, idx).

        Args:
            vehicle: keep only detections whose truth_vehicle_id is this (evaluation
                only: an oracle's identity instead of ReID), or None for all.
            max_distance_m: keep detections estimated at most this far (the ReID range).
            sample_s: keep, per (observer, track), the first detection of every
                ``sample_s`` seconds from the track's first kept detection.
            tracked_only: drop detections without a confirmed track.

        The observer's position and yaw are its camera's (as the oracle sightings).
        """
        sql = ("SELECT d.t, d.observer_id, p.cam_x, p.cam_y, p.cam_yaw, d.x, d.y, d.orientation, "
               "d.vehicle_class, d.track_id, d.distance_m, d.bearing_deg FROM detections d "
               "JOIN poses p ON p.observer_id = d.observer_id AND p.frame = d.frame")
        where, args = [], []
        if vehicle is not None:
            where.append("d.truth_vehicle_id = ?")
            args.append(int(vehicle))
        if max_distance_m is not None:
            where.append("d.distance_m <= ?")
            args.append(float(max_distance_m))
        if tracked_only:
            where.append("d.track_id IS NOT NULL")
        if where:
            sql += " WHERE " + " AND ".join(where)
        sql += " ORDER BY d.observer_id, d.track_id NULLS FIRST, d.t, d.idx"
        rows = self._query(sql, args)
        if sample_s is not None and sample_s > 0:
            kept, key, t0, last_bin = [], None, 0.0, -1
            for r in rows:
                k = (r[1], r[9])
                if k != key or r[9] is None:
                    key, t0, last_bin = k, r[0], -1
                b = int((r[0] - t0) / sample_s + 1e-9)
                if b != last_bin:
                    kept.append(r)
                    last_bin = b
            rows = kept
        out = [Sighting(t=r[0], observer_id=r[1], observer_x=r[2], observer_y=r[3],
                        observer_yaw=r[4], x=r[5], y=r[6], orientation=r[7], vehicle_class=r[8],
                        track_id=r[9], distance=r[10], bearing=r[11]) for r in rows]
        out.sort(key=lambda s: (s.t, s.observer_id))
        return out


def copy_database(src: SightingsDB, dst: SightingsDB, batch_frames: int = 500) -> dict:
    """Copy every row of ``src`` into the new, empty ``dst`` (an SQLite file into a
    PostgreSQL schema or back): the run and its meta rows, each observer's frames,
    detections, crops and tracks in batches of ``batch_frames`` frames, each observer's and
    the run's completeness as they are, and the vectors of every embedding model. Returns
    the rows copied per table; `StoreError` when a count of ``dst`` differs from
    ``src``'s."""
    run = src.run_info()
    observers = src.observers()
    dst.write_run(run["recording"], run["map_name"], run["map_sha256"], run["camera"],
                  run["config"], [(o["observer_id"], o["role"]) for o in observers])
    extra = {k: v for k, v in src.meta().items() if k not in ("format", "schema_version")}
    if extra:  # the source's and detector's sha256 (a copy can be appended to)
        dst.set_meta(extra)
    for o in observers:
        oid = o["observer_id"]
        rows: dict[int, tuple[list, list, list]] = {}
        for k, table in enumerate((src.poses(oid), src.detections(oid),
                                   src.crops(observer_id=oid))):
            for r in table:
                rows.setdefault(r.frame, ([], [], []))[k].append(r)
        frames = sorted(rows)
        tracks = src.tracks(oid)
        for a in range(0, max(len(frames), 1), batch_frames):
            batch = [rows[f] for f in frames[a:a + batch_frames]]
            dst.add_frames(*([r for b in batch for r in b[k]] for k in range(3)),
                           tracks=tracks if a + batch_frames >= len(frames) else ())
        if o["complete"]:
            dst.finish_observer(oid)
    for m in src.embedding_models():
        e = src.embeddings(m.model_sha256)
        for a in range(0, len(e), 20_000):
            dst.add_embeddings(m.model, m.model_sha256, e.keys()[a:a + 20_000],
                               e.vectors[a:a + 20_000])
    if run["complete"]:
        dst.finish_run()
    counts = {t: src.count(t) for t in _TABLES[2:]}
    for t, n in counts.items():
        if dst.count(t) != n:
            raise StoreError(f"copy of {src.path} into {dst.path}: {dst.count(t)} rows of {t}, "
                             f"the source has {n}")
    return counts
