#!/usr/bin/env bash
# Creates .venv with the Python test harness (cantools, python-can, pytest) from PyPI.
# Idempotent: reinstalls only when tests/requirements.txt changed.
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
echo "python harness ready: .venv ($(.venv/bin/python -c 'import cantools, can; print("cantools", cantools.__version__, "python-can", can.__version__)'))"
