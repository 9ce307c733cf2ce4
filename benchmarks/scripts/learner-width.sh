#!/usr/bin/env bash
# Issue 14: does the learner's width decide its robustness? The expert (256x256) keeps 4655 of its 5463 under a
# fresh ARIL-A on HalfCheetah physical, where every 64x64 learner falls to 442 or below. Trains learner $1 (aril:
# the bundled settings, 500k-step round adversaries warm-started; dr, dagger: the bundled DR's, DAgger's; DAgger collects
# clean whatever the mode, which then says only how it is judged) with $5 hidden units in env
# $2, mode $3, eps $4, then judges it as the defense table does (benchmarks/scripts/adversary-seeds.sh, ARIL-A seeds
# 0, 1, 2; aril-fresh-worst.sh). The run directory is under results/i14-fresh/ and resumes after its last round.
#   benchmarks/scripts/learner-width.sh aril HalfCheetah-v5 physical 0.03 256
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
algorithm=$1 env=$2 mode=$3 eps=$4 hidden=$5
dir=results/i14-fresh/$algorithm$hidden-$env-$mode
loop=""; [ $algorithm = aril ] && loop="adversary_steps:=500000 warm_start:=true"
[ -f $dir.pt ] || .venv/bin/aril train-learner algorithm:=$algorithm env:=$env expert:=expert mode:=$mode eps:=$eps \
  rounds:=10 episodes:=5 hidden:=$hidden epochs:=20 lr:=0.001 batch:=256 $loop eval_episodes:=5 seed:=0 \
  run_dir:=$dir out:=$dir.pt threads:=1 >> $dir.log 2>&1
for seed in 0 1 2; do benchmarks/scripts/adversary-seeds.sh $env $mode $eps $dir.pt $seed; done
benchmarks/scripts/aril-fresh-worst.sh $env $mode $eps $dir.pt
