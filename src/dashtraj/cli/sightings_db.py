"""`dashtraj sightings export DB` and `dashtraj sightings RUN --detector ...` (helpers of
`cmd_world`'s ``sightings`` command, which dispatches here)."""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path


def _vehicle_id(db, spec: str, recording_meta: dict | None) -> int | None:
    from dashtraj.errors import DashtrajError

    if spec == "all":
        return None
    if spec == "target":
        if recording_meta is None:
            raise DashtrajError("--vehicle target: the run's recording is not readable; give a "
                                "vehicle id or 'all'")
        return int(recording_meta.get("target_vehicle_id", 0))
    try:
        return int(spec)
    except ValueError:
        raise DashtrajError(f"--vehicle must be an id, 'target' or 'all', got {spec!r}") from None


def export_csv(db_path: Path | str, output: str, vehicle: str, max_distance_m: float,
               sample_s: float, overwrite: bool) -> tuple[int, int, int]:
    """Write a database's sightings as CSV; returns (sightings, observers, tracks)."""
    import json

    from dashtraj.outputs import atomic_output
    from dashtraj.store import SightingsDB
    from dashtraj.trajectory.io import write_sightings

    with SightingsDB.open(db_path) as db:
        run = db.run_info()
        meta = None
        meta_path = Path(run["recording"]) / "meta.json"
        if vehicle == "target" and meta_path.is_file():
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        vid = _vehicle_id(db, vehicle, meta)
        rows = db.sightings(vehicle=vid, max_distance_m=max_distance_m, sample_s=sample_s)
    with atomic_output(output, overwrite=overwrite, kind="file") as tmp:
        write_sightings(tmp, rows)
    return len(rows), len({s.observer_id for s in rows}), len({(s.observer_id, s.track_id)
                                                                for s in rows})


def run_sightings_db(args: argparse.Namespace) -> int:
    """``sightings export DB`` or ``sightings RUN --detector D``; returns 0."""
    from dashtraj.errors import DashtrajError
    from dashtraj.outputs import check_output

    check_output(args.output, overwrite=args.overwrite, kind="file")
    if args.recording == "export":
        if args.db is None:
            raise DashtrajError("sightings export: name the database: dashtraj sightings export "
                                "DB -o S.csv")
        from dashtraj.store.backend import display_name, is_url

        n, n_obs, n_tr = export_csv(args.db if is_url(args.db) else Path(args.db), args.output,
                                    args.vehicle, args.max_distance, args.sample,
                                    args.overwrite)
        src = display_name(args.db)
    else:
        import warnings

        from dashtraj.perception.pipeline import PerceiveConfig, perceive
        from dashtraj.world.recording import Recording

        if args.db is not None:
            raise DashtrajError(f"unexpected argument {args.db!r} after the recording")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rec = Recording.open(args.recording)
        cfg = PerceiveConfig(detector=args.detector, tracker=args.tracker,
                             localizer=args.localizer)
        with tempfile.TemporaryDirectory(prefix="dashtraj-sightings-") as td:
            db_path = Path(td) / "run.db"
            perceive(rec, db_path, cfg)
            n, n_obs, n_tr = export_csv(db_path, args.output, args.vehicle, args.max_distance,
                                        args.sample, args.overwrite)
        src = f"{args.recording} (detector {args.detector}, tracker {args.tracker}, " \
              f"localizer {args.localizer})"
    if n == 0:
        print(f"dashtraj: warning: no sightings of vehicle {args.vehicle} within "
              f"{args.max_distance:g} m; {args.output} has only its header", file=sys.stderr)
    print(f"{args.output}: {n} sightings of vehicle {args.vehicle} by {n_obs} observers in "
          f"{n_tr} tracks from {src}")
    return 0
