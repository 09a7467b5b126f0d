#!/usr/bin/env bash
# Train, trim and test a recipe's seeds one after another. For each seed S of SEEDS (1-8, or
# 1,3,5): `formic train --recipe RECIPE --seed S --run-dir RUNS/seedS`, its output appended to
# RUNS/seedS.log (it resumes from the run's checkpoints; a finished run says so at once); then
# scripts/lean_run.py on the finished run; then scripts/eval_model.sh --fig5-only into
# EVALS/seedS (its summary appended to the run's log), sealed. A seed whose run or evaluation another
# process holds is skipped, so two of these side by side share the seeds, one core each; a seed
# trained and tested (its sealed episodes there) is passed over. Ctrl-C stops the training after its
# episode set in progress (checkpoint saved) and this script with it (130); after a stop or a kill
# the same command goes on. EVAL=0 skips the evaluations. --status first: one line a seed (what it
# trains or validates, CPU-hours spent and left or its choice, its test episodes, whether a process
# holds it), nothing run.
# Usage: scripts/train_seeds.sh [--status] RECIPE SEEDS [RUNS (models/training/recipe-RECIPE)]
# [EVALS (eval/recipe-RECIPE)]. FORMIC may name another way to call the CLI (e.g. one pinned to
# a worktree: "env PYTHONPATH=/work/recipe-tree/src .venv/bin/python -m formic_cli.main").
set -euo pipefail
usage() { sed -n '2,15p' "$0"; }
only_status=0
case "${1:-}" in -h|--help) usage; exit 0 ;; --status) only_status=1; shift ;; esac
[ $# -ge 2 ] || { usage >&2; exit 2; }
cd "$(dirname "${BASH_SOURCE[0]}")/.."
RECIPE=$1 SEEDS=$2
RUNS=${3:-models/training/recipe-$RECIPE} EVALS=${4:-eval/recipe-$RECIPE}
export FORMIC=${FORMIC:-.venv/bin/formic}
case "$SEEDS" in
  *-*) seeds=$(seq "${SEEDS%-*}" "${SEEDS#*-}") ;;
  *) seeds=${SEEDS//,/ } ;;
esac
held() { [ -e "$1/.lock" ] && ! flock -n "$1/.lock" true; }
stopped() { echo "seed $seed: stopped (see $1): rerun the same command to go on" >&2; exit 130; }
tested() { [ -e "$run/selection.json" ] && [ -e "$evals/episodes.jsonl.gz" ] && [ ! -e "$evals/episodes.jsonl" ]; }
status() {
  local training="not started" testing lines stage
  if [ -e "$run/recipe.json" ]; then  # the stage or validation in progress, and the CPU-hours or the choice
    lines=$($FORMIC train --recipe "$RECIPE" --seed "$seed" --run-dir "$run" --status)
    training=$(tail -n 1 <<<"$lines")
    if [[ $training != finished:* ]]; then
      stage=$(grep -m 1 -e ": in progress" -e "^validation: .* episodes$" <<<"$lines" || true)
      training="${stage:+$stage; }$training"
    fi
  fi
  if held "$run"; then training="$training (training now)"; fi
  if tested; then testing="$(gzip -cd "$evals/episodes.jsonl.gz" | wc -l) episodes, sealed"
  elif [ -e "$evals/episodes.jsonl" ]; then testing="$(wc -l <"$evals/episodes.jsonl") episodes so far"
  else testing="not started"; fi
  if held "$evals"; then testing="$testing (playing now)"; fi
  echo "seed $seed: $training | test: $testing"
}
if [ $only_status = 1 ]; then
  for seed in $seeds; do run=$RUNS/seed$seed evals=$EVALS/seed$seed; status; done
  exit 0
fi
mkdir -p "$RUNS" "$EVALS"
for seed in $seeds; do
  run=$RUNS/seed$seed evals=$EVALS/seed$seed
  if tested; then
    echo "seed $seed: trained and tested ($evals), skipped"; continue
  fi
  if held "$run"; then echo "seed $seed: another process is training it, skipped"; continue; fi
  echo "seed $seed: training ($run.log)"
  status=0
  $FORMIC train --recipe "$RECIPE" --seed "$seed" --run-dir "$run" >>"$run.log" 2>&1 || status=$?
  if [ $status = 130 ]; then stopped "$run.log"; fi
  if [ $status != 0 ]; then
    if tail -n 1 "$run.log" | grep -q "is in use by another process"; then
      echo "seed $seed: another process is training it, skipped"; continue
    fi
    echo "seed $seed: failed, see $run.log" >&2; exit 1
  fi
  if ! trimmed=$(.venv/bin/python scripts/lean_run.py "$run" 2>&1); then
    if grep -q "is in use by another process" <<<"$trimmed"; then
      echo "seed $seed: another process holds it, skipped"; continue
    fi
    echo "$trimmed" >&2; exit 1
  fi
  echo "$trimmed"
  [ "${EVAL:-1}" = 0 ] && continue
  if held "$evals"; then echo "seed $seed: another process is evaluating it, skipped"; continue; fi
  echo "seed $seed: test episodes on Fig. 5's cells ($evals)"
  status=0
  scripts/eval_model.sh --fig5-only "$run/model.pt" "$evals" --workers 1 >>"$run.log" 2>&1 || status=$?
  if [ $status = 130 ]; then stopped "$run.log"; fi
  if [ $status != 0 ]; then
    if tail -n 3 "$run.log" | grep -q "is in use by another process"; then
      echo "seed $seed: another process is evaluating it, skipped"; continue
    fi
    echo "seed $seed: evaluation failed, see $run.log" >&2; exit 1
  fi
  if [ -e "$evals/episodes.jsonl" ]; then
    .venv/bin/python scripts/seal_episodes.py --drop-derived "$evals"
  fi
  rm -rf "$evals/scenarios"
done
