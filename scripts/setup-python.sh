#!/usr/bin/env bash
# Creates .venv with the Python test harness (cantools, python-can, pytest, gymnasium, maturin, and the
# renderer's mujoco wheel, imageio-ffmpeg, Pillow, moviepy) from PyPI, then builds the `dexstack`
# package (dexstack/, PyO3 + maturin) into it. Nothing is installed system-wide: rendering also
# needs Mesa's EGL or OSMesa from Debian, which scripts/test.sh installs (the last check here says
# whether a frame can be drawn, without failing). Idempotent: reinstalls the harness only when
# tests/requirements.txt changed; the package build is incremental (cargo), a few seconds when
# nothing changed.
# Needs MuJoCo (scripts/setup-mujoco.sh) for the package: it links libmujoco.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
command -v "$PY" >/dev/null || { echo "error: $PY not found; install Python 3.9+ (Debian: apt-get install python3 python3-venv)" >&2; exit 1; }
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv || { echo "error: cannot create .venv (Debian: apt-get install python3-venv)" >&2; exit 1; }
fi
stamp=.venv/.requirements.sha
want=$(sha256sum tests/requirements.txt | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  .venv/bin/python -m pip install --quiet --disable-pip-version-check -r tests/requirements.txt
  echo "$want" > "$stamp"
fi
[ -x .venv/bin/maturin ] || { echo "error: maturin is missing from .venv (tests/requirements.txt pins it; delete .venv/.requirements.sha and rerun)" >&2; exit 1; }
# The dev profile (optimised: see Cargo.toml's profile overrides) shares target/debug with the
# trainer binaries that the pytest step builds.
[ -e third_party/mujoco/lib/libmujoco.so ] || { echo "error: MuJoCo is not set up; run scripts/setup-mujoco.sh first" >&2; exit 1; }
VIRTUAL_ENV="$PWD/.venv" .venv/bin/maturin develop --quiet --locked -m dexstack/Cargo.toml >/dev/null \
  || { echo "error: building the dexstack package failed (maturin develop -m dexstack/Cargo.toml)" >&2; exit 1; }
.venv/bin/python -c 'import dexstack, gymnasium; gymnasium.make("dexstack/Reach-v0").reset(seed=0)' \
  || { echo "error: the dexstack package does not import or make an environment" >&2; exit 1; }
render_check='import dexstack, gymnasium as gym
e = gym.make("dexstack/Reach-v0", render_mode="rgb_array", width=32, height=32)
e.reset(seed=0); e.render(); e.close()'
if render_error=$(.venv/bin/python -c "$render_check" 2>&1); then
  echo "rendering: ok (a frame drawn with MuJoCo's offscreen renderer)"
else
  echo "warning: rendering is not available yet: $(echo "$render_error" | tail -n1)" >&2
fi
echo "python harness ready: .venv ($(.venv/bin/python -c 'import cantools, can, gymnasium, dexstack; print("cantools", cantools.__version__, "python-can", can.__version__, "gymnasium", gymnasium.__version__, "dexstack", dexstack.__version__)'))"
