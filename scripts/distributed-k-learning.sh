#!/usr/bin/env bash
# What a larger exchange interval K costs in learning (issue #33, docs/benchmarks.md "The exchange
# against the link"): one 3-rank distributed run (rank 0 and two worker ranks, W = 1 thread each)
# of TASK's learner from demonstrations (`--preset demos`) with `--exchange-every K`, then its
# exported file (the best selection checkpoint) on EVAL final-evaluation starts. Prints the
# selection curve (30 starts every 5,000 transitions), the exchange counters (updates per push is
# the staleness a slow link forces) and the final success with its interval.
# Usage: bash scripts/distributed-k-learning.sh OUT K SEED [TASK=grasp] [TRANSITIONS=20000]
#   (on namespace hosts: bash scripts/cluster-sim.sh run --hosts 3 --rate 1gbit -- bash scripts/distributed-k-learning.sh ...)
# Environment: TRAINER (default target/release/trainer, built with --features mpi); EVAL (200).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?OUT: the run folder}
k=${2:?K: updates between a worker rank exchanges}
seed=${3:?SEED}
task=${4:-grasp}
budget=${5:-20000}
bin=$(realpath "${TRAINER:-target/release/trainer}")
rm -rf "$out"; mkdir -p "$out"
out=$(realpath "$out")
source scripts/mpi-launch.sh
t0=$(date +%s.%N)
"${launch[@]}" -np 3 "$bin" train --distributed --task "$task" --preset demos \
  --transitions "$budget" --seeds "$seed" --exchange-every "$k" \
  --final-eval-episodes "${EVAL:-200}" --quiet --out "$out" > "$out.log" 2>&1
t1=$(date +%s.%N)
grep -E '^rank |selection at' "$out.log" || true
python3 - "$out/seed-$seed" "$t0" "$t1" "$k" <<'PY'
import json, math, sys
d, t0, t1, k = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
s = json.load(open(f"{d}/distributed.json"))
f = json.load(open(f"{d}/final_eval.json"))
n = f.get("episodes") or 0
ok = round(f["success_rate"] * n)
z = 1.96
c = (ok + z * z / 2) / (n + z * z)
h = z * math.sqrt(ok * (n - ok) / n + z * z / 4) / (n + z * z) if n else 0
print(f"K = {k}: wall {t1 - t0:.1f} s; {s['exchanges']} exchanges; final evaluation {ok}/{n} "
      f"= {100 * ok / max(n, 1):.1f}% ({100 * (c - h):.1f}-{100 * (c + h):.1f}%) at {f['transitions']} transitions")
PY
