#!/usr/bin/env bash
# Updates/s of the learner's DDPG update, Rust engines and PyTorch CPU side by side in one run.
# Creates a throwaway venv .venv-torch (git-ignored; the PyPI torch wheel pulls ~4 GB of CUDA libraries
# that stay unused) and alternates ROUNDS rounds of the Rust bench and the PyTorch script, so both see
# the same machine load. Prints each side's best round.
#
# Usage: scripts/bench-torch.sh [ROUNDS] [SECONDS] [HIDDEN]   (HIDDEN: width of both hidden layers, 256)
set -euo pipefail
ROUNDS="${1:-5}"
SECONDS_PER="${2:-1}"
HIDDEN="${3:-256}"
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv-torch"
if [[ ! -x "$VENV/bin/python" ]] || ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q torch numpy
fi
cd "$ROOT"
cargo bench -p dex-trainer --bench learn_update --no-run
for i in $(seq 1 "$ROUNDS"); do
    echo "== round $i: rust" >&2
    cargo bench -q -p dex-trainer --bench learn_update -- 1 "$SECONDS_PER" "$HIDDEN" | tee "/tmp/bench-rust-$i.txt"
    echo "== round $i: torch" >&2
    OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 "$VENV/bin/python" scripts/bench-torch.py 1 "$SECONDS_PER" "$HIDDEN" \
        | tee "/tmp/bench-torch-$i.txt"
done
echo "== best of $ROUNDS rounds"
cat /tmp/bench-rust-*.txt | grep -E '^\| (Gemm|MatrixMultiply)' | sort -t'|' -k2,3 -k4nr \
    | awk -F'|' '!seen[$2 $3]++'
cat /tmp/bench-torch-*.txt | grep -E '^\| PyTorch' | sort -t'|' -k3,3 -k4nr | awk -F'|' '!seen[$3]++'
