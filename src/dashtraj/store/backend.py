"""Where a sightings database lives: an SQLite file, or a schema of a PostgreSQL database.

A database target is a path (SQLite, one file per run) or a PostgreSQL URL

    postgresql://[user[:password]@][host][:port]/dbname[?schema=NAME&...]

(libpq's URL form; ``postgres://`` too). One run is one *schema* of that database,
``schema`` (default ``dashtraj``): its tables are the file's tables, so every reader and
writer of `SightingsDB` works on either. The other query parameters and the environment
(``PGPASSWORD``, ``~/.pgpass``, ``PGSSLMODE`` …) go to libpq unchanged; the messages show
the URL without its password.

PostgreSQL is the database for many writers: ``perceive --workers N`` into a URL lets every
worker process write its own observers' frames in its own connection (SQLite's workers send
them to the one writer), and several ``reid embed`` runs may add vectors to one run at once.
The driver is psycopg 3 (``pip install 'dashtraj[postgres]'``), imported only for a URL.

The two dialects differ in little: placeholders (``?`` / ``%s``), column types (REAL is
8 bytes in SQLite, DOUBLE PRECISION in PostgreSQL; BLOB / BYTEA), the catalog of tables,
transactions (sqlite3's connection context / psycopg's ``transaction()``) and the errors.
`Dialect` holds those; the SQL of `dashtraj.store.db` is written once.
"""

from __future__ import annotations

import re
import sqlite3
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

from dashtraj.errors import DashtrajError

URL_SCHEMES = ("postgresql://", "postgres://")
DEFAULT_SCHEMA = "dashtraj"
_SCHEMA_RE = re.compile(r"[a-z_][a-z0-9_]{0,62}")
MAX_RUN_SCHEMA = 48
"""A run's schema name is at most this long, so that its partial name fits PostgreSQL's 63."""
PARTIAL_TAG = "__partial_"
"""A run being written into schema S lives in ``S__partial_<n>`` until it is published."""


class StoreError(DashtrajError):
    """A sightings database is missing, foreign, truncated, newer, or misused."""


def is_url(target) -> bool:
    """Whether a database target is a PostgreSQL URL (else a path of an SQLite file)."""
    return isinstance(target, str) and target.lower().startswith(URL_SCHEMES)


@dataclass(frozen=True)
class PgTarget:
    """A parsed PostgreSQL target: the URL libpq gets (no ``schema`` parameter), the run's
    schema, and the URL as messages show it (no password)."""

    conninfo: str
    schema: str
    display: str

    def with_schema(self, schema: str) -> str:
        """The same database's URL naming another schema."""
        parts = urlsplit(self.conninfo)
        query = [*parse_qsl(parts.query, keep_blank_values=True), ("schema", schema)]
        return urlunsplit(parts._replace(query=urlencode(query, safe="/")))


def parse_url(url: str) -> PgTarget:
    """Split a PostgreSQL URL into what libpq takes and the run's schema.

    Raises StoreError: the schema is not a plain lower-case SQL name (letters, digits, _;
    at most 63 characters, PostgreSQL's limit)."""
    parts = urlsplit(url)
    query = parse_qsl(parts.query, keep_blank_values=True)
    schemas = [v for k, v in query if k == "schema"]
    schema = schemas[-1] if schemas else DEFAULT_SCHEMA
    rest = [(k, v) for k, v in query if k != "schema"]
    netloc = parts.netloc
    if parts.password is not None:
        netloc = netloc.replace(f":{parts.password}@", ":***@", 1)
    display_query = urlencode([*rest, ("schema", schema)], safe="/")
    display = urlunsplit(parts._replace(netloc=netloc, query=display_query))
    if not _SCHEMA_RE.fullmatch(schema):
        raise StoreError(f"{display}: schema {schema!r} must be lower-case letters, digits and "
                         "_ (at most 63, not starting with a digit)")
    conninfo = urlunsplit(parts._replace(query=urlencode(rest, safe="/")))
    return PgTarget(conninfo, schema, display)


def display_name(target) -> str:
    """A database target as messages and JSON show it: a path as given, a URL without its
    password (a URL that does not parse is shown as ``postgresql://…``)."""
    if not is_url(target):
        return str(target)
    try:
        return parse_url(target).display
    except (StoreError, ValueError):
        return target.split("://", 1)[0] + "://…"


def connect_pg(target: PgTarget):
    """A psycopg connection (autocommit: each read its own snapshot, writes in explicit
    transactions). Raises StoreError without the driver or when the server refuses."""
    try:
        import psycopg
    except ImportError:
        raise StoreError(f"{target.display}: a PostgreSQL database needs the psycopg driver: "
                         "pip install 'dashtraj[postgres]'") from None
    try:
        return psycopg.connect(target.conninfo, autocommit=True)
    except psycopg.Error as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise StoreError(f"{target.display}: cannot connect: {first}") from None


def insert_sql(table: str, cols, key=()) -> str:
    """INSERT of ``cols`` with ``?`` placeholders; with ``key`` (the primary key) a row of
    that key is replaced (SQLite 3.24+ and PostgreSQL take the same ON CONFLICT clause)."""
    sql = f"INSERT INTO {table} ({', '.join(cols)}) VALUES ({', '.join('?' * len(cols))})"
    if key:
        sets = ", ".join(f"{c} = excluded.{c}" for c in cols if c not in key)
        sql += f" ON CONFLICT ({', '.join(key)}) DO UPDATE SET {sets}"
    return sql


def quote_ident(name: str) -> str:
    """A schema name as an SQL identifier (names are checked by `parse_url`)."""
    return '"' + name.replace('"', '""') + '"'


class Dialect:
    """SQLite: the connection and what its SQL needs (`PgDialect` for PostgreSQL)."""

    name = "sqlite"
    errors: tuple[type[BaseException], ...] = (sqlite3.DatabaseError,)
    integrity_errors: tuple[type[BaseException], ...] = (sqlite3.IntegrityError,)

    def __init__(self, conn):
        self.conn = conn

    def sql(self, text: str) -> str:
        """A statement written with ``?`` placeholders, in this dialect."""
        return text

    def ddl(self, text: str) -> str:
        """A CREATE / ALTER statement written with SQLite's types, in this dialect."""
        return text

    def execute(self, text: str, args=()):
        return self.conn.execute(self.sql(text), tuple(args))

    def many(self, text: str, rows) -> int:
        """Run a statement once per row; the rows it inserted or changed."""
        rows = list(rows)
        if not rows:
            return 0
        cur = self.conn.cursor()
        cur.executemany(self.sql(text), rows)
        return max(cur.rowcount, 0)

    def insert(self, table: str, cols, rows, types=None) -> int:
        """Append rows to a table (no conflict clause); the rows inserted. ``types``: the
        columns' PostgreSQL type names (`PgDialect` streams them in binary)."""
        return self.many(insert_sql(table, cols), rows)

    def transaction(self):
        """A context that commits on success and rolls back on an exception."""
        return self.conn

    def tables(self) -> set[str]:
        return {r[0] for r in self.conn.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table'")}

    def close(self) -> None:
        self.conn.close()


class PgDialect(Dialect):
    """PostgreSQL through psycopg 3, the run's schema first on the search path."""

    name = "postgresql"

    def __init__(self, conn, schema: str):
        super().__init__(conn)
        import psycopg

        self.errors = (psycopg.Error,)
        self.integrity_errors = (psycopg.IntegrityError,)
        self.schema = schema

    def sql(self, text: str) -> str:
        return text.replace("?", "%s")

    def ddl(self, text: str) -> str:
        return re.sub(r"\bBLOB\b", "BYTEA", re.sub(r"\bREAL\b", "DOUBLE PRECISION", text))

    def insert(self, table: str, cols, rows, types=None) -> int:
        """COPY FROM STDIN (binary where the column ``types`` are given, PostgreSQL type
        names): one stream per table, where an INSERT per row costs a round trip."""
        rows = list(rows)
        if not rows:
            return 0
        fmt = " (FORMAT BINARY)" if types else ""
        with self.conn.cursor() as cur, cur.copy(
                f"COPY {table} ({', '.join(cols)}) FROM STDIN{fmt}") as copy:
            if types:
                copy.set_types(list(types))
            for r in rows:
                copy.write_row(r)
        return len(rows)

    def transaction(self):
        return self.conn.transaction()

    def tables(self) -> set[str]:
        return {r[0] for r in self.conn.execute(
            "SELECT table_name FROM information_schema.tables WHERE table_schema = %s",
            (self.schema,))}

    def schema_exists(self, schema: str | None = None) -> bool:
        return bool(self.conn.execute(
            "SELECT 1 FROM information_schema.schemata WHERE schema_name = %s",
            (schema or self.schema,)).fetchall())

    def use_schema(self) -> None:
        self.conn.execute(f"SET search_path TO {quote_ident(self.schema)}")
