#!/usr/bin/env bash
# The shipped Stack policy (policies/stack.dxpl since session 23; docs/experiments.md, session 23,
# confirmation 11): seven Stack clones of the imitation learner (Stack's recipe, seeds 1-7), then
# one network distilled from the mean of their actions with one DAgger round of 400 episodes; the
# shipped file is the distillation's round 1.
# Since session 24 that is the clone stage of `trainer train --task stack`'s default pipeline at
# seed 1 ([[clone.members]], docs/learner.md "A clone stage of members"): the members two at a
# time in OUT/clone/seed-1/default-sK, the distillation in OUT/clone/seed-1/distil, whose round 1
# is the file; the command then fine-tunes that file with the RL learner and guards the fine-tune
# against it (OUT/seed-1/guard.json says which of the two OUT/seed-1/policy.dxpl is).
# Usage: bash experiments/stack-distil.sh [OUT]   (default runs/stack-distil; the same command
# resumes a stopped or killed run, redoing no finished member).
# Compute on dev-2c (2 cores, 2026-12-04/05): members 553-945 s each on a loaded core, the
# distillation 943 s; about 50 min of wall to the distilled file by these figures, then the
# fine-tune (40,000 transitions) and the guard (500 starts). Not yet run end to end: the
# shipped file's members are session 14's clone (seed 1), session 22's seeds 2-3 and session 23's
# seeds 4-7, each made by `trainer imitate --task stack --seeds K` in its session (seed 1 on
# another machine, whose GEMM may round differently), so a fresh run may differ from
# policies/stack.dxpl in its bits. Checked in session 24 without running it: the pipeline's
# member of seed 2 has the settings of session 22's run of that seed (settings.json: only
# eval_threads differs, 1 against 2, which no file's bits depend on; the members differ only in
# their seeds), and its distillation has those of session 23's (the teacher's paths aside;
# test the_default_members_at_seed_one_are_the_shipped_recipes in
# trainer/src/pipeline/train_settings.rs). On Grasp the same stage reproduced the shipped file
# bit for bit (experiments/grasp-distil.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-runs/stack-distil}
. scripts/lib/target-dir.sh
bin=$(release_trainer)
"$bin" train --task stack --seeds 1 --out "$out" --resume
sha256sum "$out/clone/seed-1/distil/policy-1.dxpl" policies/stack.dxpl
