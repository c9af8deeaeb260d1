#!/usr/bin/env bash
# Firmware SIL: the firmware image (firmware/node, `dex-node`) in QEMU's netduinoplus2 as the
# controller node on the virtual CAN bus, the MuJoCo plant on the other side, lockstep. Its CAN is
# SLCAN on USART1, joined to the bus by `hil-sim slcan-bridge --stamp` (docs/firmware.md).
#
#   scripts/firmware-sil.sh                       # everything (CI)
#   FIRMWARE_SIL_EPISODES=5 scripts/firmware-sil.sh
#   FIRMWARE_SIL_TRAINER=1 scripts/firmware-sil.sh  # also against trainer eval (builds the trainer)
#   FIRMWARE_SIL_TIMEOUT=1200                       # bound on the whole run in seconds (default)
#
# Checks, each against the host controller node (`hil-sim bus --lockstep --controller`) given the
# same frames:
#   1. the policy (policies/grasp-128.dxpl, the shipped 58-128-128-9 Grasp network, quantised to
#      int8 by `policy quantise`: 29 kB, inside the firmware's 32 KiB RAM slots; policies/grasp.dxpl,
#      334 kB, is not, see docs/firmware.md) is flashed over the bus into the firmware's slot
#      (`hil-sim flash`: CANopen program download through the bridge), not built in;
#   2. a second flash (runtime/tests/golden/jaco_64.dxpl) cut on the wire after 2 s: the firmware
#      keeps the first policy (one COMMIT in its log, and step 3's actions) and its SDO server
#      aborts the stale transfer (0x0504_0000) once bus time passes the SDO timeout;
#   3. N lockstep episodes of the MuJoCo Grasp task from `trainer eval`'s starts: every applied
#      action (`hil-sim plant --actions`) identical to the host node's, the same returns and success;
#      with FIRMWARE_SIL_TRAINER=1 (scripts/test.sh) also identical to `trainer eval --envelope
#      --actions` for the same starts (the runtime's evaluator without a bus);
#   4. the watchdog: SYNC for 8 periods without observations: emergency 0x8250, every frame
#      identical to the host node's;
#   5. bad input straight on the serial line (another QEMU): garbage, half and over-long lines, a
#      flood of 3,000 frames: refused with BEL, accounted in the firmware's STATUS line, heartbeat
#      kept, NMT still answered (scripts/firmware_sil.py bad-input).
# Exits non-zero, loudly, on any difference, missing tool or timeout.
set -euo pipefail

# The whole run under one bound (cold builds included), so that nothing can hang CI: on the
# bound the inner run is stopped, its processes are killed (EXIT trap) and the status is 124.
if [ -z "${FIRMWARE_SIL_INNER:-}" ]; then
    rc=0
    FIRMWARE_SIL_INNER=1 timeout "${FIRMWARE_SIL_TIMEOUT:-1200}" bash "$0" "$@" || rc=$?
    [ "$rc" = 124 ] && echo "firmware-sil: FAIL: timed out after ${FIRMWARE_SIL_TIMEOUT:-1200} s" >&2
    exit "$rc"
fi
trap 'exit 143' TERM

ROOT=$(cd "$(dirname "$0")/.." && pwd)
FW="$ROOT/firmware"
TARGET=thumbv7em-none-eabihf
EPISODES=${FIRMWARE_SIL_EPISODES:-3}
TASK=grasp

die() {
    echo "firmware-sil: FAIL: $*" >&2
    exit 1
}
step() { echo "== firmware-sil: $*"; }
start=$(date +%s)

# --- tools ---------------------------------------------------------------------------------------
if ! command -v qemu-system-arm >/dev/null; then
    step "installing qemu-system-arm"
    SUDO=""
    if [ "$(id -u)" != 0 ]; then
        command -v sudo >/dev/null || die "need qemu-system-arm and neither root nor sudo to install it"
        SUDO=sudo
    fi
    $SUDO apt-get install -y --no-install-recommends qemu-system-arm >/dev/null ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y --no-install-recommends qemu-system-arm >/dev/null; } ||
        die "apt-get install qemu-system-arm failed"
fi
for tool in qemu-system-arm python3 cargo rustup timeout; do
    command -v "$tool" >/dev/null || die "missing tool: $tool"
done
rustup target add "$TARGET" >/dev/null 2>&1 || die "rustup target add $TARGET failed"
[ -e "$ROOT/third_party/mujoco/lib/libmujoco.so" ] || {
    step "MuJoCo (scripts/setup-mujoco.sh)"
    bash "$ROOT/scripts/setup-mujoco.sh" || die "scripts/setup-mujoco.sh failed"
}

# --- builds --------------------------------------------------------------------------------------
. "$ROOT/scripts/lib/target-dir.sh"
FW_TARGET=$(cargo_target_dir "$FW") || die "cargo metadata failed in $FW"
TARGET_DIR=$(cargo_target_dir "$ROOT") || die "cargo metadata failed in $ROOT"
W="$FW_TARGET/firmware-sil"
rm -rf "$W"
mkdir -p "$W"

step "build: the firmware node (release, QEMU: SLCAN on USART1), hil-sim (MuJoCo plant), policy tool"
(cd "$FW" && cargo build --release --locked --quiet -p dex-firmware-node) || die "firmware node build failed"
ELF="$FW_TARGET/$TARGET/release/dex-node"
# --all-features: the feature set scripts/test.sh's cargo test builds, so the suite reuses it.
(cd "$ROOT" && cargo build --locked --quiet -p dex-hil-sim -p dex-policy-tool --all-features) ||
    die "hil-sim build failed"
# Copies: the Python harness, which scripts/test.sh runs beside this script, rebuilds
# target/debug/hil-sim with other features.
for bin in hil-sim policy; do
    cp "$TARGET_DIR/debug/$bin" "$W/$bin" || die "no $bin binary in $TARGET_DIR/debug"
done
HS="$W/hil-sim"
POLICY_TOOL="$W/policy"

POLICY="$W/grasp_128_int8.dxpl"
"$POLICY_TOOL" quantise "$ROOT/policies/grasp-128.dxpl" "$POLICY" >/dev/null ||
    die "policy quantise failed"
CUT_POLICY="$ROOT/runtime/tests/golden/jaco_64.dxpl"
echo "   policy $(stat -c %s "$POLICY") B (Grasp 58-128-128-9, int8), cut transfer of $(stat -c %s "$CUT_POLICY") B"

# --- processes -----------------------------------------------------------------------------------
pids=()
cleanup() {
    local p
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
    pids=()
}
trap cleanup EXIT

# start_bus NAME [ARGS]: a lockstep bus with a candump log; sets BUS.
start_bus() {
    local name=$1
    shift
    "$HS" bus --port 0 --lockstep --log "$W/$name.candump" "$@" >"$W/$name.bus.out" 2>"$W/$name.bus.err" &
    pids+=($!)
    for _ in $(seq 100); do
        # The backgrounded bus may not have created its output file yet: not an error (under
        # set -e a failing sed here would end the script without a word).
        BUS=$(sed -n 's/^hil-sim bus listening on //p' "$W/$name.bus.out" 2>/dev/null || true)
        [ -n "$BUS" ] && return 0
        sleep 0.05
    done
    die "$name: the bus did not start: $(cat "$W/$name.bus.err")"
}

free_port() {
    python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# start_qemu NAME: the firmware, its USART1 a TCP server on a free port; sets SERIAL.
start_qemu() {
    local port
    port=$(free_port)
    SERIAL="127.0.0.1:$port"
    timeout 600 qemu-system-arm -machine netduinoplus2 -display none \
        -semihosting-config enable=on,target=native \
        -serial "tcp:$SERIAL,server=on,wait=on" -kernel "$ELF" </dev/null >"$W/$1.qemu.log" 2>&1 &
    pids+=($!)
    for _ in $(seq 100); do
        grep -q "waiting for connection" "$W/$1.qemu.log" 2>/dev/null && return 0
        sleep 0.05
    done
    die "$1: QEMU did not open its serial socket: $(cat "$W/$1.qemu.log")"
}

# start_bridge NAME: the SLCAN bridge between $BUS and QEMU's $SERIAL, stamping frames with bus
# time. Returns once the firmware has answered the bridge's start-up version request: frames put
# on the bus before then could reach a USART the firmware has not enabled yet, which drops them
# (docs/firmware.md, "Start-up of the serial link").
start_bridge() {
    local pid
    "$HS" slcan-bridge --connect "$BUS" --serial "$SERIAL" --stamp >"$W/$1.bridge.out" 2>"$W/$1.bridge.err" &
    pid=$!
    pids+=("$pid")
    for _ in $(seq 300); do
        grep -q "^hil-sim slcan-bridge ready" "$W/$1.bridge.out" 2>/dev/null && {
            sed 's/^hil-sim slcan-bridge /   bridge /' "$W/$1.bridge.out"
            return 0
        }
        kill -0 "$pid" 2>/dev/null || die "$1: the SLCAN bridge stopped: $(cat "$W/$1.bridge.err")"
        sleep 0.05
    done
    die "$1: the SLCAN bridge was not ready within 15 s: $(cat "$W/$1.bridge.err")"
}

# episodes NAME: the plant's episodes and the watchdog check on $BUS.
episodes() {
    timeout 240 "$HS" plant --connect "$BUS" --plant mujoco --task "$TASK" --episodes "$EPISODES" --seed 0 \
        --actions "$W/$1.actions" >"$W/$1.plant" 2>"$W/$1.plant.err" ||
        die "$1: the plant failed: $(tail -3 "$W/$1.plant.err")"
    sed 's/^/   /' "$W/$1.plant"
    timeout 60 python3 "$ROOT/scripts/firmware_sil.py" watchdog "$BUS" "$W/$1.candump" "$W/$1.watchdog" ||
        die "$1: watchdog check failed"
}

# --- 1. host controller node: the reference --------------------------------------------------------
step "host controller node: flash, $EPISODES lockstep $TASK episodes, watchdog"
start_bus host --controller
timeout 120 "$HS" flash --connect "$BUS" "$POLICY" | sed 's/^/   /' || die "host: flash failed"
episodes host
cleanup

# --- 2. the firmware in QEMU -------------------------------------------------------------------------
step "firmware node in QEMU over SLCAN: flash, cut flash, $EPISODES lockstep $TASK episodes, watchdog"
start_bus fw
start_qemu fw
start_bridge fw
t0=$(date +%s.%N)
timeout 120 "$HS" flash --connect "$BUS" "$POLICY" | sed 's/^/   /' || die "firmware: flash failed"
echo "   flash over SLCAN took $(python3 -c "import time; print(f'{time.time() - $t0:.1f}')") s"
if timeout 2 "$HS" flash --connect "$BUS" "$CUT_POLICY" >"$W/fw.cut.out" 2>&1; then
    die "firmware: the second flash was meant to be cut but completed"
fi
echo "   second flash cut on the wire after 2 s"
episodes fw
cleanup
grep -E '^(BOOT|BUSTIME|COMMIT|FAULT)' "$W/fw.qemu.log" | sed 's/^/   fw: /'
grep -q '^FAULT' "$W/fw.qemu.log" && die "firmware reported a fault"

# --- 3. compare ------------------------------------------------------------------------------------
step "compare firmware with host"
want_crc=$(python3 -c 'import sys, zlib; print("0x%08x" % zlib.crc32(open(sys.argv[1], "rb").read()))' "$POLICY")
commits=$(grep -c '^COMMIT' "$W/fw.qemu.log" || true)
[ "$commits" = 1 ] || die "firmware committed $commits policies, want 1 (the cut transfer must not commit)"
grep -q "^COMMIT active=Some([01]) crc=$want_crc" "$W/fw.qemu.log" ||
    die "firmware's committed policy is not the flashed one ($want_crc)"
echo "   one policy committed ($want_crc); the cut transfer left it active"
# The controller's SDO server aborts the stale transfer once bus time passes its timeout: abort
# 0x0504_0000 (SDO protocol timed out) for 0x1F50:1 on 0x590.
grep -q ' 590#80501F0100000405$' "$W/fw.candump" ||
    die "no SDO timeout abort (590#80501F0100000405) for the cut transfer in $W/fw.candump"
echo "   the cut transfer aborted by the firmware's SDO server at $(grep -m1 ' 590#80501F0100000405$' "$W/fw.candump" | cut -d' ' -f1 | tr -d '()') s bus time (0x05040000, timeout)"
cmp -s "$W/host.actions" "$W/fw.actions" ||
    die "actions differ: $(diff "$W/host.actions" "$W/fw.actions" | head -3)"
echo "   all $(wc -l <"$W/fw.actions") applied actions identical to the host node's"
diff <(grep '^episode\|^success' "$W/host.plant" | sed 's/ mode .*//') \
    <(grep '^episode\|^success' "$W/fw.plant" | sed 's/ mode .*//') >/dev/null ||
    die "episode results differ"
echo "   episode returns and success identical"
cmp -s "$W/host.watchdog" "$W/fw.watchdog" ||
    die "watchdog frames differ: $(diff "$W/host.watchdog" "$W/fw.watchdog" | head -3)"
echo "   watchdog: the same $(wc -l <"$W/fw.watchdog") frames, emergency 0x8250 included"

# --- 3b. trainer eval: the same starts through the runtime evaluator, no bus ------------------------
if [ "${FIRMWARE_SIL_TRAINER:-0}" = 1 ]; then
    step "trainer eval --actions for the same starts"
    # Built as tests/test_sil_stack_policy.py builds it (with dexstack selected, cargo reuses the
    # libraries of scripts/setup-python.sh's build).
    (cd "$ROOT" && cargo build --locked --quiet -p dex-trainer --bin trainer -p dexstack) ||
        die "trainer build failed"
    cp "$TARGET_DIR/debug/trainer" "$W/trainer" || die "no trainer binary in $TARGET_DIR/debug"
    timeout 300 "$W/trainer" eval "$POLICY" --episodes "$EPISODES" --seed 0 --envelope \
        --actions "$W/eval.actions" >"$W/eval.out" 2>"$W/eval.err" || die "trainer eval failed: $(tail -3 "$W/eval.err")"
    cmp -s "$W/eval.actions" "$W/fw.actions" ||
        die "actions differ from trainer eval's: $(diff "$W/eval.actions" "$W/fw.actions" | head -3)"
    diff <(grep '^episode' "$W/eval.out" | grep -o 'success [a-z]*') <(grep '^episode' "$W/fw.plant" | grep -o 'success [a-z]*') >/dev/null ||
        die "success differs from trainer eval's"
    echo "   all $(wc -l <"$W/eval.actions") actions and every episode's success identical to trainer eval's"
else
    echo "   (trainer eval comparison skipped: FIRMWARE_SIL_TRAINER=1 builds the trainer and adds it; scripts/test.sh sets it)"
fi

# --- 4. bad input on the serial line ------------------------------------------------------------------
step "bad input on the serial line"
start_qemu bad
timeout 60 python3 "$ROOT/scripts/firmware_sil.py" bad-input "$SERIAL" "$W/bad.qemu.log" ||
    die "bad input check failed"
cleanup

echo "firmware-sil: OK ($(($(date +%s) - start)) s)"
