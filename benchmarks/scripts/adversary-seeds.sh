#!/usr/bin/env bash
# Issue 14: how much an ARIL-A's strength depends on its training seed. Trains ARIL-A (the defense table's settings,
# 1M steps) with seed $5 against policy $4 in env $1, mode $2 at eps $3, then evaluates it as the defense table does
# (20 episodes from env seed 3000); one JSON line per (policy, seed) into results/i14-fresh/adversary-seeds.jsonl.
# The adversaries are kept (committed) in results/i14-fresh/adversary-seeds/: one that exists is not trained again.
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
env=$1 mode=$2 eps=$3 policy=$4 seed=$5
out=results/i14-fresh/adversary-seeds/$(echo ${policy%.pt} | tr / _)-seed$seed.pt  # the whole path: bundled files share names
mkdir -p results/i14-fresh/adversary-seeds
[ -f $out ] || .venv/bin/aril train-adversary env:=$env mode:=$mode eps:=$eps victim:=$policy steps:=1000000 seed:=$seed \
  out:=$out > $out.log 2>&1
.venv/bin/aril eval env:=$env policy:=$policy mode:=$mode attack:=aril_a attack_file:=$out episodes:=20 seed:=3000 \
  2>/dev/null | tail -1 | python3 -c "import json, sys; d = json.load(sys.stdin); d['adversary_seed'] = $seed; print(json.dumps(d))" \
  >> results/i14-fresh/adversary-seeds.jsonl
