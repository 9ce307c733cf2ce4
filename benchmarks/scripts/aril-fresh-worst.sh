#!/usr/bin/env bash
# Issue 14: the defense table's protocol for one learner file (20 episodes from env seed 3000; clean, then random,
# FGSM, FGSM^k, SPSA^k at the cell's eps; ARIL-A: benchmarks/scripts/adversary-seeds.sh), one JSON line per attack
# into <learner without .pt>-attacks.jsonl (an attack already there is skipped).
#   benchmarks/scripts/aril-fresh-worst.sh Swimmer-v5 physical 0.005 results/i14-fresh/aril-Swimmer-v5-physical.pt
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
env=$1 mode=$2 eps=$3 learner=$4
out=${learner%.pt}-attacks.jsonl
touch $out
for attack in none random fgsm fgsm_k spsa; do
  grep -q "\"attack\": \"$attack\"" $out && continue
  m=$mode; [ $attack = none ] && m=clean
  .venv/bin/aril eval env:=$env policy:=$learner mode:=$m attack:=$attack eps:=$eps episodes:=20 seed:=3000 \
    2>/dev/null | tail -1 >> $out
done
