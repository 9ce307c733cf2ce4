#!/usr/bin/env bash
# Issue 14, part 3: outputs in runs/i14/ (a cell whose output exists is skipped: rerun to resume); finished files
# are copied into aril_ros/data/ (aril/<env>-<mode>.pt, defense-adversary/<env>-<mode>-<defense>.pt) and committed.
# Retrain ARIL (Algorithm 1 unchanged, the new default adversary in its loop), the bundled commands per cell.
cd "$(dirname "$0")/../.."  # the checkout
run() { env=$1 mode=$2 eps=$3
  out=runs/i14/aril-$env-$mode.pt
  [ -f $out ] && return
  .venv/bin/aril train-learner algorithm:=aril env:=$env expert:=expert mode:=$mode eps:=$eps rounds:=10 episodes:=5 \
    hidden:=64 epochs:=20 lr:=0.001 batch:=256 adversary_steps:=500000 warm_start:=true eval_episodes:=5 seed:=0 \
    run_dir:=runs/i14/aril-$env-$mode out:=$out threads:=1 > runs/i14/aril-$env-$mode.log 2>&1
}
run HalfCheetah-v5 sensory 0.04
run Swimmer-v5 sensory 0.3
run HalfCheetah-v5 physical 0.03
run Swimmer-v5 physical 0.005
run Ant-v5 sensory 0.03
run Ant-v5 physical 0.01
