#!/usr/bin/env bash
# README command one: all set-up on a fresh machine, then the main job: learn Grasp (the imitation
# learner: 600 episodes of the Markov demonstrator, 200 clean and 400 with DART noise, cloned into a
# 58-256-256-9 policy that takes the controller's task features; 2-4 min), export the policy file,
# evaluate the file through the controller's runtime on 200 unseen starts, and show what is in it.
# Extra arguments go to `trainer imitate` (e.g. --task stack-in-hand --seeds 0,1,2).
set -euo pipefail
cd "$(dirname "$0")/.."
command -v cargo >/dev/null || { echo "error: cargo not found: install Rust with rustup" >&2; exit 1; }
command -v python3 >/dev/null || { echo "error: python3 not found (needed to fetch MuJoCo from PyPI)" >&2; exit 1; }
if [ ! -f /usr/share/fonts/truetype/dejavu/DejaVuSans.ttf ]; then
  echo "installing fonts-dejavu-core (plot labels)"
  apt-get install -y --no-install-recommends fonts-dejavu-core >/dev/null 2>&1 \
    || { apt-get update >/dev/null && apt-get install -y --no-install-recommends fonts-dejavu-core >/dev/null; } \
    || { echo "error: cannot install fonts-dejavu-core (needed for PNG plots)" >&2; exit 1; }
fi
bash scripts/setup-mujoco.sh
cargo build --release --locked -p dex-trainer --bin trainer -p dex-policy-tool --bin policy
. scripts/lib/target-dir.sh
BIN=$(cargo_target_dir)/release
OUT=${OUT:-runs/main}
"$BIN/trainer" imitate --out "$OUT" --final-eval-episodes 0 "$@"   # --task grasp is the default
"$BIN/trainer" eval "$OUT/seed-0/policy.dxpl" --episodes 200
"$BIN/policy" inspect "$OUT/seed-0/policy.dxpl"
echo "plots: $OUT/return.png $OUT/success.png"
