#!/usr/bin/env bash
# Does the Markov teacher recover from the states where a Grasp policy stalls on brick 2? For each
# final-evaluation episode given (indices from seed 1,000,000, as `task_failures --verbose` numbers
# them), the policy drives until a hand body first touches brick 2; then the teacher acts, once as
# shipped and once tucking first (`MarkovDemonstrator::with_tuck_first`). Prints one line per
# episode and the counts (docs/experiments.md, session 21, "A teacher that tucks first").
# Usage: bash scripts/teacher-handover.sh POLICY.dxpl EPISODE...
#   e.g. the session-14 clone's 26 failures of 2000 (shipped until session 22):
#   bash scripts/teacher-handover.sh trainer/tests/fixtures/grasp_clone_session14.dxpl 145 159 190 236 381 477 664 675 848 910 \
#     980 997 1062 1120 1308 1442 1478 1494 1509 1649 1667 1726 1743 1829 1913 1985
set -euo pipefail
cd "$(dirname "$0")/.."
policy=${1:?POLICY: a Grasp policy file}
shift
[ $# -gt 0 ] || { echo "error: name at least one episode" >&2; exit 2; }
cargo build --release -q -p dex-trainer --example grasp_failure_trace
trace=target/release/examples/grasp_failure_trace
tmp=$(mktemp); trap 'rm -f "$tmp"' EXIT
plain=0 tucking=0 stalled=0
for e in "$@"; do
  "$trace" "$policy" --episode "$e" > "$tmp"
  step=$(awk '$1 ~ /^[0-9]+$/ && / 2:/ {print $1; exit}' "$tmp")
  if [ -z "$step" ]; then echo "episode $e: the hand never touches brick 2"; continue; fi
  stalled=$((stalled + 1))
  a=$("$trace" "$policy" --episode "$e" --handover "$step" | awk '/^end:/ {print $3}' | tr -d ,)
  b=$("$trace" "$policy" --episode "$e" --handover "$step" --tuck-first | awk '/^end:/ {print $3}' | tr -d ,)
  [ "$a" = true ] && plain=$((plain + 1))
  [ "$b" = true ] && tucking=$((tucking + 1))
  echo "episode $e: brick 2 touched at step $step; the teacher recovers: $a; tucking first: $b"
done
echo "recovered: the teacher $plain of $stalled, tucking first $tucking of $stalled"
