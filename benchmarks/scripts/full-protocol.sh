#!/usr/bin/env bash
# Issue 18: the paper's full protocol (aril report budget:=full: 3 training seeds per defense, 50 episodes per cell,
# wide eps sweeps) for every env, committed as it goes (commit-as-it-goes.sh), so that a fresh clone continues where
# the last run stopped. The report's work directory, results/report-full/ ($WORK), holds the trained seeds, their
# adversaries (they serve any checkout) and the evaluation cache (known by content, not by path, and by the CPU model:
# it serves any checkout on the model that made it; another evaluates again); it is committed every
# $COMMIT_EVERY seconds (default 900) while the report runs, and at the end with docs/results.md and its figures.
# The run directories of the learners' trainings under way ($WORK/learners/: ARIL's runs last hours on one CPU and
# resume after their last finished round) are committed only at the end, or when the run is stopped: their
# aggregated data sets are tens of MB, rewritten every round.
# Arguments go to aril report after budget:=full and work_dir:=, so they can change either.
#   benchmarks/scripts/full-protocol.sh                     # the 2 CPUs of this machine
#   benchmarks/scripts/full-protocol.sh address:=auto       # a Ray cluster this machine has joined (docs/scaling.md)
#   benchmarks/scripts/full-protocol.sh envs:=Swimmer-v5 modes:=physical seeds:=0,1,2,3,4 evaluate:=false
#                                # trainings only, on a CPU model the committed cache does not serve (no report)
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
work=${WORK:-results/report-full}
mkdir -p "$work"
out=docs/results.md
for arg in "$@"; do case $arg in out:=*) out=${arg#out:=} ;; esac; done
benchmarks/scripts/commit-as-it-goes.sh "Full protocol: $out by aril report budget:=full $*" \
  "$work" "$work.log" "$out" "${out%.md}" --at-end "$work/learners" -- .venv/bin/aril report budget:=full work_dir:="$work" "$@" >> "$work.log" 2>&1
