#!/usr/bin/env bash
# Runs a long command and commits what it has written under the given paths every $COMMIT_EVERY seconds (default
# 900), and once more when it ends or fails (its exit status is kept), so that a fresh clone resumes where it
# stopped: commands whose outputs are reused when they exist (trained files, caches) continue from the last commit.
# A file being written (*.tmp, *.partial*) is never committed. Paths after --at-end (inside the others or not) are
# committed only with the last commit: large files rewritten as the command goes (a training's aggregated data set),
# whose every version the periodic commits would otherwise add to the history.
#   benchmarks/scripts/commit-as-it-goes.sh "<what it makes>" <path>... [--at-end <path>...] -- <command> [arg...]
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
what=$1; shift
paths=() at_end=()
while [ $# -gt 0 ] && [ "$1" != -- ] && [ "$1" != --at-end ]; do paths+=("$1"); shift; done
if [ "${1:-}" = --at-end ]; then shift; while [ $# -gt 0 ] && [ "$1" != -- ]; do at_end+=("$1"); shift; done; fi
[ $# -gt 1 ] || { echo "usage: $0 \"<what it makes>\" <path>... [--at-end <path>...] -- <command> [arg...]" >&2
  exit 2; }
shift

commit() {  # $1: periodic or last; $2: the message. What has finished under the paths that hold a file by now
  local when=$1 message=$2 there=() path candidates=("${paths[@]}")
  [ "$when" = periodic ] || candidates+=("${at_end[@]}")
  for path in "${candidates[@]}"; do  # git refuses a pathspec without a file (an empty directory), and adds nothing
    if [ -n "$(find "$path" -type f ! -name '*.tmp' ! -name '*.partial*' -print -quit 2>/dev/null)" ] ||
      git ls-files --error-unmatch -- "$path" >/dev/null 2>&1; then there+=("$path"); fi
  done
  [ ${#there[@]} -gt 0 ] || return 0
  # staged, then a file being written (and, periodically, the at-end paths) unstaged: git 2.39's add with an
  # :(exclude) pathspec adds no untracked file under a subdirectory it names (seen with results/report-full/policies)
  git add -A -- "${there[@]}" || true
  local unstage=(':(glob)**/*.tmp' ':(glob)**/*.partial*')
  if [ "$when" = periodic ]; then for path in "${at_end[@]}"; do unstage+=("$path"); there+=(":(exclude)$path"); done; fi
  git reset -q -- "${unstage[@]}" 2>/dev/null || true
  git commit -q -m "$message" -- "${there[@]}" ":(exclude)*.tmp" ":(exclude)*.partial*" >/dev/null || true
}

"$@" &
job=$!
trap 'kill $job 2>/dev/null' INT TERM
while true; do
  for _ in $(seq "${COMMIT_EVERY:-900}"); do kill -0 $job 2>/dev/null || break; sleep 1; done
  kill -0 $job 2>/dev/null || break  # its end gets the last commit
  commit periodic "$what, under way: what has finished so far"
done
status=0
wait $job || status=$?
if [ $status -ne 0 ]; then  # what finished is kept; the same command resumes
  commit last "$what, stopped (exit $status): what had finished"
  exit $status
fi
commit last "$what"
