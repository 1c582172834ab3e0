"""The table of scripts/reid_judge.sh: one markdown row per model measured under WORK/models.

Usage: python scripts/reid_judge_table.py WORK [--json]

Columns (rank-1 / mAP in %, from `reid eval --json`): the ring and moving queries of WORK/veri
(make reid-data's test part) and the whole-vehicle moving queries (--max-truncation 0), the
ring and moving queries of WORK/veri99 (make reid-heldout's set), the decision threshold, and
per end-to-end set (scripts/reid_rescore.py --json) the target's true / false / missed tracks
and the hmm method's mean SSPD over the whole trip and the seen stretch. A figure not measured
(yet) is a dash. The shipped model (its sha256 equal to the package's file) comes first and is
marked.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

EVALS = (("ring", "ring"), ("moving", "moving"), ("whole", "moving, whole vehicles"),
         ("ring99", "second set ring"), ("moving99", "second set moving"))
E2E = (("ten", "the ten"), ("ten_twins", "the ten, `--twins 3`"), ("dev", "development"),
       ("dev_twins", "development, `--twins 3`"))


def _read(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def shipped_sha256() -> str | None:
    """The sha256 of the package's ReID model, or None where it is not there."""
    from dashtraj.digest import file_sha256
    from dashtraj.reid.embed import shipped_model_path

    path = shipped_model_path()
    return file_sha256(path) if path.is_file() else None


def model_figures(folder: Path) -> dict:
    """Every figure measured for one model folder of WORK/models (None where missing)."""
    out: dict = {"name": folder.name,
                 "source": (folder / "source.txt").read_text().strip()
                 if (folder / "source.txt").is_file() else None}
    th = _read(folder / "model.threshold.json")
    out["threshold"] = th["calibration"]["threshold"] if th else None
    for key, _ in EVALS:
        r = _read(folder / f"{key}.json")
        out[key] = ({k: r[k] for k in ("rank1", "rank5", "map", "minp", "queries")}
                    if r else None)
    for key, _ in E2E:
        r = _read(folder / f"e2e_{key}.json")
        if r is None:
            out[key] = None
            continue
        hmm = r["methods"].get("hmm", {})
        out[key] = {"true": r["reid"]["reid_true_matches"],
                    "false": r["reid"]["reid_false_matches"],
                    "missed": r["reid"]["reid_misses"],
                    "precision": r["reid"]["reid_precision"],
                    "recall": r["reid"]["reid_recall"],
                    "hmm_sspd_whole_m": hmm.get("sspd_whole_m"),
                    "hmm_sspd_seen_m": hmm.get("sspd_seen_m")}
    return out


def table(rows: list[dict]) -> str:
    """The markdown table of `model_figures` rows."""
    head = (["model", "threshold"] + [t for _, t in EVALS] + [t for _, t in E2E])
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["name"] + (" (shipped)" if r.get("shipped") else ""),
                 "—" if r["threshold"] is None else f"{r['threshold']:.4f}"]
        for key, _ in EVALS:
            e = r[key]
            cells.append("—" if e is None else f"{100 * e['rank1']:.1f} / {100 * e['map']:.1f}")
        for key, _ in E2E:
            e = r[key]
            if e is None:
                cells.append("—")
                continue
            sspd = ("" if e["hmm_sspd_whole_m"] is None else
                    f"; hmm {e['hmm_sspd_whole_m']:.2f} / {e['hmm_sspd_seen_m']:.2f} m")
            prec = "—" if e["precision"] is None else f"{e['precision']:.3f}"
            cells.append(f"{e['true']} / {e['false']} / {e['missed']} ({prec}){sspd}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("work", type=Path, help="scripts/reid_judge.sh's WORK folder")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    folders = sorted(p for p in (args.work / "models").glob("*") if p.is_dir())
    if not folders:
        print(f"{args.work}: no models measured (no folders under {args.work / 'models'})",
              file=sys.stderr)
        return 2
    sha = shipped_sha256()
    rows = []
    for f in folders:
        r = model_figures(f)
        r["shipped"] = bool(sha) and r["name"].endswith("_" + sha[:12])
        rows.append(r)
    rows.sort(key=lambda r: not r["shipped"])  # stable: the shipped model first
    print(json.dumps(rows, indent=1) if args.json else table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
