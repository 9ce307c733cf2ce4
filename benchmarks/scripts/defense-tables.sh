#!/usr/bin/env bash
# Issue 14, item 3: both defense tables (Tables 1 and 2, Robust IL rows) with each cell's ARIL-A the strongest of
# three trained against that very defense (aril defense-table adversary_seeds:=3), committed as it goes
# (commit-as-it-goes.sh): the adversaries trained so far, and the tables once made. Adversaries that exist for the
# bundled learners are reused (bundle_widths.py, quoted in results/tuning-drivers.md, copied in the ones that judged them), so the same
# command resumes on a fresh clone. Arguments go to both aril defense-table runs (e.g. workers:=, address:=).
#   benchmarks/scripts/defense-tables.sh
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
log=results/defenses.log
benchmarks/scripts/commit-as-it-goes.sh "Defense tables, each ARIL-A the strongest of three seeds" \
  aril_ros/data/defense-adversary aril_ros/data/adversary results/defenses_sensory.json results/defenses_sensory.md \
  results/defenses_physical.json results/defenses_physical.md $log -- \
  bash -c 'for mode in sensory physical; do .venv/bin/aril defense-table mode:=$mode adversary_seeds:=3 "$@" || exit; done' \
  _ "$@" >> $log 2>&1
