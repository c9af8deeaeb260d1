#!/usr/bin/env bash
# The paper's Table II: success of the best Grasp, StackInHand and Stack policies over 1000 random
# starts (seeds from 3,000,000: apart from training, selection and final evaluations), through the
# exported policy files and the runtime, with 95% Wilson intervals. Paper: 99.2%, 98.2%, 95.5%.
# Usage: bash experiments/table2.sh [GRASP.dxpl STACK_IN_HAND.dxpl STACK.dxpl] [EPISODES]
# Defaults: the shipped policies (policies/README.md: the imitation learner), 1000 episodes. The
# DDPG runs of the earlier sessions: runs/{grasp,stack-in-hand,stack}-sparse-demo/seed-0/policy.dxpl.
set -euo pipefail
cd "$(dirname "$0")/.."
grasp=${1:-policies/grasp.dxpl}
inhand=${2:-policies/stack-in-hand.dxpl}
stack=${3:-policies/stack.dxpl}
episodes=${4:-1000}
. scripts/lib/target-dir.sh
bin=$(release_trainer)
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
