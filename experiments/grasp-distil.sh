#!/usr/bin/env bash
# The shipped Grasp policy (policies/grasp.dxpl since session 22; docs/experiments.md, session 22,
# confirmation 8): eight Grasp clones of the imitation learner, then one network distilled from the
# mean of their actions with two DAgger rounds; the shipped file is round 1 of seed 1.
# Usage: bash experiments/grasp-distil.sh [OUT]   (default runs/grasp-distil; resumes: each
# trainer imitate run folder redoes nothing it has). Two members run at a time (one per core).
# Compute on dev-2c (2 cores, 2026-12-04): about 16 min of wall in all (the members two at a time,
# then the distillation's three rounds, 301 s); it reproduced policies/grasp.dxpl bit for bit.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/grasp-distil}
bin=$(cargo metadata --format-version 1 --no-deps |
  python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')/release/trainer
[ -x "$bin" ] || cargo build --release -p dex-trainer --bin trainer
mkdir -p "$out"
member() { # NAME SEED FLAGS...
  local name=$1 seed=$2
  shift 2
  "$bin" imitate --task grasp --seeds "$seed" "$@" --final-eval-episodes 0 --quiet \
    --out "$out/$name" > "$out/$name.log" 2>&1
}
# The members: the default recipe's seeds 0-3 (seed 0 is the clone shipped before session 22),
# close bursts 0.02 seeds 0-1, the teacher that tucks first seeds 0-1 (sessions 20-21).
member def-s0 0 & member def-s1 1; wait
member def-s2 2 & member def-s3 3; wait
member cb-s0 0 --close-bursts 0.02 & member cb-s1 1 --close-bursts 0.02; wait
member tf-s0 0 --tuck-first & member tf-s1 1 --tuck-first; wait
teachers=""
for m in def-s0:0 def-s1:1 def-s2:2 def-s3:3 cb-s0:0 cb-s1:1 tf-s0:0 tf-s1:1; do
  teachers="$teachers${teachers:+,}$out/${m%%:*}/seed-${m##*:}/policy.dxpl"
done
"$bin" imitate --task grasp --teacher-policies "$teachers" --rounds 2 --episodes-per-round 400 \
  --seeds 1 --final-eval-episodes 0 --quiet --out "$out/distil"
cp "$out/distil/seed-1/policy-1.dxpl" "$out/grasp.dxpl"
sha256sum "$out/grasp.dxpl" policies/grasp.dxpl
