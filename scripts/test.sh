#!/usr/bin/env bash
# README command two: all set-up on a fresh machine, then every test. `.ci/run` calls this.
# Fails loudly at the first missing tool or failing step.
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/lib/target-dir.sh
start=$(date +%s)
step() { printf '\n==> [%4ss] %s\n' "$(( $(date +%s) - start ))" "$*"; }
# cargo's target probe runs `rustc -`, which reads its source from stdin: when /dev/null is not
# the null device (a program renamed a file over it; `trainer eval --actions /dev/null` once did,
# see trainer/src/files/atomic_write.rs) it reads whatever was last written there and the build fails
# with "failed to run `rustc` to learn about target-specific information". A machine that
# arrives so is mended (as root); a step of the suite that breaks it fails the suite.
null_device_ok() { [ -c /dev/null ]; }
if ! null_device_ok; then
  echo "warning: /dev/null is a $(stat -c %F /dev/null), not the null device: recreating it" >&2
  { rm -f /dev/null && mknod -m 666 /dev/null c 1 3; } ||
    { echo "error: cannot recreate /dev/null (needs root: rm /dev/null && mknod -m 666 /dev/null c 1 3)" >&2; exit 1; }
fi
exec </dev/null
need() { command -v "$1" >/dev/null || { echo "error: '$1' not found: $2" >&2; exit 1; }; }
# Installs the Debian packages among "$@" that are missing (apt-get; an update first if needed).
debian_install() {
  local missing
  missing=$(for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" || echo "$p"
  done)
  [ -z "$missing" ] && return 0
  # shellcheck disable=SC2086
  { apt-get install -y --no-install-recommends $missing >/dev/null 2>&1 \
    || { apt-get update >/dev/null && apt-get install -y --no-install-recommends $missing >/dev/null; }; } \
    || { echo "error: cannot install $(echo $missing) (apt-get; needs root)" >&2; exit 1; }
}

step "toolchain"
need cargo "install Rust with rustup (the pinned toolchain is in rust-toolchain.toml)"
need rustup "install Rust with rustup"
need python3 "install Python 3 (Debian: apt-get install python3 python3-venv)"
# RUSTUP_AUTO_INSTALL=0 on these machines: the toolchain file alone does not install the target.
rustup target add thumbv7em-none-eabihf >/dev/null
cargo --version

step "Debian packages (fonts for PNG plots)"
debian_install fonts-dejavu-core

step "Debian packages (Mesa's EGL and OSMesa for the dexstack renderer)"
# render_mode="rgb_array" and `python -m dexstack.render` draw with the mujoco wheel's offscreen
# renderer, headless through EGL (MUJOCO_GL=egl, the package's default without a display) or OSMesa;
# without a GPU, Mesa's llvmpipe software rasteriser draws (tests/test_dexstack_render.py).
render_pkgs="libegl1 libegl-mesa0 libgl1 libopengl0 libgl1-mesa-dri libosmesa6"
debian_install $render_pkgs

step "Debian packages (Open MPI and libclang for the trainer's mpi feature; iproute2 for the namespace hosts of scripts/cluster-sim.sh)"
# `--all-features` builds the trainer's `mpi` feature (the mpi crate's bindings need libclang)
# and trainer/tests/distributed.rs runs mpirun.
mpi_pkgs="openmpi-bin libopenmpi-dev libclang-dev iproute2"
debian_install $mpi_pkgs
need mpirun "install Open MPI (Debian: apt-get install openmpi-bin libopenmpi-dev)"

step "MuJoCo and Jaco assets (scripts/setup-mujoco.sh)"
bash scripts/setup-mujoco.sh

step "cargo fmt --check"
cargo fmt --all -- --check

step "docs/results.md against its records (python3 scripts/results.py --check)"
# The headline figures live in one generated page; it must match docs/results/*.json.
python3 scripts/results.py --check || { echo "error: docs/results.md is stale or a record is wrong (above)" >&2; exit 1; }

step "cargo clippy -D warnings"
cargo clippy --workspace --all-targets --all-features --locked -- -D warnings

step "cargo test"
cargo test --workspace --all-features --locked

# The benchmarks must keep running: each is built with the test profile (reusing what cargo test
# built) and run once in a quick mode. criterion's `control_step` runs every benchmark once when
# cargo test starts it; `learn_update` takes ROUNDS SECONDS. The timed runs are
# `cargo bench -p dex-runtime --bench control_step` and `cargo bench -p dex-trainer --bench
# learn_update` (docs/benchmarks.md).
step "benchmarks, each once (quick mode)"
cargo test -p dex-runtime --locked --bench control_step
cargo test -p dex-trainer --all-features --locked --bench learn_update -- 1 0.05

# After cargo test, so that the package's build (dev profile, target/debug) can reuse the
# dependencies cargo test has built instead of building most of them first on its own.
step "Python harness (scripts/setup-python.sh)"
bash scripts/setup-python.sh

step "no_std build for thumbv7em-none-eabihf (runtime, policy-format)"
cargo build -p dex-runtime -p dex-policy --target thumbv7em-none-eabihf --no-default-features --release --locked

step "fuzz targets build (fuzz/; run them with cargo +nightly fuzz, see docs/policy-format.md)"
cargo build --manifest-path fuzz/Cargo.toml --bins --locked

# The Python harness runs beside the firmware check: QEMU is single-threaded and counts
# instructions (-icount), so neither result depends on the other's load, and the suite saves
# about a minute and a half on two cores. Its output is printed when the firmware steps end.
step "python harness (pytest), in the background beside the firmware check"
pytest_log=$(mktemp "${TMPDIR:-/tmp}/dex-pytest.XXXXXX")
.venv/bin/python -m pytest -q tests/ >"$pytest_log" 2>&1 &
pytest_pid=$!
trap 'kill "$pytest_pid" 2>/dev/null || true; rm -f "$pytest_log"' EXIT

step "firmware under QEMU (scripts/firmware-check.sh)"
bash scripts/firmware-check.sh

step "firmware check with another CARGO_TARGET_DIR (the scripts find cargo's output there)"
# Developer set-ups often set CARGO_TARGET_DIR; the scripts ask cargo where it builds. A fresh
# folder, seeded with a copy of the firmware build just made when that is the workspace's own
# firmware/target (a cold build adds 2-3 min here; a shared CARGO_TARGET_DIR is not copied) but
# without its binaries: the check must build them there and find them there (those left in the
# usual folder were built for another policy, so reading them would fail the golden comparison).
fw_target=$(cargo_target_dir firmware)
host=$(rustc -vV | sed -n 's/^host: //p')
alt=$(mktemp -d "${TMPDIR:-/tmp}/dex-alt-target.XXXXXX")
trap 'rm -rf "$alt"; kill "$pytest_pid" 2>/dev/null || true; rm -f "$pytest_log"' EXIT
if [ "$fw_target" = "$PWD/firmware/target" ]; then
  cp -a "$fw_target/." "$alt/"
  rm -rf "$alt/firmware-check" "$alt/thumbv7em-none-eabihf/release/dex-firmware" "$alt/$host/release/fw-host"
fi
CARGO_TARGET_DIR="$alt" FIRMWARE_QUICK=1 bash scripts/firmware-check.sh
rm -rf "$alt"

step "firmware as the controller node in the closed loop (scripts/firmware-sil.sh)"
# QEMU's netduinoplus2 runs firmware/node; hil-sim (built with --all-features by cargo test above)
# bridges its SLCAN serial line to the lockstep bus with the MuJoCo plant (docs/firmware.md).
FIRMWARE_SIL_TRAINER=1 bash scripts/firmware-sil.sh

step "python harness (pytest): its output"
pytest_rc=0
wait "$pytest_pid" || pytest_rc=$?
cat "$pytest_log"
rm -f "$pytest_log"
trap - EXIT
[ "$pytest_rc" = 0 ] || { echo "error: pytest failed (exit status $pytest_rc)" >&2; exit 1; }

null_device_ok || { echo "error: a step above replaced /dev/null with a $(stat -c %F /dev/null)" >&2; exit 1; }
step "all green"
