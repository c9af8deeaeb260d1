#!/usr/bin/env bash
# A distributed run (3 ranks; Reach unless TASK says otherwise) with a fault on worker rank 2 once the first checkpoint is
# written: `kill` (SIGKILL), `stop` (SIGSTOP, then SIGCONT after HOLD s) or `cut` (its host's
# cable out of the bridge for HOLD s, then back in; only inside scripts/cluster-sim.sh), or
# `none` (the same run undisturbed, to compare the policies with). Prints
# rank 0's membership lines, the ranks' counter lines, mpirun's status, the run's transitions and
# the final evaluation (docs/distributed.md, "Faults"; docs/benchmarks.md).
# Usage: bash scripts/distributed-fault-run.sh MODE OUT [TRANSITIONS=12000] [HOLD=15]
#   (under cluster-sim: bash scripts/cluster-sim.sh run --hosts 3 -- bash scripts/distributed-fault-run.sh cut runs/x)
# Environment: TRAINER (default target/release/trainer, built with --features mpi); TASK (reach,
# the default, or grasp); LEARNER: `paper` (default: the paper's learner, --preset paper),
# `demos` (the learner from demonstrations, --preset demos) or `default` (the task's default
# pipeline: for Reach the learner from demonstrations that reaches 100%); EVAL (final evaluation
# episodes, default 50); RESPAWN (seconds: `--respawn-after`, rank 0 replaces a rank lost that long
# by a new one; off when unset).
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:?MODE: kill, stop or cut}
out=${2:?OUT: the run folder}
budget=${3:-12000}
hold=${4:-15}
bin=$(realpath "${TRAINER:-target/release/trainer}")
case $mode in kill|stop|none) ;; cut) [ -n "${CLUSTER_SIM_CUT:-}" ] || { echo "error: cut needs scripts/cluster-sim.sh" >&2; exit 2; } ;;
  *) echo "error: MODE is kill, stop, cut or none" >&2; exit 2 ;; esac
case ${LEARNER:-paper} in paper) learner=(--preset paper) ;; demos) learner=(--preset demos) ;;
  default) learner=() ;; *) echo "error: LEARNER is paper, demos or default" >&2; exit 2 ;; esac
task=${TASK:-reach}
case $task in reach|grasp) ;; *) echo "error: TASK is reach or grasp" >&2; exit 2 ;; esac
evals=${EVAL:-50}
respawn=()
[ -n "${RESPAWN:-}" ] && respawn=(--respawn-after "$RESPAWN")
rm -rf "$out"; mkdir -p "$out"
out=$(realpath "$out")
source scripts/mpi-launch.sh
# A replacement needs a free slot (the dead rank's is not given back): cluster-sim's hosts have one
# slot each.
if [ -n "${RESPAWN:-}" ] && [[ " ${launch[*]} " != *" --oversubscribe "* ]]; then
  launch+=(--oversubscribe)
fi
log="$out.log"
t0=$(date +%s.%N)
"${launch[@]}" --mca orte_abort_on_non_zero_status 0 -np 3 "$bin" train --distributed --task "$task" \
  "${learner[@]}" --checkpoint-every 2000 --select-best-episodes 0 --final-eval-episodes "$evals" \
  --seeds 0 --quiet --rank-timeout 5 "${respawn[@]}" --transitions "$budget" --out "$out" >"$log" 2>&1 &
job=$!
stamp() { printf '%7.1f s  %s\n' "$(echo "$(date +%s.%N) - $t0" | bc)" "$*"; }
while [ ! -e "$out/seed-0/checkpoint.bin" ]; do
  kill -0 "$job" 2>/dev/null || { stamp "the run ended before its first checkpoint"; cat "$log"; exit 1; }
  sleep 0.2
done
rank2=""
for p in $(pgrep -f -- "--out $out" || true); do
  if tr '\0' '\n' < "/proc/$p/environ" 2>/dev/null | grep -qx OMPI_COMM_WORLD_RANK=2; then rank2=$p; fi
done
[ -n "$rank2" ] || { echo "error: rank 2's process not found" >&2; kill "$job"; exit 1; }
case $mode in
  none) stamp "no fault" ;;
  kill) stamp "SIGKILL to rank 2 (pid $rank2)"; kill -KILL "$rank2" ;;
  stop) stamp "SIGSTOP to rank 2 (pid $rank2)"; kill -STOP "$rank2"; sleep "$hold"
        stamp "SIGCONT to rank 2"; kill -CONT "$rank2" ;;
  cut)  stamp "h2's cable out"; "$CLUSTER_SIM_CUT" h2; sleep "$hold"
        stamp "h2's cable back in"; "$CLUSTER_SIM_RESTORE" h2 ;;
esac
set +e
wait "$job"
rc=$?
set -e
stamp "mpirun exited with $rc"
grep -E '^(rank [0-9]+:|error:)' "$log" || true
python3 - "$out/seed-0" <<'PY'
import json, sys
d = sys.argv[1]
s = json.load(open(f"{d}/distributed.json"))
f = json.load(open(f"{d}/final_eval.json"))
print(f"distributed.json: exchanges {s['exchanges']}, lost {s['lost']}, readmitted {s['readmitted']}, "
      f"replaced {s.get('replaced', 0)}; changes "
      f"{[(c['rank'], c['kind'], round(c['silent_s'], 1), c['transitions'], c.get('by')) for c in s['rank_changes']]}")
print(f"final evaluation: {f['transitions']} transitions, success {f['success_rate']:.2f} "
      f"over {f.get('episodes', '?')} episodes")
PY
