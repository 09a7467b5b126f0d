#!/usr/bin/env bash
# Rebuild eval/readme/: the README's results matrix at the paper's 1024 steps (SPEC §8), every
# algorithm on the same stored scenarios (eval/readme/scenarios/), then one report. Resumes:
# finished episodes are reused. Usage: scripts/eval_readme.sh [extra formic eval options,
# e.g. --workers 16]. FORMIC may name another way to call the CLI.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
FORMIC=${FORMIC:-.venv/bin/formic}
OUT=${OUT_DIR:-eval/readme}
BASE=(--seed 7 --steps 1024 --out "$OUT" "$@")
ALL=formic,random,csaf,csaf11,csaf-ref,csaf11-ref,cardinality,planner
big() { $FORMIC eval --sizes 128 --teams 16,32,64,128 "${BASE[@]}" "$@"; }
big --algorithms $ALL --obstacles 0 --env infinite --scenarios 20
big --algorithms formic --obstacles 0 --env infinite --scenarios 20 --greedy
big --algorithms formic --obstacles 0 --env infinite --scenarios 20 --no-pheromones
big --algorithms formic --obstacles 0 --env infinite --scenarios 20 --no-pheromones --greedy
big --algorithms $ALL --obstacles 0 --env finite --scenarios 10
big --algorithms formic --obstacles 0 --env finite --scenarios 10 --greedy
big --algorithms formic,csaf,csaf11,csaf-ref,csaf11-ref --obstacles 0 --env wipeout --scenarios 10
big --algorithms formic --obstacles 0 --env wipeout --scenarios 10 --greedy
big --algorithms formic,csaf11,csaf11-ref,cardinality,planner --obstacles 0.05 --env infinite --scenarios 10
big --algorithms formic --obstacles 0.05 --env infinite --scenarios 10 --greedy
# the paper's other world sizes, infinite resources, no obstacles
$FORMIC eval --sizes 32,64 --teams 16,32,64,128 "${BASE[@]}" --algorithms $ALL --obstacles 0 --env infinite --scenarios 10
$FORMIC eval --out "$OUT" --report
