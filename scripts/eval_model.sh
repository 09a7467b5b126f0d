#!/usr/bin/env bash
# Evaluate a ForMIC model the way the README reports the shipped one, on the README's stored
# scenarios (the same files as eval/readme/, regenerated from seed 7 into OUT/scenarios):
# Fig. 5's 24 cells (128x128, 1024 steps, 20 scenarios per cell), the pheromone channel empty and
# the paper's three out-of-distribution trail variants (infinite resources, no obstacles), and
# the 32x32 and 64x64 worlds (10 per cell); then one report. With --fig5-only, Fig. 5's cells
# alone (480 of the 880 episodes: what the statistics over a recipe's seeds read). Resumes:
# finished episodes are reused.
# Usage: scripts/eval_model.sh [--fig5-only] MODEL OUT [extra formic eval options, e.g. --workers 16].
set -euo pipefail
usage() { sed -n '2,9p' "$0"; }
case "${1:-}" in -h|--help) usage; exit 0 ;; esac
FIG5_ONLY=0
if [ "${1:-}" = --fig5-only ]; then FIG5_ONLY=1; shift; fi
[ $# -ge 2 ] || { usage >&2; exit 2; }
MODEL=$1 OUT=$2; shift 2
cd "$(dirname "${BASH_SOURCE[0]}")/.."
FORMIC=${FORMIC:-.venv/bin/formic}
run() { $FORMIC eval --algorithms formic --model "$MODEL" --seed 7 --steps 1024 --out "$OUT" "$@"; }
run --sizes 128 --teams 16,32,64,128 --obstacles 0,0.05 --env infinite,finite,wipeout --scenarios 20 "$@"
if [ $FIG5_ONLY = 0 ]; then
  run --sizes 128 --teams 16,32,64,128 --obstacles 0 --env infinite --scenarios 20 --no-pheromones "$@"
  for trails in flat noisy random; do
    run --sizes 128 --teams 16,32,64,128 --obstacles 0 --env infinite --scenarios 20 --variant $trails "$@"
  done
  run --sizes 32,64 --teams 16,32,64,128 --obstacles 0 --env infinite --scenarios 10 "$@"
fi
$FORMIC eval --out "$OUT" --report
