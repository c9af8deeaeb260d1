#!/usr/bin/env bash
# Compare the Rust Jaco environment with dm_control's stack_2_bricks_features, same MuJoCo (3.17.0), in one
# run. Installs mujoco and dm_control into a throwaway venv (.venv-dmc, git-ignored) on first use.
#
#   scripts/bench-dm-control.sh [STEPS]
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
STEPS="${1:-3000}"
VENV="$ROOT/.venv-dmc"
if [[ ! -x "$VENV/bin/python" ]]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet "mujoco==3.17.0" "dm_control==1.0.50"
fi
"$ROOT/scripts/setup-mujoco.sh" >/dev/null
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$ROOT/target-env}"
cargo build --release --quiet -p dex-trainer --bin env-tool
TOOL="$CARGO_TARGET_DIR/release/env-tool"
echo "== Rust (mujoco-rs), random actions, 50 ms control steps"
"$TOOL" bench --threads 1 --steps "$STEPS" --mode random
echo "== dm_control (Python), random actions"
MUJOCO_GL=disable "$VENV/bin/python" "$ROOT/scripts/bench-dm-control.py" "$STEPS"
