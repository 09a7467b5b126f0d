#!/usr/bin/env bash
# Train the rows of the paper's Tables I-III one after another: the reference row (the recipe
# unchanged) and then one row per switch of the recipe, in the file's order, each
# `formic train --recipe R --scale S --seed N [--switch NAME] --run-dir RUNS/NAME`, its output
# appended to RUNS/NAME.log. A row with its model.pt is done and skipped; a row another process
# is training (its folder held) is skipped, so two of these side by side share the rows, one
# core each. Each row resumes from its checkpoints, so after a kill the same command goes on.
# Usage: scripts/train_tables.sh [RUNS] (default models/training/tables). RECIPE (paper), SCALE
# (0.5) and SEED (1) change the runs, THREADS (unset: the recipe's) how fast (`--threads`); FORMIC
# may name another way to call the CLI (e.g. one pinned to a worktree:
# "env PYTHONPATH=/work/tables-tree/src .venv/bin/python -m formic_cli.main").
set -euo pipefail
usage() { sed -n '2,11p' "$0"; }
case "${1:-}" in -h|--help) usage; exit 0 ;; esac
cd "$(dirname "${BASH_SOURCE[0]}")/.."
RUNS=${1:-models/training/tables}
RECIPE=${RECIPE:-paper} SCALE=${SCALE:-0.5} SEED=${SEED:-1}
FORMIC=${FORMIC:-.venv/bin/formic}
SWITCHES=$(.venv/bin/python - "$RECIPE" <<'EOF'
import sys
from formic_trainer.recipes.files import load_recipe
print(*load_recipe(sys.argv[1]).switches)
EOF
)
mkdir -p "$RUNS"
for row in reference $SWITCHES; do
  dir=$RUNS/$row
  if [ -f "$dir/model.pt" ]; then echo "$row: done ($dir/model.pt)"; continue; fi
  if [ -e "$dir/.lock" ] && ! flock -n "$dir/.lock" true; then
    echo "$row: another process is training it, skipped"; continue
  fi
  switch=(); [ "$row" = reference ] || switch=(--switch "$row")
  threads=(); [ -z "${THREADS:-}" ] || threads=(--threads "$THREADS")
  echo "$row: training ($dir.log)"
  if $FORMIC train --recipe "$RECIPE" --scale "$SCALE" --seed "$SEED" "${switch[@]}" "${threads[@]}" \
      --run-dir "$dir" \
      >>"$dir.log" 2>&1; then
    echo "$row: done ($dir/model.pt)"
  elif tail -n 1 "$dir.log" | grep -q "is in use by another process"; then
    echo "$row: another process is training it, skipped"
  else
    echo "$row: failed, see $dir.log" >&2; exit 1
  fi
done
