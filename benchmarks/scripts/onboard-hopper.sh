#!/usr/bin/env bash
# Issue 17's demonstration: Hopper-v5 from nothing to a scorecard, with the two commands a user types, each timed.
# Resumable: rerun it after an interruption (onboarding resumes stage by stage from $ARIL_DATA, the scorecard
# reuses its trained adversaries). The user data folder is runs/aril-data (this machine's; its expert checkpoint
# holds the replay buffer); what it produced is copied to docs/onboarding/Hopper-v5/ for committing.
set -euo pipefail
cd "$(dirname "$0")/../.."
export ARIL_DATA=runs/aril-data
mkdir -p runs docs/onboarding/Hopper-v5
/usr/bin/time -f "onboard wall %e s" .venv/bin/aril onboard env:=Hopper-v5 expert_steps:=400000 2>&1 | tee -a runs/onboard-hopper.log
/usr/bin/time -f "scorecard wall %e s" .venv/bin/aril scorecard policy:=dagger env:=Hopper-v5 budget:=quick \
  out:=docs/scorecards/Hopper-v5-dagger 2>&1 | tee -a runs/scorecard-hopper.log
cp "$ARIL_DATA"/expert/Hopper-v5.pt docs/onboarding/Hopper-v5/expert.pt
cp "$ARIL_DATA"/dagger/Hopper-v5.pt docs/onboarding/Hopper-v5/dagger.pt
cp "$ARIL_DATA"/eps_calibration.json "$ARIL_DATA"/eps_calibration.md "$ARIL_DATA"/onboard/Hopper-v5/onboard.json \
  docs/onboarding/Hopper-v5/
grep -h "wall" runs/onboard-hopper.log runs/scorecard-hopper.log | tail -2
