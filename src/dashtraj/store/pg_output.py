"""Output discipline for a run written into a PostgreSQL schema (a file's is
`dashtraj.outputs.atomic_output`).

A run is written into a new schema ``<schema>__partial_<n>`` and published in one
transaction (PostgreSQL's DDL is transactional): the old run's schema, if ``overwrite``,
is dropped and the new one renamed to its name. Readers see the old run or the new one,
never a mix. A failure or Ctrl-C keeps the partial schema under its own name (every
committed frame readable, like a file's ``.partial-<n>``) and leaves the old run as it
was. A schema that is not a dashtraj sightings database is never replaced.

With ``append`` (``perceive --append``) the partial schema is appended to the run's
instead of replacing it, in the same one transaction under the same lock
(`dashtraj.store.append`).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator

from dashtraj.store.backend import (
    MAX_RUN_SCHEMA,
    PARTIAL_TAG,
    PgDialect,
    PgTarget,
    StoreError,
    connect_pg,
    parse_url,
    quote_ident,
)
from dashtraj.store.db import FORMAT


def _connect(target: PgTarget) -> PgDialect:
    return PgDialect(connect_pg(target), target.schema)


def _refuse_foreign(d: PgDialect, target: PgTarget, schema: str) -> None:
    """StoreError unless ``schema`` holds a dashtraj sightings database."""
    q = quote_ident(schema)
    has_meta = bool(d.conn.execute(
        "SELECT 1 FROM information_schema.tables WHERE table_schema = %s AND "
        "table_name = 'meta'", (schema,)).fetchall())
    fmt = (d.conn.execute(f"SELECT value FROM {q}.meta WHERE key = 'format'").fetchall()
           if has_meta else [])
    if not fmt or fmt[0][0] != FORMAT:
        raise StoreError(f"{target.display} is a schema that is not a dashtraj sightings "
                         "database; it is not replaced (choose another ?schema=)")


def pg_schema_exists(target: PgTarget) -> bool:
    """Whether the run's schema of ``target`` exists."""
    d = _connect(target)
    try:
        return d.schema_exists()
    finally:
        d.close()


def check_pg_output(url: str, *, overwrite: bool, append: bool = False) -> PgTarget:
    """Refuse early (before any work) what `pg_atomic_output` would refuse at the end: the
    run's schema exists and neither ``overwrite`` nor ``append`` is on, or it exists and is
    not a dashtraj run."""
    target = parse_url(url)
    if len(target.schema) > MAX_RUN_SCHEMA:
        raise StoreError(f"{target.display}: a run's schema name is at most {MAX_RUN_SCHEMA} "
                         "characters (its partial name must fit PostgreSQL's 63)")
    d = _connect(target)
    try:
        if d.schema_exists():
            if not (overwrite or append):
                raise StoreError(f"{target.display} exists; pass --overwrite to replace it "
                                 "whole")
            _refuse_foreign(d, target, target.schema)
    finally:
        d.close()
    return target


@contextlib.contextmanager
def pg_atomic_output(url: str, *, overwrite: bool = False, keep_partial: bool = True,
                     quiet: bool = False, append: bool = False) -> Iterator[str]:
    """Yield the URL of a new partial schema to write the run into; publish it as the run's
    schema when the block ends without an exception (module docstring), or with ``append``
    append it to the run's schema (`dashtraj.store.append.append_schema`). On an exception
    the partial schema is kept (and said so on stderr unless ``quiet``), or dropped
    without ``keep_partial``."""
    target = check_pg_output(url, overwrite=overwrite, append=append)
    d = _connect(target)
    try:
        n = 1  # a name no schema has and no other writer is about to create (its lock)
        while (d.schema_exists(f"{target.schema}{PARTIAL_TAG}{n}")
               or not d.conn.execute("SELECT pg_try_advisory_lock(hashtext(%s))", (
                   f"{target.schema}{PARTIAL_TAG}{n}",)).fetchone()[0]):
            n += 1
        partial = f"{target.schema}{PARTIAL_TAG}{n}"
        try:
            yield target.with_schema(partial)
            if append and d.schema_exists():  # an older run is upgraded first, on its own
                from dashtraj.store.db import SightingsDB

                SightingsDB.open(url, writable=True).close()
            with d.transaction():
                d.conn.execute("SELECT pg_advisory_xact_lock(hashtext(%s))", (target.schema,))
                if append:
                    from dashtraj.store.append import append_schema

                    append_schema(d, target.schema, partial, target.display)
                else:
                    if d.schema_exists():
                        if not overwrite:
                            raise StoreError(f"{target.display} was created while this run "
                                             "was written; pass --overwrite to replace it "
                                             "whole")
                        _refuse_foreign(d, target, target.schema)
                        d.conn.execute(f"DROP SCHEMA {quote_ident(target.schema)} CASCADE")
                    d.conn.execute(f"ALTER SCHEMA {quote_ident(partial)} RENAME TO "
                                   f"{quote_ident(target.schema)}")
        except BaseException:
            if not d.conn.closed and d.schema_exists(partial):
                if not keep_partial:
                    d.conn.execute(f"DROP SCHEMA {quote_ident(partial)} CASCADE")
                elif not quiet:
                    print(f"dashtraj: kept the partial output in schema {partial} "
                          f"({target.display} is unchanged)", file=sys.stderr)
            raise
    finally:
        d.close()


def check_db_output(target, *, overwrite: bool, append: bool = False) -> None:
    """`check_pg_output` for a URL, `dashtraj.outputs.check_output` (a file) otherwise:
    what a command that writes a sightings database refuses before any work (with
    ``append`` an existing run is no reason to refuse)."""
    from dashtraj.outputs import check_output
    from dashtraj.store.backend import is_url

    if is_url(target):
        check_pg_output(target, overwrite=overwrite, append=append)
    else:
        check_output(target, overwrite=overwrite or append, kind="file")


def db_output(target, *, overwrite: bool, keep_partial: bool, append: bool = False):
    """The context that writes a sightings database whole: `pg_atomic_output` for a URL,
    `dashtraj.outputs.atomic_output` (a file) otherwise; it yields where to create it.
    With ``append`` what was written is appended to the run there (or becomes it when
    there is none; `dashtraj.store.append`)."""
    from dashtraj.outputs import atomic_output
    from dashtraj.store.backend import is_url

    if is_url(target):
        return pg_atomic_output(target, overwrite=overwrite, keep_partial=keep_partial,
                                append=append)
    if append:
        from dashtraj.store.append import append_file

        return atomic_output(target, overwrite=True, kind="file", keep_partial=keep_partial,
                             publish=append_file)
    return atomic_output(target, overwrite=overwrite, kind="file", keep_partial=keep_partial)
