#!/usr/bin/env bash
# Issue 14, part 3: outputs in runs/i14/ (a cell whose output exists is skipped: rerun to resume); finished files
# are copied into aril_ros/data/ (aril/<env>-<mode>.pt, defense-adversary/<env>-<mode>-<defense>.pt) and committed.
# One core of adversary training: the ARIL-A against each retrained ARIL learner as soon as it exists (so the pair
# can be bundled), otherwise the next non-ARIL defense cell; stops when every cell has its adversary.
cd "$(dirname "$0")/../.."  # the checkout
train() { env=$1 mode=$2 victim=$3 out=$4
  eps=$(.venv/bin/python -c "from aril_ros.registry import calibrated_eps; print(calibrated_eps('$env','$mode'))")
  .venv/bin/aril train-adversary env:=$env mode:=$mode eps:=$eps victim:=$victim expert:=expert steps:=1000000 \
    out:=$out threads:=1 > ${out%.pt}.log 2>&1
}
next() {
  for env in HalfCheetah-v5 Swimmer-v5 Ant-v5; do for mode in sensory physical; do
    out=runs/i14/def/$env-$mode-aril.pt
    [ -f $out ] || { [ -f runs/i14/aril-$env-$mode.pt ] && { echo "$env $mode runs/i14/aril-$env-$mode.pt $out"; return; }; }
  done; done
  for env in HalfCheetah-v5 Swimmer-v5 Ant-v5; do for mode in sensory physical; do for d in bc dart dr gail; do
    out=runs/i14/def/$env-$mode-$d.pt
    [ -f $out ] && continue
    victim=$(.venv/bin/python -c "from aril_ros.registry import bundled_file; print(bundled_file('$d','$env','$mode'))")
    echo "$env $mode $(realpath --relative-to=. "$victim") $out"; return
  done; done; done
}
while :; do
  job=$(next)
  if [ -z "$job" ]; then
    ls runs/i14/aril-*-*.pt 2>/dev/null | wc -l | grep -q '^6$' && break
    sleep 60; continue
  fi
  train $job
done
