#!/usr/bin/env bash
# Regenerate the README's from-pixels tables: the error budget (experiments --ablation) on the
# paper's ten experiments, one experiment per folder so that a stopped run keeps what it
# finished, then scripts/e2e_tables.py prints the markdown tables.
# Usage: [SEEDS=0-4] [TOWNS="town01 town10"] [EVERY=0.1] [README=README.md] \
#        scripts/e2e_results.sh WORK
# (README: replace the tables between its e2e-results markers)
set -euo pipefail
WORK=${1:-runs/results}
D=${DASHTRAJ:-dashtraj}
PY=${PYTHON:-$(dirname "$(command -v "$D")")/python}
SEEDS=${SEEDS:-0-4}
TOWNS=${TOWNS:-town01 town10}
EVERY=${EVERY:-0.1}
lo=${SEEDS%-*}; hi=${SEEDS#*-}
mkdir -p "$WORK"
for seed in $(seq "$lo" "$hi"); do
  for town in $TOWNS; do
    out="$WORK/${town}_seed$seed"
    test -f "$out/ablation.json" && continue
    $D experiments --ablation --towns "$town" --seeds "$seed-$seed" --every "$EVERY" -o "$out" \
        --overwrite ${EXTRA:-}
  done
done
"$PY" "$(dirname "$0")/e2e_tables.py" "$WORK" ${README:+--readme "$README"}
