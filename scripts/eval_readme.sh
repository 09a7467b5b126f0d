#!/usr/bin/env bash
# Rebuild eval/readme/: the baselines and the planner on the paper's test matrix at 1024 steps
# (SPEC §8): 128x128, teams 16/32/64/128, obstacles 0 and 5%, infinite and finite resources and
# 3 wipeouts (Fig. 5's 24 cells), 20 stored scenarios per cell (eval/readme/scenarios/, seed 7);
# the paper's other world sizes (32x32, 64x64, infinite, no obstacles) with 10; then one report.
# The shipped model goes through scripts/eval_model.sh on the same scenarios. Resumes: finished
# episodes are reused. Usage: scripts/eval_readme.sh [extra formic eval options, e.g.
# --workers 16]. FORMIC may name another way to call the CLI.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
FORMIC=${FORMIC:-.venv/bin/formic}
OUT=${OUT_DIR:-eval/readme}
BASE=(--seed 7 --steps 1024 --out "$OUT" "$@")
BASELINES=csaf,csaf11,cardinality,planner,csaf11-ref
$FORMIC eval --algorithms $BASELINES --sizes 128 --teams 16,32,64,128 --obstacles 0,0.05 \
  --env infinite,finite,wipeout --scenarios 20 "${BASE[@]}"
# C-SAF as the authors ran it, and random agents: the paper's main setting only
$FORMIC eval --algorithms csaf-ref,random --sizes 128 --teams 16,32,64,128 --obstacles 0 --env infinite \
  --scenarios 20 "${BASE[@]}"
$FORMIC eval --algorithms $BASELINES,csaf-ref,random --sizes 32,64 --teams 16,32,64,128 --obstacles 0 \
  --env infinite --scenarios 10 "${BASE[@]}"
$FORMIC eval --out "$OUT" --report
