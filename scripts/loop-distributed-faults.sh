#!/usr/bin/env bash
# Runs the lost-rank tests of trainer/tests/distributed.rs (a worker rank SIGKILLed: the run
# finishes without it; SIGKILLed with --respawn-after: replaced by a spawned rank; SIGSTOPped:
# lost, then re-admitted at SIGCONT; the only worker rank
# killed: rank 0 checkpoints, fails naming it, and the run resumes) N times each, one after the
# other, and prints one line per run. Used to find the
# 1-in-7 hang of these tests (docs/distributed.md, "Faults"). Builds into its own target folder
# (runs/target-faults) so other builds cannot swap the trainer binary under a running test.
# Usage: bash scripts/loop-distributed-faults.sh [N=15]
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-15}
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-runs/target-faults}
cargo build --release --all-features --locked -p dex-trainer --tests >/dev/null
bin=$(find "$CARGO_TARGET_DIR/release/deps" -name 'distributed-*' -type f -executable | head -1)
[ -n "$bin" ] || { echo "error: no distributed test binary under $CARGO_TARGET_DIR" >&2; exit 1; }
mkdir -p runs/fault-loop
pass=0; fail=0
for i in $(seq 1 "$n"); do
  for t in killed_worker_rank_is_left killed_worker_rank_is_replaced stopped_worker losing_the_only; do
    log=runs/fault-loop/$t-$i.log
    if timeout 200 "$bin" "$t" --nocapture >"$log" 2>&1; then
      pass=$((pass + 1)); echo "$i $t ok"; rm -f "$log"
    else
      fail=$((fail + 1)); echo "$i $t FAILED (log: $log)"
    fi
  done
done
echo "passed $pass, failed $fail"
[ "$fail" = 0 ]
