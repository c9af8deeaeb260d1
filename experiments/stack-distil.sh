#!/usr/bin/env bash
# The shipped Stack policy (policies/stack.dxpl since session 23; docs/experiments.md, session 23,
# confirmation 11): seven Stack clones of the imitation learner (Stack's recipe, seeds 1-7), then
# one network distilled from the mean of their actions with one DAgger round; the shipped file is
# round 1 of seed 1.
# Usage: bash experiments/stack-distil.sh [OUT]   (default runs/stack-distil; resumes: each
# trainer imitate run folder redoes nothing it has). Two members run at a time (one per core).
# Compute on dev-2c (2 cores, 2026-12-04/05): members 553-945 s each on a loaded core, the
# distillation 943 s; about 50 min of wall in all by these figures. Not yet run end to end: the
# shipped file's members are session 14's clone (seed 1), session 22's seeds 2-3 and session 23's
# seeds 4-7, each made by the command below in its session (seed 1 on another machine, whose GEMM
# may round differently), so a fresh run may differ from policies/stack.dxpl in its bits.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/stack-distil}
bin=$(cargo metadata --format-version 1 --no-deps |
  python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')/release/trainer
[ -x "$bin" ] || cargo build --release -p dex-trainer --bin trainer
mkdir -p "$out"
member() { # SEED
  "$bin" imitate --task stack --seeds "$1" --final-eval-episodes 0 --quiet \
    --out "$out/def-s$1" > "$out/def-s$1.log" 2>&1
}
member 1 & member 2; wait
member 3 & member 4; wait
member 5 & member 6; wait
member 7
teachers=""
for s in 1 2 3 4 5 6 7; do
  teachers="$teachers${teachers:+,}$out/def-s$s/seed-$s/policy.dxpl"
done
"$bin" imitate --task stack --teacher-policies "$teachers" --rounds 1 --episodes-per-round 400 \
  --seeds 1 --final-eval-episodes 0 --quiet --out "$out/distil"
cp "$out/distil/seed-1/policy-1.dxpl" "$out/stack.dxpl"
sha256sum "$out/stack.dxpl" policies/stack.dxpl
