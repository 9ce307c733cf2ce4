#!/usr/bin/env bash
# Issue 14: the defense table's protocol for one learner file of aril-fresh-adversaries.sh (20 episodes from env seed
# 3000; clean, then random, FGSM, FGSM^k, SPSA^k at the cell's eps; its ARIL-A is that script's eval), one JSON line
# per attack into <learner>-attacks.jsonl (an attack already there is skipped).
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
env=$1 mode=$2 eps=$3
dir=results/i14-fresh/aril-$env-$mode
out=$dir-attacks.jsonl
touch $out
for attack in none random fgsm fgsm_k spsa; do
  grep -q "\"attack\": \"$attack\"" $out && continue
  m=$mode; [ $attack = none ] && m=clean
  .venv/bin/aril eval env:=$env policy:=$dir.pt mode:=$m attack:=$attack eps:=$eps episodes:=20 seed:=3000 \
    2>> $dir.log | tail -1 >> $out
done
