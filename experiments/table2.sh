#!/usr/bin/env bash
# The paper's Table II: success of the best Grasp, StackInHand and Stack policies over 1000 random
# starts (seeds from 3,000,000: apart from training, selection and final evaluations), through the
# exported policy files and the runtime, with 95% Wilson intervals. Paper: 99.2%, 98.2%, 95.5%.
# Usage: bash experiments/table2.sh [GRASP.dxpl STACK_IN_HAND.dxpl STACK.dxpl] [EPISODES]
# Defaults: seed 0 of the runs of experiments/figures/sparse-demo-tasks.toml, 1000 episodes.
set -euo pipefail
cd "$(dirname "$0")/.."
grasp=${1:-runs/grasp-sparse-demo/seed-0/policy.dxpl}
inhand=${2:-runs/stack-in-hand-sparse-demo/seed-0/policy.dxpl}
stack=${3:-runs/stack-sparse-demo/seed-0/policy.dxpl}
episodes=${4:-1000}
bin=./target/release/trainer
[ -x "$bin" ] || cargo build --release -p dex-trainer --bin trainer
echo "| task | policy | success over $episodes starts (95% CI) | paper |"
echo "|---|---|---|---|"
for row in "grasp $grasp 99.2%" "stack-in-hand $inhand 98.2%" "stack $stack 95.5%"; do
  set -- $row
  if [ ! -f "$2" ]; then
    echo "| $1 | $2 | missing: train it first | $3 |"
    continue
  fi
  line=$("$bin" eval "$2" --task "$1" --episodes "$episodes" --seed 3000000 2>/dev/null \
    | grep -E "success" | tail -n1 | sed 's/.*: success //')
  echo "| $1 | $2 | $line | $3 |"
done
