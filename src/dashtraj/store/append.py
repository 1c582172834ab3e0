"""Appending observers to a run (``dashtraj perceive --append``): several machines, each
perceiving its own observers of one recording or drive, write one run.

An appender writes its observers into a partial output of its own, exactly as a new run
is written (a ``.<name>.tmp-…`` file beside an SQLite run, ``<schema>__partial_<n>``
beside a PostgreSQL one). When it has finished, one transaction of the run's database

1. checks that the partial and the run are one run: the same source (``meta``
   ``source_sha256``: the recording's or drive's defining files, not its path, which
   differs between machines), map, camera, perception settings, and detector model file
   (``detector_sha256``; its path may differ too) — `same_run`;
2. checks that none of the partial's observers is in the run yet;
3. copies the partial's observers, poses, tracks, detections, crops (and embeddings)
   into the run, and drops the partial.

Readers see the run without the new observers or with all of them, never some of their
frames. A failure, a refusal or Ctrl-C keeps the partial (every committed frame readable,
as after an interrupted new run) and leaves the run as it was. The run's ``run`` row (its
recording path, its config) stays the first writer's, but for the config's ``observers``,
which lists the run's observers after the append. When the run does not exist yet
the first appender to finish publishes its partial as the run, as a new run is published
(an SQLite file by a hard link, which fails if another appender made it first; a
PostgreSQL schema by a rename under the run's advisory lock); the others append to it.

PostgreSQL is the database for several machines: appenders of one schema serialize on
the run's advisory lock (`pg_output`). An SQLite run takes appends one at a time
(``BEGIN IMMEDIATE``); on a shared file system its locking is only as good as that file
system's.
"""

from __future__ import annotations

import json
import os
import sqlite3
from pathlib import Path

from dashtraj.store.backend import Dialect, StoreError, quote_ident
from dashtraj.store.db import (
    CropRow,
    DetectionRow,
    PoseRow,
    SightingsDB,
    TrackRow,
    _cols,
)

RUNTIME_SETTINGS = ("observers", "threads", "parallel_frames", "detector", "reid_model")
"""Perception settings that do not change what is written for an observer (which
observers, how many threads) or that name a file by a path that may differ between
machines (the detector model and the ReID model of ``live_relink``: compared by their
sha256 instead)."""

_MERGED = (
    ("observers", ("observer_id", "role", "frames", "complete")),
    ("poses", _cols(PoseRow)),
    ("tracks", _cols(TrackRow)),
    ("detections", _cols(DetectionRow)),
    ("crops", _cols(CropRow)),
    ("embeddings", ("observer_id", "frame", "idx", "model", "model_sha256", "dim", "vector")),
)
"""The tables an append copies, in an order their foreign keys allow, with their columns
named (a migrated run's columns may lie in another order)."""


ADDED_SETTINGS = {"calibrate_pitch": False, "live_relink": False}
"""Perception settings added after runs with ``source_sha256`` were first written, and the
value a run without one was perceived with."""


def run_identity(meta: dict, map_sha256, camera: dict, config: dict) -> dict:
    """What makes two perception outputs one run (`same_run` compares two of these): the
    source's and the detector's sha256 (``meta``), the map's, the camera, and the settings
    without `RUNTIME_SETTINGS` (`ADDED_SETTINGS` filled in; a pose noise of zero errors is
    no pose noise, and without one its seed is left out); JSON-normalised (tuples become
    lists)."""
    settings = {k: v for k, v in {**ADDED_SETTINGS, **config}.items()
                if k not in RUNTIME_SETTINGS}
    noise = settings.get("pose_noise")
    if noise is not None and not any(noise[:3]):
        settings["pose_noise"] = None  # zero errors: the exact poses
    if settings.get("pose_noise") is None:
        settings.pop("pose_noise_seed", None)  # the seed of no errors changes nothing
    return json.loads(json.dumps({
        "source": meta.get("source_sha256"), "detector": meta.get("detector_sha256"),
        "relink_model": meta.get("relink_model_sha256"),
        "map": map_sha256, "camera": camera, "settings": settings}))


def db_identity(db: SightingsDB) -> dict:
    """`run_identity` of an open sightings database."""
    run = db.run_info()
    return run_identity(db.meta(), run["map_sha256"], run["camera"], run["config"])


def same_run(run: dict, new: dict, where) -> None:
    """StoreError naming the first thing that differs between the run at ``where`` (its
    identity ``run``) and the observers to append (``new``)."""
    if run["source"] is None:
        raise StoreError(f"{where} was written before perceive recorded its source's sha256; "
                         "observers cannot be appended to it (perceive them into a new run)")
    for key, what in (("source", "recording or drive"), ("map", "map"),
                      ("camera", "camera"), ("detector", "detector model"),
                      ("relink_model", "ReID model of --live-relink")):
        if key == "relink_model" and None in (run.get(key), new.get(key)):
            continue  # one without --live-relink: the settings below say so
        if run.get(key) != new.get(key):
            raise StoreError(f"{where} was perceived from another {what}; appended observers "
                             f"must come from the run's {what}")
    a, b = run["settings"], new["settings"]
    for k in sorted(set(a) | set(b)):
        if a.get(k) != b.get(k):
            raise StoreError(f"{where} was perceived with {k}={a.get(k)!r}, these observers "
                             f"with {k}={b.get(k)!r}; appended observers must be perceived "
                             "with the run's settings")


def check_append(target, identity: dict) -> list[int] | None:
    """Before any work: the observers of the run at ``target`` (a file or a PostgreSQL URL)
    when it is one run with what ``identity`` describes (`same_run`), None when there is no
    run there yet. StoreError for a foreign, damaged or other run."""
    from dashtraj.store.backend import is_url, parse_url

    if is_url(target):
        from dashtraj.store.pg_output import pg_schema_exists

        if not pg_schema_exists(parse_url(target)):
            return None
    elif not Path(target).exists():
        return None
    with SightingsDB.open(target) as db:
        same_run(db_identity(db), identity, db.path)
        return [o["observer_id"] for o in db.observers()]


def _identity_sql(d: Dialect, prefix: str) -> dict:
    meta = dict(d.execute(f"SELECT key, value FROM {prefix}meta").fetchall())
    row = d.execute(f"SELECT map_sha256, camera, config FROM {prefix}run WHERE id = 1").fetchone()
    if row is None:
        raise StoreError("a run without its run row")
    return run_identity(meta, row[0], json.loads(row[1]), json.loads(row[2]))


def merge_run(d: Dialect, run: str, part: str, where) -> list[int]:
    """Inside the caller's transaction: check and copy the partial's rows (tables under
    the prefix ``part``, e.g. ``part.`` or ``"s__partial_1".``) into the run's (``run``);
    the observers appended. StoreError (nothing copied) when they are not one run or an
    observer is in both."""
    same_run(_identity_sql(d, run), _identity_sql(d, part), where)
    have = {r[0] for r in d.execute(f"SELECT observer_id FROM {run}observers").fetchall()}
    new = [r[0] for r in d.execute(
        f"SELECT observer_id FROM {part}observers ORDER BY observer_id").fetchall()]
    both = sorted(have & set(new))
    if both:
        raise StoreError(f"{where} already has observer{'s' if len(both) > 1 else ''} "
                         f"{', '.join(map(str, both))} (appended meanwhile?); perceive "
                         "only the others")
    for table, cols in _MERGED:
        c = ", ".join(cols)
        d.execute(f"INSERT INTO {run}{table} ({c}) SELECT {c} FROM {part}{table}")
    config = json.loads(d.execute(f"SELECT config FROM {run}run WHERE id = 1").fetchone()[0])
    if config.get("observers") is not None:  # the settings name the run's observers
        config["observers"] = sorted(have | set(new))
        d.execute(f"UPDATE {run}run SET config = ? WHERE id = 1",
                  (json.dumps(config, sort_keys=True),))
    return new


def append_file(part: Path, path: Path) -> list[int] | None:
    """Publish the finished SQLite run ``part`` into ``path``: as the run when there is
    none (None), else appended to it (the observers appended; module docstring). ``part``
    is removed once its rows are in; on an exception it is left as it was."""
    try:
        os.link(part, path)  # atomic, and refused when another appender made it first
    except FileExistsError:
        pass
    except OSError:  # a file system without hard links: publish by rename if still free
        if not path.exists():
            os.replace(part, path)
            return None
    else:
        part.unlink()
        return None
    SightingsDB.open(path, writable=True).close()  # checks it, upgrades an older schema
    before = os.stat(path).st_ino
    # a URI connection, so that ATTACH takes the partial's URI (read-only) as one
    conn = sqlite3.connect(path.resolve().as_uri(), uri=True, isolation_level=None)
    try:
        conn.execute("PRAGMA foreign_keys=ON")
        conn.execute("ATTACH DATABASE ? AS part", (f"{part.resolve().as_uri()}?mode=ro",))
        conn.execute("BEGIN IMMEDIATE")
        try:
            if os.stat(path).st_ino != before:
                raise StoreError(f"{path} was replaced while observers were appended to it")
            new = merge_run(Dialect(conn), "main.", "part.", path)
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise
    finally:
        conn.close()
    if os.stat(path).st_ino != before:
        raise StoreError(f"{path} was replaced (--overwrite?) while observers were appended "
                         "to it; they are not in it")
    part.unlink()
    return new


def append_schema(d, run_schema: str, partial: str, where) -> list[int] | None:
    """Inside the caller's transaction, holding the run's advisory lock (`pg_output`):
    the partial schema becomes the run (None) or is appended to it and dropped."""
    if not d.schema_exists(run_schema):
        d.conn.execute(f"ALTER SCHEMA {quote_ident(partial)} RENAME TO "
                       f"{quote_ident(run_schema)}")
        return None
    new = merge_run(d, quote_ident(run_schema) + ".", quote_ident(partial) + ".", where)
    d.conn.execute(f"DROP SCHEMA {quote_ident(partial)} CASCADE")
    return new
