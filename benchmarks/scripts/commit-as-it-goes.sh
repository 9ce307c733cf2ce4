#!/usr/bin/env bash
# Runs a long command and commits what it has written under the given paths every $COMMIT_EVERY seconds (default
# 900), and once more when it ends or fails (its exit status is kept), so that a fresh clone resumes where it
# stopped: commands whose outputs are reused when they exist (trained files, caches) continue from the last commit.
# A file being written (*.tmp, *.partial*) is never committed.
#   benchmarks/scripts/commit-as-it-goes.sh "<what it makes>" <path>... -- <command> [arg...]
set -euo pipefail
cd "$(dirname "$0")/../.."  # the checkout
what=$1; shift
paths=()
while [ $# -gt 0 ] && [ "$1" != -- ]; do paths+=("$1"); shift; done
[ $# -gt 1 ] || { echo "usage: $0 \"<what it makes>\" <path>... -- <command> [arg...]" >&2; exit 2; }
shift

commit() {  # what has finished under the paths that hold a file by now; nothing new: no commit
  local there=() path
  for path in "${paths[@]}"; do  # git refuses a pathspec without a file (an empty directory), and then adds nothing
    if [ -n "$(find "$path" -type f ! -name '*.tmp' ! -name '*.partial*' -print -quit 2>/dev/null)" ] ||
      git ls-files --error-unmatch -- "$path" >/dev/null 2>&1; then there+=("$path"); fi
  done
  [ ${#there[@]} -gt 0 ] || return 0
  git add -A -- "${there[@]}" ":(exclude)*.tmp" ":(exclude)*.partial*" || true
  git commit -q -m "$1" -- "${there[@]}" >/dev/null || true
}

"$@" &
job=$!
trap 'kill $job 2>/dev/null' INT TERM
while true; do
  for _ in $(seq "${COMMIT_EVERY:-900}"); do kill -0 $job 2>/dev/null || break; sleep 1; done
  kill -0 $job 2>/dev/null || break  # its end gets the last commit
  commit "$what, under way: what has finished so far"
done
status=0
wait $job || status=$?
if [ $status -ne 0 ]; then  # what finished is kept; the same command resumes
  commit "$what, stopped (exit $status): what had finished"
  exit $status
fi
commit "$what"
