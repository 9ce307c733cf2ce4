#!/usr/bin/env bash
# Issue 14: the baselines that learn without the expert's labels on new states, as wide as the other learners of an
# env (learner-width.sh trains dagger, dart, dr and aril). Trains learner $1 (bc: the bundled BC's settings; gail:
# the bundled GAIL's, its generator $5 wide) with $5 hidden units in env $2, once for both modes (neither collects
# under attack), then judges it in mode $3 at eps $4 as the defense table does, through the link
# results/i14-fresh/<algorithm><hidden>-<env>-<mode>.pt (adversary-seeds.sh, ARIL-A seeds
# 0, 1, 2; aril-fresh-worst.sh). The learner is results/i14-fresh/<algorithm><hidden>-<env>.pt.
#   benchmarks/scripts/baseline-width.sh bc HalfCheetah-v5 physical 0.03 256
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
algorithm=$1 env=$2 mode=$3 eps=$4 hidden=$5
out=results/i14-fresh/$algorithm$hidden-$env.pt
if [ ! -f $out ]; then
  case $algorithm in
    bc) .venv/bin/aril train-bc env:=$env expert:=expert episodes:=10 hidden:=$hidden epochs:=30 lr:=0.001 batch:=256 \
          seed:=0 out:=$out >> ${out%.pt}.log 2>&1 ;;
    gail) .venv/bin/aril train-gail env:=$env expert:=expert demos:=10 steps:=1000000 hidden:=$hidden disc_hidden:=64 \
            disc_lr:=0.0003 disc_epochs:=2 disc_batch:=256 seed:=0 eval_every:=50000 eval_episodes:=5 out:=$out \
            threads:=1 >> ${out%.pt}.log 2>&1 ;;
    *) echo "baseline-width.sh: bc or gail, not $algorithm" >&2; exit 2 ;;
  esac
fi
# judged through a link named for the mode: the judgements' files are named after the learner file
judged=${out%.pt}-$mode.pt
ln -sfn $(basename $out) $judged
for seed in 0 1 2; do benchmarks/scripts/adversary-seeds.sh $env $mode $eps $judged $seed; done
benchmarks/scripts/aril-fresh-worst.sh $env $mode $eps $judged
