"""`dashtraj sightings-copy SRC -o DST`: a sightings database copied whole between an
SQLite file and a PostgreSQL schema (either way)."""

from __future__ import annotations

import argparse
import json


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `sightings-copy` command."""
    from dashtraj.outputs import add_output_args

    p = subparsers.add_parser(
        "sightings-copy",
        help="copy a sightings database whole: an SQLite file into a PostgreSQL schema, or "
             "back",
        description=(
            "Copy every row of a sightings database (dashtraj perceive's output: the run, "
            "observers, poses, tracks, detections, crops and embeddings) into a new one. "
            "SRC and DST are each a file (SQLite) or a PostgreSQL URL "
            "postgresql://[user@]host[:port]/dbname[?schema=NAME] (one schema per run, "
            "default dashtraj; pip install 'dashtraj[postgres]'): observers that recorded "
            "into files gather their runs in one server, and a run in the server becomes a "
            "file to share. DST is written whole or not at all."
        ),
    )
    p.add_argument("source", metavar="SRC", help="sightings database to read (file or URL)")
    p.add_argument("-o", "--output", required=True, metavar="DST",
                   help="the new database (file or URL)")
    p.add_argument("--json", action="store_true", help="print the rows copied as JSON")
    add_output_args(p)
    p.set_defaults(func=run_sightings_copy)


def run_sightings_copy(args: argparse.Namespace) -> int:
    from dashtraj.store import SightingsDB, copy_database
    from dashtraj.store.backend import display_name
    from dashtraj.store.pg_output import check_db_output, db_output

    check_db_output(args.output, overwrite=args.overwrite)
    with SightingsDB.open(args.source) as src:
        # a failed copy is not kept: the source is still there
        with db_output(args.output, overwrite=args.overwrite, keep_partial=False) as tmp, \
                SightingsDB.create(tmp) as dst:
            counts = copy_database(src, dst)
    name = display_name(args.output)
    if args.json:
        print(json.dumps({"source": display_name(args.source), "output": name, **counts}))
    else:
        print(f"{name}: {counts['poses']} frames, {counts['detections']} detections in "
              f"{counts['tracks']} tracks, {counts['crops']} crops, {counts['embeddings']} "
              f"embeddings from {display_name(args.source)}")
    return 0
