#!/usr/bin/env bash
# Issue 14, the next experiment of results/aril_a_tuning.md: ARIL (Algorithm 1) whose round adversaries are trained
# fresh to 1M steps each instead of warm-started for 500k, on one cell (default Swimmer-v5 physical at 0.005); then a
# fresh 1M ARIL-A against the selected learner and 20 episodes from seed 3000 under it (the defense table's protocol).
# The run directory is under results/i14-fresh/ and committed as it goes: a fresh clone resumes after the last
# finished round (rerun this script). A step whose output exists is skipped.
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
env=${1:-Swimmer-v5} mode=${2:-physical} eps=${3:-0.005}
dir=results/i14-fresh/aril-$env-$mode
aril=.venv/bin/aril
[ -f $dir.pt ] || $aril train-learner algorithm:=aril env:=$env expert:=expert mode:=$mode eps:=$eps rounds:=10 \
  episodes:=5 hidden:=64 epochs:=20 lr:=0.001 batch:=256 adversary_steps:=1000000 warm_start:=false eval_episodes:=5 \
  seed:=0 run_dir:=$dir out:=$dir.pt threads:=1 >> $dir.log 2>&1
[ -f $dir-adversary.pt ] || $aril train-adversary env:=$env mode:=$mode eps:=$eps victim:=$dir.pt steps:=1000000 \
  seed:=1 out:=$dir-adversary.pt >> $dir.log 2>&1
[ -f $dir-eval.json ] || $aril eval env:=$env policy:=$dir.pt mode:=$mode attack:=aril_a attack_file:=$dir-adversary.pt \
  episodes:=20 seed:=3000 > $dir-eval.json 2>> $dir.log
