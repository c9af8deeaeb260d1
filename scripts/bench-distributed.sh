#!/usr/bin/env bash
# Throughput of `trainer train --distributed` for N = 1, 2, 3 ranks on this machine
# (docs/benchmarks.md, "Distributed ADPG-R over MPI"). Reach, the paper's learner, W = 1 thread
# per worker rank, R = 2, 9,000 transitions, no selection, 2 evaluation episodes every 20. Prints per N the wall time, the
# transitions/s and updates/s between the first and last evaluation records (updates run from
# the first record on), each worker rank's exchange line, and `uptime` before and after.
# Usage: bash scripts/bench-distributed.sh [TRAINER]   (default target/release/trainer, built
# with --features mpi)
set -euo pipefail
cd "$(dirname "$0")/.."
bin=${1:-target/release/trainer}
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
for n in 1 2 3; do
  out=$(mktemp -d "${TMPDIR:-/tmp}/dex-bench-mpi.XXXXXX")
  # An evaluation (2 episodes) every 20 episodes, so every N has records to time between.
  printf 'task = "reach"\n[run.eval]\nevery_episodes = 20\nepisodes = 2\n' > "$out.toml"
  echo "== N = $n ranks ($(uptime | sed 's/.*load/load/'))"
  t0=$(date +%s.%N)
  mpirun --oversubscribe --mca btl tcp,self -np "$n" "$bin" train --distributed --config "$out.toml" \
    --preset paper --transitions 9000 --checkpoint-every 9000 --select-best-episodes 0 \
    --final-eval-episodes 10 --seeds 0 --quiet --out "$out" 2>&1 | grep -E '^rank ' || true
  t1=$(date +%s.%N)
  python3 - "$out/seed-0/eval.jsonl" "$t0" "$t1" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
a, b = rows[0], rows[-1]
dt = b["wall_s"] - a["wall_s"]
print(f"wall {float(sys.argv[3]) - float(sys.argv[2]):.1f} s (whole command); {len(rows)} records; "
      f"from {a['transitions']} to {b['transitions']} transitions in {dt:.1f} s: "
      f"{(b['transitions'] - a['transitions']) / dt:.1f} transitions/s, "
      f"{(b['updates'] - a['updates']) / dt:.1f} updates/s")
PY
  rm -rf "$out" "$out.toml"
done
uptime
