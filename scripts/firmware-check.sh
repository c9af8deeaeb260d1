#!/usr/bin/env bash
# Firmware check: builds firmware/ for thumbv7em-none-eabihf, runs it under QEMU and proves that the
# Cortex-M4F computes exactly the host's actions; checks footprint, fault paths and the instruction
# budget. Exits non-zero, loudly, on any mismatch, fault or missing tool. See docs/firmware.md.
#
#   scripts/firmware-check.sh            # everything (about 1 min warm, 3 min cold)
#   FIRMWARE_EXTRA_POLICY=path.dxpl scripts/firmware-check.sh   # also a trained policy, bit for bit, and its instructions per step
#   FIRMWARE_BLESS=1 scripts/firmware-check.sh   # rewrite firmware/budget.txt from this run
#   FIRMWARE_QUICK=1 scripts/firmware-check.sh   # case 1's f32 golden only (scripts/test.sh runs it
#                                                # with another CARGO_TARGET_DIR: the build paths)
#   FIRMWARE_SLOTS_ONLY=1 scripts/firmware-check.sh  # case 1's f32 golden, then case 8 (A/B slots);
#                                                # with FIRMWARE_BLESS=1 it re-blesses the slots_* budgets only
#
# Build output goes wherever cargo puts it for the firmware workspace (`cargo metadata`: honours
# CARGO_TARGET_DIR and build.target-dir; default firmware/target); scratch files in its
# firmware-check/ folder.
#
# Cases:
#   1. golden 44-64-64-9 policy on mps2-an386: every action bit equals runtime/tests/golden/actions_64.f32,
#      and the evaluator and controller lines equal the host twin's (fw-host reference).
#   2. default-size 44-256-256-9 policy on mps2-an386: equal to the host twin; instructions per step,
#      code flash (without the embedded policy file and trace), static RAM and peak stack within 10%
#      of firmware/budget.txt; footprint by section.
#   3. the same policy on netduinoplus2 (STM32F405 map: 1 MB flash, 128 KB RAM): equal to the host twin.
#   4. a corrupted policy file: the fault state, reported, exit status non-zero, no hang.
#   5. an undefined instruction at boot: the HardFault handler reports and exits non-zero.
#   6. the default-size policy quantised to int8 (format version 2, `fw-host make-policy ... int8`) run by
#      the runtime's int8 evaluator: equal to the host twin, action error against the f32 run at most 1%
#      of each joint's range, instructions, code flash and peak stack within budget. (Step 1 also checks
#      the int8 golden.)
#   7. a trained policy (trainer/tests/fixtures/reach_int8_seed0.dxpl, Reach, trained for int8) and its
#      int8 twin (`policy quantise`): both equal to the host twin, int8 within 1% of the f32 actions;
#      then policies/grasp-128-int8.dxpl (58 inputs: the task features on the target), equal to the
#      host twin, its controller step within budget.
#   8. A/B policy slots (feature `slots`): the golden policy in one of two static slots, the recorded
#      flash of the int8 golden policy (runtime/tests/golden/flash_int8.frames, the frames of a real
#      hil-sim flash) fed to the controller: every response as recorded, the inactive slot written and
#      activated; the trace before and after the swap bit-identical to actions_64.f32 and
#      actions_64_int8.f32 (evaluator over the slot) and to the host twin (controller); a transfer cut
#      in the middle (then a reset) and one with a corrupt segment leave the old slot active;
#      instructions, RAM and stack of the slot image within budget.
#   9. the CAN node (firmware/node, docs/firmware.md "The firmware as a CAN node"): host tests and
#      clippy of its target-independent crates (firmware/slcan, firmware/slot-mirror); the QEMU build
#      (SLCAN on USART1, RAM-backed NorFlash) and the board build (bxCAN1, the STM32F405's flash
#      sectors as NorFlash) compile, clippy-clean, their flash and static RAM within budget
#      (node_*); scripts/firmware-sil.sh runs the QEMU build in the closed loop.
set -euo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
FW="$ROOT/firmware"
TARGET=thumbv7em-none-eabihf
QEMU_TIMEOUT=${QEMU_TIMEOUT:-60}
TOLERANCE_PCT=10

die() {
    echo "firmware-check: FAIL: $*" >&2
    exit 1
}
step() { echo "== firmware-check: $*"; }

# --- tools ---------------------------------------------------------------------------------------
need_apt=()
command -v qemu-system-arm >/dev/null || need_apt+=(qemu-system-arm)
command -v arm-none-eabi-size >/dev/null || need_apt+=(binutils-arm-none-eabi)
if ((${#need_apt[@]})); then
    step "installing ${need_apt[*]}"
    SUDO=""
    if [ "$(id -u)" != 0 ]; then
        command -v sudo >/dev/null || die "need ${need_apt[*]} and neither root nor sudo to install them"
        SUDO=sudo
    fi
    $SUDO apt-get install -y --no-install-recommends "${need_apt[@]}" >/dev/null ||
        { $SUDO apt-get update >/dev/null && $SUDO apt-get install -y --no-install-recommends "${need_apt[@]}" >/dev/null; } ||
        die "apt-get install ${need_apt[*]} failed"
fi
for tool in qemu-system-arm arm-none-eabi-size python3 cargo rustup timeout; do
    command -v "$tool" >/dev/null || die "missing tool: $tool"
done
# RUSTUP_AUTO_INSTALL=0 on these machines: rust-toolchain.toml's `targets` alone does not install
# the target (scripts/test.sh adds it the same way).
rustup target add "$TARGET" >/dev/null 2>&1 || die "rustup target add $TARGET failed"
HOST=$(rustc -vV | sed -n 's/^host: //p')
[ -n "$HOST" ] || die "cannot tell the host target"
# Ask cargo where it builds this workspace instead of assuming firmware/target.
. "$ROOT/scripts/lib/target-dir.sh"
FW_TARGET=$(cargo_target_dir "$FW") || die "cargo metadata failed in $FW"
[ -n "$FW_TARGET" ] || die "cargo metadata gave no target directory"
WORK="$FW_TARGET/firmware-check"
mkdir -p "$WORK"
echo "== firmware-check: cargo target directory $FW_TARGET"

# --- helpers -------------------------------------------------------------------------------------
# build_fw OUT_ELF POLICY BOARD [cargo args...]: builds the firmware with POLICY embedded.
build_fw() {
    local out=$1 policy=$2 board=$3
    shift 3
    (cd "$FW" && DEX_POLICY="$policy" DEX_TRACE="" DEX_BOARD="$board" \
        cargo build --release --quiet --target "$TARGET" -p dex-firmware "$@") ||
        die "firmware build failed (policy $policy, board $board)"
    cp "$FW_TARGET/$TARGET/release/dex-firmware" "$out"
}

# host_ref OUT POLICY [cargo args...]: the host twin's report for POLICY.
host_ref() {
    local out=$1 policy=$2
    shift 2
    (cd "$FW" && DEX_POLICY="$policy" DEX_TRACE="" \
        cargo build --release --quiet --target "$HOST" -p dex-firmware-host "$@") ||
        die "host twin build failed (policy $policy)"
    "$FW_TARGET/$HOST/release/fw-host" reference >"$out" || die "host twin failed: $(tail -1 "$out")"
}

# run_qemu ELF BOARD LOG: runs under timeout; echoes QEMU's exit status.
run_qemu() {
    local elf=$1 board=$2 log=$3 rc=0 cpu=()
    [ "$board" = mps2-an386 ] && cpu=(-cpu cortex-m4)
    timeout "$QEMU_TIMEOUT" qemu-system-arm -machine "$board" "${cpu[@]}" -display none \
        -semihosting-config enable=on,target=native -icount shift=6 -kernel "$elf" \
        </dev/null >"$log" 2>&1 || rc=$?
    echo "$rc"
}

# expect_ok RC LOG WHAT
expect_ok() {
    [ "$1" = 0 ] || { tail -5 "$2" >&2; die "$3: QEMU exit status $1 (124 = timeout, a hang)"; }
    grep -q '^END ok' "$2" || die "$3: no END line"
}

# same_as_host QEMU_LOG HOST_LOG WHAT: layer, evaluator and controller lines identical.
same_as_host() {
    local n
    n=$(grep -c '^[ACQ] ' "$1" || true)
    [ "$n" -gt 0 ] || die "$3: no action lines from QEMU"
    diff <(grep -E '^(L|J|A|C|E|P|Q|R|V|F) ' "$2") <(grep -E '^(L|J|A|C|E|P|Q|R|V|F) ' "$1") >"$WORK/diff.txt" ||
        { head -20 "$WORK/diff.txt" >&2; die "$3: QEMU output differs from the host twin"; }
    echo "   $3: $n action lines bit-identical to the host twin"
}

# run_policy NAME POLICY WHAT: POLICY on mps2-an386 into $WORK/NAME.log, ends well, and equals the host
# twin's report ($WORK/NAME.host).
run_policy() {
    local name=$1 policy=$2 what=$3 rc
    build_fw "$WORK/$name.elf" "$policy" mps2-an386
    rc=$(run_qemu "$WORK/$name.elf" mps2-an386 "$WORK/$name.log")
    expect_ok "$rc" "$WORK/$name.log" "$what"
    host_ref "$WORK/$name.host" "$policy"
    same_as_host "$WORK/$name.log" "$WORK/$name.host" "$what"
}

# check_golden LOG ACTIONS.f32 WHAT [TAG]: every TAG line (default A) equals the golden actions bit
# for bit.
check_golden() {
    python3 - "$1" "$2" "$3" "${4:-A}" <<'EOF' || die "$3: actions differ from $(basename "$2")"
import struct, sys
log, golden, what, tag = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
def canon(bits):  # NaN payloads differ between x86 and Arm: compare all NaNs as one
    return 0x7FC00000 if (bits & 0x7F800000) == 0x7F800000 and bits & 0x007FFFFF else bits
raw = open(golden, "rb").read()
want = [canon(b) for b in struct.unpack("<%dI" % (len(raw) // 4), raw)]
rows = [l.split() for l in open(log) if l.startswith(tag + " ")]
if len(rows) * 9 != len(want):
    sys.exit(f"{len(rows)} steps from QEMU, {len(want) // 9} in the golden file")
bad = 0
for r in rows:
    s = int(r[1]); got = [canon(int(x, 16)) for x in r[2:]]
    if got != want[9 * s: 9 * s + 9]:
        bad += 1
        print(f"step {s}: got {' '.join('%08x' % g for g in got)}", file=sys.stderr)
        print(f"step {s}: want {' '.join('%08x' % w for w in want[9 * s: 9 * s + 9])}", file=sys.stderr)
if bad:
    sys.exit(f"{bad} of {len(rows)} steps differ")
print(f"   {what}: all {len(want)} action values bit-identical to {golden.split('/')[-1]}")
EOF
}

# check_error F32_LOG INT8_LOG WHAT: the int8 run's actions within 1% of each joint's range of the f32
# run's, step by step.
check_error() {
    python3 - "$1" "$2" "$3" <<'EOF' || die "$3: action error above 1% of a joint's range"
import struct, sys
def rows(path, tag):
    return {int(l.split()[1]): [struct.unpack("<f", struct.pack("<I", int(x, 16)))[0] for x in l.split()[2:]]
            for l in open(path) if l.startswith(tag + " ")}
ref, got, joints = rows(sys.argv[1], "A"), rows(sys.argv[2], "A"), rows(sys.argv[1], "J")
worst = [0.0] * len(joints)
for step, a in ref.items():
    for k, (x, y) in enumerate(zip(a, got[step])):
        lo, hi = joints[k]
        worst[k] = max(worst[k], abs(x - y) / (hi - lo))
print("   %s max action error vs f32, %% of joint range: " % sys.argv[3] + " ".join("%.3f" % (100 * w) for w in worst)
      + " (worst %.3f%%, %d steps)" % (100 * max(worst), len(ref)))
sys.exit(1 if max(worst) > 0.01 else 0)
EOF
}

BUDGET="$FW/budget.txt"
trace_bytes=$(stat -c %s "$ROOT/runtime/tests/golden/obs_trace.f32")
# footprint ELF POLICY_BYTES PREFIX: prints the sections; sets code_flash (flash without the embedded
# policy file and trace: what the firmware itself costs) and static_ram.
footprint() {
    local report
    report=$(arm-none-eabi-size -A "$1" | awk -v pol="$2" -v tr="$trace_bytes" -v pre="$3" '
        $1 ~ /^\.(vector_table|text|rodata|data|bss|uninit)$/ { s[$1] = $2 }
        END {
            flash = s[".vector_table"] + s[".text"] + s[".rodata"] + s[".data"]
            printf "   %sfootprint: flash %d B = .vector_table %d + .text %d + .rodata %d (policy file %d, trace %d, other %d) + .data %d\n",
                pre, flash, s[".vector_table"], s[".text"], s[".rodata"], pol, tr, s[".rodata"] - pol - tr, s[".data"]
            printf "   %sfootprint: static RAM .data %d + .bss %d + .uninit %d B (stack: see S lines)\n",
                pre, s[".data"], s[".bss"], s[".uninit"]
            printf "FIGURES %d %d\n", flash - pol - tr, s[".data"] + s[".bss"] + s[".uninit"]
        }') || die "arm-none-eabi-size failed on $1"
    grep -v '^FIGURES ' <<<"$report"
    read -r _ code_flash static_ram < <(grep '^FIGURES ' <<<"$report")
    [ -n "${code_flash:-}" ] && [ -n "${static_ram:-}" ] || die "no footprint figures for $1"
}
# peak_stack LOG: the S peak line's stack_used.
peak_stack() {
    local used
    used=$(sed -n 's/^S peak stack_used=\([0-9]*\).*/\1/p' "$1")
    [ -n "$used" ] || die "no peak stack figure in $1"
    echo "$used"
}
# worst KIND LOG: the worst (max) instructions of LOG's `I KIND` line; empty when it has none.
worst() {
    sed -n "s/^I $1 .*max=\([0-9]*\).*/\1/p" "$2"
}
# check_budget NAME VALUE UNIT: VALUE at most the budget + TOLERANCE_PCT.
check_budget() {
    local name=$1 got=$2 unit=$3 budget
    budget=$(awk -v k="$name" '$1 == k { print $2 }' "$BUDGET")
    [ -n "$budget" ] || die "budget file has no $name"
    [[ "$budget" =~ ^[0-9]+$ ]] || die "budget $name is '$budget', not a number (FIRMWARE_BLESS=1 writes one)"
    local limit=$((budget + budget * TOLERANCE_PCT / 100))
    [ "$got" -le "$limit" ] ||
        die "$name: $got $unit, budget $budget (+${TOLERANCE_PCT}% = $limit): a regression"
    echo "   $name: $got $unit (budget $budget, limit $limit) ok"
}
# --- 8. A/B policy slots (a function: FIRMWARE_SLOTS_ONLY=1 runs it alone, after case 1) --------
case_slots() {
    step "8/9 A/B policy slots: the recorded flash of the int8 golden into the inactive slot, cut and corrupt transfers"
    FLASH_REC="$GOLDEN/flash_int8.frames"
    build_fw "$WORK/slots.elf" "$GOLDEN/jaco_64.dxpl" mps2-an386 --features slots
    rc=$(run_qemu "$WORK/slots.elf" mps2-an386 "$WORK/slots.log")
    expect_ok "$rc" "$WORK/slots.log" slots
    grep '^F ' "$WORK/slots.log" | sed 's/^/   /'
    check_golden "$WORK/slots.log" "$GOLDEN/actions_64.f32" "slots before the swap (evaluator over the slot)" P
    check_golden "$WORK/slots.log" "$GOLDEN/actions_64_int8.f32" "slots after the swap (evaluator over the slot)" Q
    diff <(sed -n 's/^C \([^|]*\) |.*/\1/p' "$WORK/slots.log" | sed 's/ *$//') \
        <(sed -n 's/^R //p' "$WORK/slots.log" | sed 's/ *$//') >/dev/null ||
        die "slots: the controller over the slot differs from the controller over the embedded file"
    echo "   slots: controller over the slot bit-identical to the controller over the embedded file"
    host_ref "$WORK/slots.host" "$GOLDEN/jaco_64.dxpl" --features slots
    same_as_host "$WORK/slots.log" "$WORK/slots.host" slots
    grep -E '^(I|S) ' "$WORK/slots.log" | grep -E 'slot|flash|peak' | sed 's/^/   /'
    slots_ctrl=$(worst slot_controller "$WORK/slots.log")
    slots_req=$(worst flash_request "$WORK/slots.log")
    [ -n "$slots_ctrl" ] && [ -n "$slots_req" ] || die "slots: no instruction counts"
    footprint "$WORK/slots.elf" "$(stat -c %s "$GOLDEN/jaco_64.dxpl")" "slots "
    # The slot image embeds the recording too: count it with the data, not the code.
    code_flash=$((code_flash - $(stat -c %s "$FLASH_REC")))
    echo "   slots: code flash without the policy, trace and recording: $code_flash B"
    slots_stack=$(peak_stack "$WORK/slots.log")
    if [ "${FIRMWARE_BLESS:-0}" = 1 ]; then
        sed -i "s/^slots_controller_step .*/slots_controller_step $slots_ctrl/; s/^slots_flash_request .*/slots_flash_request $slots_req/;
            s/^slots_flash_code_bytes .*/slots_flash_code_bytes $code_flash/; s/^slots_static_ram_bytes .*/slots_static_ram_bytes $static_ram/;
            s/^slots_stack_bytes .*/slots_stack_bytes $slots_stack/" "$BUDGET"
    fi
    check_budget slots_controller_step "$slots_ctrl" "instructions per step"
    check_budget slots_flash_request "$slots_req" "instructions per flash request (worst: verification)"
    check_budget slots_flash_code_bytes "$code_flash" "bytes of code flash"
    check_budget slots_static_ram_bytes "$static_ram" "bytes of static RAM (two 32 KiB slots)"
    check_budget slots_stack_bytes "$slots_stack" "bytes of peak stack"
}

# --- 9. the CAN node: QEMU and board builds, footprint (a function: FIRMWARE_NODE_ONLY=1 runs it alone)
case_node() {
    step "9/9 CAN node (firmware/node): QEMU build (SLCAN) and board build (bxCAN, flash), footprint"
    local variant elf flash ram
    # The node's target-independent parts, on the host: the SLCAN codec and the slot mirror.
    (cd "$FW" && cargo test --quiet --locked --target "$HOST" -p dex-slcan -p dex-slot-mirror 2>&1 |
        grep -E '^test result' | sed 's/^/   /') || die "dex-slcan / dex-slot-mirror tests failed"
    (cd "$FW" && cargo clippy --quiet --locked --target "$HOST" -p dex-slcan -p dex-slot-mirror --all-targets -- -D warnings) ||
        die "dex-slcan / dex-slot-mirror clippy failed"
    for variant in qemu board; do
        local feats=()
        [ "$variant" = board ] && feats=(--no-default-features --features board)
        (cd "$FW" && cargo build --release --quiet --locked -p dex-firmware-node "${feats[@]}") ||
            die "CAN node build failed ($variant)"
        (cd "$FW" && cargo clippy --release --quiet --locked -p dex-firmware-node "${feats[@]}" -- -D warnings) ||
            die "CAN node clippy failed ($variant)"
        elf="$WORK/node-$variant.elf"
        cp "$FW_TARGET/$TARGET/release/dex-node" "$elf"
        read -r flash ram < <(arm-none-eabi-size -A "$elf" | awk '
            $1 ~ /^\.(vector_table|text|rodata|data)$/ { f += $2 }
            $1 ~ /^\.(data|bss|uninit)$/ { r += $2 }
            END { print f, r }')
        [ -n "$flash" ] && [ -n "$ram" ] || die "no footprint for $elf"
        echo "   node $variant: flash $flash B, static RAM $ram B"
        if [ "${FIRMWARE_BLESS:-0}" = 1 ]; then
            sed -i "s/^node_${variant}_flash_bytes .*/node_${variant}_flash_bytes $flash/;
                s/^node_${variant}_static_ram_bytes .*/node_${variant}_static_ram_bytes $ram/" "$BUDGET"
        fi
        check_budget "node_${variant}_flash_bytes" "$flash" "bytes of flash"
        check_budget "node_${variant}_static_ram_bytes" "$ram" "bytes of static RAM"
    done
}
if [ "${FIRMWARE_NODE_ONLY:-0}" = 1 ]; then
    case_node
    echo "firmware-check: OK (CAN node only: case 9)"
    exit 0
fi

# --- 1. golden policy ----------------------------------------------------------------------------
GOLDEN="$ROOT/runtime/tests/golden"
step "1/9 golden 44-64-64-9 policy on mps2-an386"
build_fw "$WORK/golden.elf" "$GOLDEN/jaco_64.dxpl" mps2-an386
rc=$(run_qemu "$WORK/golden.elf" mps2-an386 "$WORK/golden.log")
expect_ok "$rc" "$WORK/golden.log" golden
check_golden "$WORK/golden.log" "$GOLDEN/actions_64.f32" golden
host_ref "$WORK/golden.host" "$GOLDEN/jaco_64.dxpl"
same_as_host "$WORK/golden.log" "$WORK/golden.host" golden
if [ "${FIRMWARE_QUICK:-0}" = 1 ]; then
    echo "firmware-check: OK (quick: the f32 golden of case 1 only)"
    exit 0
fi
if [ "${FIRMWARE_SLOTS_ONLY:-0}" = 1 ]; then
    case_slots
    echo "firmware-check: OK (slots only: case 1's f32 golden and case 8)"
    exit 0
fi
build_fw "$WORK/golden_int8.elf" "$GOLDEN/jaco_64_int8.dxpl" mps2-an386
rc=$(run_qemu "$WORK/golden_int8.elf" mps2-an386 "$WORK/golden_int8.log")
expect_ok "$rc" "$WORK/golden_int8.log" "golden int8"
check_golden "$WORK/golden_int8.log" "$GOLDEN/actions_64_int8.f32" "golden int8"
host_ref "$WORK/golden_int8.host" "$GOLDEN/jaco_64_int8.dxpl"
same_as_host "$WORK/golden_int8.log" "$WORK/golden_int8.host" "golden int8"

# --- 2. default-size policy, budget and footprint -------------------------------------------------
step "2/9 default-size 44-256-256-9 policy on mps2-an386: bit-exactness, instructions, footprint"
(cd "$FW" && cargo build --release --quiet --target "$HOST" -p dex-firmware-host) || die "host twin build failed"
"$FW_TARGET/$HOST/release/fw-host" make-policy 256,256 3 "$WORK/jaco_256.dxpl" 2>/dev/null ||
    die "make-policy failed"
run_policy p256 "$WORK/jaco_256.dxpl" "44-256-256-9"
grep -E '^(I|S) ' "$WORK/p256.log" | sed 's/^/   /'

mlp_max=$(worst mlp "$WORK/p256.log")
ctrl_max=$(worst controller "$WORK/p256.log")
env_max=$(worst envelope "$WORK/p256.log")
[ -n "$mlp_max" ] && [ -n "$ctrl_max" ] && [ -n "$env_max" ] || die "no instruction counts in the QEMU output"
policy_bytes=$(stat -c %s "$WORK/jaco_256.dxpl")
footprint "$WORK/p256.elf" "$policy_bytes" ""
stack_max=$(peak_stack "$WORK/p256.log")

if [ "${FIRMWARE_BLESS:-0}" = 1 ]; then
    {
        echo "# Budgets of scripts/firmware-check.sh, measured under QEMU -icount shift=6 on mps2-an386 with the"
        echo "# default-size 44-256-256-9 policy (fw-host make-policy 256,256 3) and its int8 twin (int8_*)."
        echo "# *_step: guest instructions per control step (worst step of the golden trace)."
        echo "# *flash_code_bytes: flash without the embedded policy file and trace (.vector_table + .text +"
        echo "# .rodata + .data, less those two); static_ram_bytes: .data + .bss + .uninit; *stack_bytes: peak"
        echo "# stack (paint and measure, worst phase)."
        echo "# scripts/firmware-check.sh fails when a measurement exceeds its budget by more than ${TOLERANCE_PCT}%."
        echo "# slots_*: the A/B slot image of case 8 (golden 44-64-64-9 policy, --features slots): one control"
        echo "# period over a slot, the worst flash request (the end's verification of the 9.5 kB int8 file), code"
        echo "# flash less policy, trace and flash recording, static RAM (two 32 KiB + 32 B slots), peak stack."
        echo "# grasp128_int8_controller_step: case 7's policies/grasp-128-int8.dxpl (58-128-128-9 int8, the task"
        echo "# features computed on the target), the step behind the 5 ms loop (docs/benchmarks.md)."
        echo "# node_*: the CAN node (firmware/node, case 9): flash (.vector_table + .text + .rodata + .data) and"
        echo "# static RAM (.data + .bss + .uninit) of its QEMU build (SLCAN, RAM-backed NorFlash) and board build."
        echo "# Re-bless only on purpose: FIRMWARE_BLESS=1 scripts/firmware-check.sh (the slots_* lines alone:"
        echo "# FIRMWARE_BLESS=1 FIRMWARE_SLOTS_ONLY=1 scripts/firmware-check.sh)"
        echo "mlp_step $mlp_max"
        echo "controller_step $ctrl_max"
        echo "envelope_step $env_max"
        echo "flash_code_bytes $code_flash"
        echo "static_ram_bytes $static_ram"
        echo "stack_bytes $stack_max"
        echo "int8_step BLESS_PENDING"
        echo "int8_controller_step BLESS_PENDING"
        echo "int8_flash_code_bytes BLESS_PENDING"
        echo "int8_stack_bytes BLESS_PENDING"
        echo "grasp128_int8_controller_step BLESS_PENDING"
        echo "slots_controller_step BLESS_PENDING"
        echo "slots_flash_request BLESS_PENDING"
        echo "slots_flash_code_bytes BLESS_PENDING"
        echo "slots_static_ram_bytes BLESS_PENDING"
        echo "slots_stack_bytes BLESS_PENDING"
        echo "node_qemu_flash_bytes BLESS_PENDING"
        echo "node_qemu_static_ram_bytes BLESS_PENDING"
        echo "node_board_flash_bytes BLESS_PENDING"
        echo "node_board_static_ram_bytes BLESS_PENDING"
    } >"$BUDGET"
    echo "   blessed $BUDGET"
fi
[ -f "$BUDGET" ] || die "no budget file $BUDGET (FIRMWARE_BLESS=1 writes one)"
check_budget mlp_step "$mlp_max" "instructions per step"
check_budget controller_step "$ctrl_max" "instructions per step"
check_budget envelope_step "$env_max" "instructions per step"
check_budget flash_code_bytes "$code_flash" "bytes of code flash"
check_budget static_ram_bytes "$static_ram" "bytes of static RAM"
check_budget stack_bytes "$stack_max" "bytes of peak stack"

# --- 3. second board ------------------------------------------------------------------------------
step "3/9 44-256-256-9 policy on netduinoplus2 (STM32F405 memory map)"
build_fw "$WORK/nd.elf" "$WORK/jaco_256.dxpl" netduinoplus2
rc=$(run_qemu "$WORK/nd.elf" netduinoplus2 "$WORK/nd.log")
expect_ok "$rc" "$WORK/nd.log" netduinoplus2
same_as_host "$WORK/nd.log" "$WORK/p256.host" netduinoplus2

if [ -n "${FIRMWARE_EXTRA_POLICY:-}" ]; then
    step "extra policy $FIRMWARE_EXTRA_POLICY on mps2-an386"
    extra=$(cd "$ROOT" && realpath "$FIRMWARE_EXTRA_POLICY")
    run_policy extra "$extra" "extra policy"
    # Its instructions per step (the worst step of the golden trace; a file that takes the task
    # features computes them in the `mlp` count, as the controller does).
    grep -E '^(I|S peak) ' "$WORK/extra.log" | sed 's/^/   /'
fi

# --- 4. corrupted policy: the fault state ---------------------------------------------------------
step "4/9 corrupted policy file: fault state, non-zero exit, no hang"
python3 - "$GOLDEN/jaco_64.dxpl" "$WORK/corrupt.dxpl" <<'EOF'
import sys
b = bytearray(open(sys.argv[1], "rb").read())
b[len(b) // 2] ^= 0x01  # one bit in the weights: the CRC must catch it
open(sys.argv[2], "wb").write(b)
EOF
build_fw "$WORK/corrupt.elf" "$WORK/corrupt.dxpl" mps2-an386
rc=$(run_qemu "$WORK/corrupt.elf" mps2-an386 "$WORK/corrupt.log")
[ "$rc" = 1 ] || die "corrupted policy: exit status $rc, want 1 (124 = hang)"
grep -q '^FAULT policy file rejected' "$WORK/corrupt.log" || die "corrupted policy: no FAULT report"
grep -q '^[AC] ' "$WORK/corrupt.log" && die "corrupted policy: actions were produced"
echo "   $(grep '^FAULT' "$WORK/corrupt.log") (exit $rc)"

# --- 5. HardFault -----------------------------------------------------------------------------------
step "5/9 HardFault handler exits non-zero"
build_fw "$WORK/hardfault.elf" "$GOLDEN/jaco_64.dxpl" mps2-an386 --features hardfault-test
rc=$(run_qemu "$WORK/hardfault.elf" mps2-an386 "$WORK/hardfault.log")
[ "$rc" = 1 ] || die "hardfault test: exit status $rc, want 1 (124 = hang)"
grep -q '^FAULT hardfault' "$WORK/hardfault.log" || die "hardfault test: no FAULT report"
echo "   $(grep '^FAULT' "$WORK/hardfault.log") (exit $rc)"

# --- 6. int8 policy file ---------------------------------------------------------------------------
step "6/9 int8 policy file (format v2, W8A16, per-output-channel scales) of the 44-256-256-9 policy"
"$FW_TARGET/$HOST/release/fw-host" make-policy 256,256 3 "$WORK/jaco_256_int8.dxpl" int8 2>/dev/null ||
    die "make-policy int8 failed"
run_policy int8 "$WORK/jaco_256_int8.dxpl" int8
grep -E '^(H|I|S peak) ' "$WORK/int8.log" | sed 's/^/   /'
check_error "$WORK/p256.log" "$WORK/int8.log" int8
int8_max=$(worst mlp "$WORK/int8.log")
int8_ctrl_max=$(worst controller "$WORK/int8.log")
[ -n "$int8_max" ] && [ -n "$int8_ctrl_max" ] || die "int8: no instruction count"
int8_bytes=$(stat -c %s "$WORK/jaco_256_int8.dxpl")
footprint "$WORK/int8.elf" "$int8_bytes" "int8 "
int8_stack_max=$(peak_stack "$WORK/int8.log")
if [ "${FIRMWARE_BLESS:-0}" = 1 ]; then
    sed -i "s/^int8_step .*/int8_step $int8_max/; s/^int8_controller_step .*/int8_controller_step $int8_ctrl_max/;
        s/^int8_flash_code_bytes .*/int8_flash_code_bytes $code_flash/; s/^int8_stack_bytes .*/int8_stack_bytes $int8_stack_max/" "$BUDGET"
fi
check_budget int8_step "$int8_max" "instructions per step"
check_budget int8_controller_step "$int8_ctrl_max" "instructions per step"
check_budget int8_flash_code_bytes "$code_flash" "bytes of code flash"
check_budget int8_stack_bytes "$int8_stack_max" "bytes of peak stack"

# --- 7. a trained policy and its int8 twin ---------------------------------------------------------
step "7/9 trained Reach policy (trained for int8) and its int8 twin on mps2-an386"
TRAINED="$ROOT/trainer/tests/fixtures/reach_int8_seed0.dxpl"
(cd "$ROOT" && cargo run --quiet --locked -p dex-policy-tool --bin policy -- \
    quantise "$TRAINED" "$WORK/trained_int8.dxpl" | sed 's/^/   /') || die "policy quantise failed"
run_policy trained "$TRAINED" trained
run_policy trained_int8 "$WORK/trained_int8.dxpl" trained_int8
for name in trained trained_int8; do
    grep -E '^(I|S peak) ' "$WORK/$name.log" | sed "s/^/   $name: /"
done
check_error "$WORK/trained.log" "$WORK/trained_int8.log" "trained int8"
# The Grasp file firmware-sil.sh flashes (58-128-128-9 int8, the task features computed on the
# target): its controller step is what the 5 ms loop at 500 kbit/s rests on (docs/benchmarks.md).
run_policy grasp128_int8 "$ROOT/policies/grasp-128-int8.dxpl" grasp-128-int8
grep -E '^(I|S peak) ' "$WORK/grasp128_int8.log" | sed "s/^/   grasp-128-int8: /"
g128_ctrl_max=$(worst controller "$WORK/grasp128_int8.log")
[ -n "$g128_ctrl_max" ] || die "grasp-128-int8: no instruction count"
if [ "${FIRMWARE_BLESS:-0}" = 1 ]; then
    sed -i "s/^grasp128_int8_controller_step .*/grasp128_int8_controller_step $g128_ctrl_max/" "$BUDGET"
fi
check_budget grasp128_int8_controller_step "$g128_ctrl_max" "instructions per step (task features included)"

case_slots
case_node

echo "firmware-check: OK"
