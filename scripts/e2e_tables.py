"""Print the README's from-pixels tables from `experiments --ablation` outputs.

Usage: python scripts/e2e_tables.py WORK [--readme README.md]
(WORK/<town>_seed<N>/ablation.json, as scripts/e2e_results.sh writes them; with --readme the
tables replace the block between the e2e-results markers of that file)
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np

from dashtraj.ablation import ROWS, SOURCES, budget


def load(work: Path) -> dict[str, dict]:
    out: dict[str, dict] = {}
    suites = [work / "ablation.json"] if (work / "ablation.json").is_file() else []
    for p in suites + sorted(work.glob("*/ablation.json")):
        out.update(json.loads(p.read_text())["per_experiment"])
    return out


def pooled(exps: list[dict], row: str) -> tuple[float | None, float | None, int, int]:
    tp = sum(e["rows"][row].get("reid_true_matches", 0) for e in exps)
    fp = sum(e["rows"][row].get("reid_false_matches", 0) for e in exps)
    fn = sum(e["rows"][row].get("reid_misses", 0) for e in exps)
    return (tp / (tp + fp) if tp + fp else None, tp / (tp + fn) if tp + fn else None, tp, fp)


def mean(exps: list[dict], row: str, method: str, key: str) -> tuple[float, int]:
    vals = [e["rows"][row]["methods"][method][key] for e in exps
            if method in e["rows"][row]["methods"]]
    return (float(np.mean(vals)) if vals else float("nan")), len(vals)


def fmt(x: float | None, nd: int = 2) -> str:
    return "-" if x is None or x != x else f"{x:.{nd}f}"


BEGIN = "<!-- e2e-results:"
END = "<!-- /e2e-results -->"


def main(argv: list[str]) -> int:
    if "--readme" in argv:
        i = argv.index("--readme")
        readme = Path(argv[i + 1])
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            rc = tables(argv[:i] + argv[i + 2:])
        if rc:
            print(buf.getvalue(), end="")
            return rc
        text = readme.read_text()
        a = text.index(BEGIN)
        a = text.index("\n", a) + 1
        b = text.index(END)
        readme.write_text(text[:a] + buf.getvalue() + text[b:])
        print(f"{readme}: tables replaced")
        return 0
    return tables(argv)


def tables(argv: list[str]) -> int:
    work = Path(argv[0] if argv else "runs/results")
    per = load(work)
    if not per:
        print(f"no {work}/*/ablation.json yet")
        return 1
    names = sorted(per)
    exps = [per[n] for n in names]
    first = exps[0]
    print(f"{len(exps)} experiments: {', '.join(names)}; detector {first['detector']}, "
          f"ReID {first['reid_model']}, look {first['look']}, frame period "
          f"{first['config']['every_s']} s, images {first['config']['image_size']}\n")
    print("| pipeline | hmm SSPD whole / seen | hmm Hausdorff seen | shortest-path SSPD "
          "whole / seen | shortest-path Hausdorff seen | ReID precision / recall (tracks) |")
    print("|---|---|---|---|---|---|")
    label = {"oracle": "all oracle (exact boxes, true tracks, true positions, identity)",
             "localization": "from pixels, target picked by identity (no appearance ReID)",
             "vision-oracle-detector": "from pixels, exact boxes, appearance ReID + gate",
             "reid": f"from pixels, detector {first['detector']}, appearance ReID + gate"}
    for row in ("oracle", "localization", "vision-oracle-detector", "reid"):
        cells = []
        for m in ("hmm", "shortest-path"):
            w, n = mean(exps, row, m, "sspd_whole_m")
            s, _ = mean(exps, row, m, "sspd_seen_m")
            h, _ = mean(exps, row, m, "hausdorff_seen_m")
            note = "" if n == len(exps) else f" ({n} of {len(exps)} with sightings)"
            cells += [f"{fmt(w)} / {fmt(s)} m{note}", f"{fmt(h, 1)} m"]
        p, r, tp, fp = pooled(exps, row)
        cells.append(f"{fmt(p, 3)} / {fmt(r, 3)} ({tp} true, {fp} false)")
        print(f"| {label[row]} | " + " | ".join(cells) + " |")
    print("\n| error source (Table IV) | stage turned real | impact on hmm SSPD whole / seen "
          "| impact on shortest-path SSPD whole / seen |")
    print("|---|---|---|---|")
    b = budget(exps)
    for i in range(1, len(ROWS)):
        row = ROWS[i][0]
        cells = []
        for m in ("hmm", "shortest-path"):
            imp = b.get(m, {}).get("impact", {}).get(row)
            cells.append("-" if imp is None else
                         f"{imp['sspd_whole_m']:+.2f} / {imp['sspd_seen_m']:+.2f} m"
                         + ("" if imp["experiments"] == len(exps)
                            else f" ({imp['experiments']} of {len(exps)})"))
        print(f"| {SOURCES[row]} | {row} | " + " | ".join(cells) + " |")
    base = b.get("hmm", {}).get("rows", {}).get("oracle")
    if base:
        print(f"\n(all-oracle baseline, hmm: {base['sspd_whole_m']:.2f} / "
              f"{base['sspd_seen_m']:.2f} m over {base['experiments']} experiments; an impact "
              "is the mean difference to the row before over the experiments where both rows "
              "had sightings)")
    print("\n| experiment | hmm SSPD whole / seen, by row: " + ", ".join(r[0] for r in ROWS)
          + " | ReID TP / FP / FN (reid row) |")
    print("|---|---|---|")
    for n, e in zip(names, exps, strict=True):
        cells = []
        for r in ROWS:
            mm = e["rows"][r[0]]["methods"].get("hmm")
            cells.append("-" if mm is None else f"{mm['sspd_whole_m']:.1f}/{mm['sspd_seen_m']:.1f}")
        rr = e["rows"]["reid"]
        print(f"| {n} | {', '.join(cells)} | {rr.get('reid_true_matches')} / "
              f"{rr.get('reid_false_matches')} / {rr.get('reid_misses')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
