#!/usr/bin/env bash
# One 3-rank distributed run of TASK (default reach; rank 0 and two worker ranks, W = 1 thread each; the paper's
# learner, 128-128 networks, R = 2, 2 evaluation episodes every 20 episodes) for the throughput
# figures of docs/benchmarks.md ("Distributed ADPG-R on namespace hosts"): transitions/s and
# updates/s between the first and last evaluation record, exchanges/s, bytes per exchange (the
# messages; on namespace hosts also the bytes rank 0's link carried, from the bridge's counters),
# the workers' push-to-answer latency.
# On one host:         bash scripts/bench-cluster.sh OUT [TRANSITIONS=9000] [K=10]
# On namespace hosts:  bash scripts/cluster-sim.sh run --hosts 3 --rate 1gbit -- \
#                        bash scripts/bench-cluster.sh OUT [TRANSITIONS] [K]
# Environment: TRAINER (default target/release/trainer, built with --features mpi); TASK (reach,
# grasp, stack-in-hand or stack; default reach).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?OUT: the run folder}
budget=${2:-9000}
k=${3:-10}
bin=$(realpath "${TRAINER:-target/release/trainer}")
rm -rf "$out"; mkdir -p "$out"
out=$(realpath "$out")
task=${TASK:-reach}
case $task in reach|grasp|stack-in-hand|stack) ;; *) echo "error: TASK is reach, grasp, stack-in-hand or stack" >&2; exit 2 ;; esac
printf 'task = "%s"\n[run.eval]\nevery_episodes = 20\nepisodes = 2\n' "$task" > "$out.toml"
wire() { # bytes through rank 0's host link (h0 <-> bridge), both ways
  if [ -n "${CLUSTER_SIM_NS_PREFIX:-}" ]; then
    ip netns exec "$CLUSTER_SIM_NS_PREFIX-sw" sh -c \
      'echo $(( $(cat /sys/class/net/v0/statistics/tx_bytes) + $(cat /sys/class/net/v0/statistics/rx_bytes) ))'
  else echo 0; fi
}
source scripts/mpi-launch.sh
echo "== $task, $where, K = $k, $(uptime | sed 's/.*load/load/')"
w0=$(wire)
t0=$(date +%s.%N)
"${launch[@]}" -np 3 "$bin" train --distributed --config "$out.toml" --preset paper \
  --transitions "$budget" --checkpoint-every "$budget" --select-best-episodes 0 \
  --final-eval-episodes 10 --seeds 0 --quiet --exchange-every "$k" --out "$out" > "$out.log" 2>&1
t1=$(date +%s.%N)
w1=$(wire)
grep -E '^rank ' "$out.log" || true
python3 - "$out" "$t0" "$t1" "$w0" "$w1" <<'PY'
import json, re, sys
out, t0, t1, w0, w1 = sys.argv[1], *map(float, sys.argv[2:6])
rows = [json.loads(l) for l in open(f"{out}/seed-0/eval.jsonl") if l.strip()]
if len(rows) >= 2:
    a, b = rows[0], rows[-1]
    dt = b["wall_s"] - a["wall_s"]
    rates = (f"{(b['transitions'] - a['transitions']) / dt:.1f} transitions/s, "
             f"{(b['updates'] - a['updates']) / dt:.1f} updates/s between them")
else:
    rates = "too few records for rates between them (see the rank lines)"
st = json.load(open(f"{out}/seed-0/distributed.json"))
log = open(f"{out}.log").read()
wall0 = float(re.search(r"rank 0: .* in ([0-9.]+) s", log).group(1))
lat = [tuple(map(float, m)) for m in re.findall(r"latency mean ([0-9.]+) ms max ([0-9.]+) ms", log)]
per = (st["bytes_sent"] + st["bytes_received"]) / max(st["exchanges"], 1)
print(f"wall {t1 - t0:.1f} s; {len(rows)} records; {rates}; "
      f"{st['exchanges']} exchanges in {wall0:.1f} s = {st['exchanges'] / wall0:.1f}/s; "
      f"messages {per:,.0f} bytes per exchange"
      + (f", rank 0's link {(w1 - w0) / max(st['exchanges'], 1):,.0f} bytes per exchange" if w1 > w0 else "")
      + "; latency mean/max per worker rank (ms): " + ", ".join(f"{m:.1f}/{x:.1f}" for m, x in lat))
PY
rm -f "$out.toml"
