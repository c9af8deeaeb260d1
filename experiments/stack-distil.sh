#!/usr/bin/env bash
# The Stack policy shipped from session 23 to session 37 (now policies/history/stack-session23.dxpl;
# docs/experiments.md, session 23, confirmation 11): seven Stack clones of the imitation learner (Stack's recipe, seeds 1-7), then
# one network distilled from the mean of their actions with one DAgger round of 400 episodes; the
# shipped file is the distillation's round 1.
# From session 24 to 37 that was the clone stage of `trainer train --task stack`'s default pipeline
# at seed 1 (since session 38 the default is one close-start clone, policies/stack.dxpl; this
# recipe is experiments/stack-distil.toml) ([[clone.members]], docs/learner.md "A clone stage of members"): the members two at a
# time in OUT/clone/seed-1/default-sK, the distillation in OUT/clone/seed-1/distil, whose round 1
# is the file; the command then fine-tunes that file with the RL learner and guards the fine-tune
# against it (OUT/seed-1/guard.json says which of the two OUT/seed-1/policy.dxpl is).
# Usage: bash experiments/stack-distil.sh [OUT]   (default runs/stack-distil; the same command
# resumes a stopped or killed run, redoing no finished member).
# Verified end to end in sessions 24-25 (dev-2c, 2 cores shared with one to three other jobs,
# 2026-12-05 03:54-05:42 UTC, stopped between the sessions and resumed with the same command):
# the seven members are bit for bit the shipped file's (session 14's clone for seed 1, sha256
# 2f83e346c584...; session 22's seeds 2-3; session 23's seeds 4-7), the distilled file
# OUT/clone/seed-1/distil/policy-1.dxpl is that file (sha256 1f15aadc0503...), the
# fine-tune lost to it on the guard's 500 starts (486 against 498, p = 0.0005), so the guard
# shipped it unchanged and OUT/seed-1/policy.dxpl is that file bit for bit too. Wall,
# two at a time: members 1089 s (seeds 1-2), 604 s (3-4), 848 s (5-6), 584 s (7); distillation
# 651 s (round 0) + 768 s (round 1); fine-tune and guard about 5 min: about 81 min in all.
# That was the runtime up to session 27 (commit 42422b5): since session 28 the task features' f32
# sines and cosines change the cloning data's last bits, so the script makes a file of the same
# recipe, not this one bit for bit (policies/README.md).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/stack-distil}
. scripts/lib/target-dir.sh
bin=$(release_trainer)
"$bin" train --config experiments/stack-distil.toml --preset finetune --out "$out" --resume
sha256sum "$out/clone/seed-1/distil/policy-1.dxpl" "$out/seed-1/policy.dxpl" \
    policies/history/stack-session23.dxpl
