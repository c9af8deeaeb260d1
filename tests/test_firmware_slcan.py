"""python-can's `slcan` interface talking straight to the firmware node (firmware/node, the QEMU
build: SLCAN on USART1, QEMU's serial line a TCP socket that pyserial opens as `socket://`).
No bus in between: the SLCAN protocol of the firmware is the one python-can speaks."""
import json
import shutil
import socket
import subprocess
import time
from pathlib import Path

import can
import pytest

ROOT = Path(__file__).resolve().parents[1]

NODE = 0x10
HEARTBEAT = 0x700 + NODE
EMCY = 0x80 + NODE


def firmware_node():
    """Builds the node's QEMU image (release) and returns its path."""
    fw = ROOT / "firmware"
    subprocess.run(["cargo", "build", "-q", "--release", "--locked", "-p", "dex-firmware-node"],
                   cwd=fw, check=True)
    meta = subprocess.run(["cargo", "metadata", "--format-version", "1", "--no-deps"], cwd=fw,
                          check=True, capture_output=True, text=True).stdout
    return f'{json.loads(meta)["target_directory"]}/thumbv7em-none-eabihf/release/dex-node'


@pytest.fixture
def qemu_node(tmp_path):
    if shutil.which("qemu-system-arm") is None:
        pytest.skip("qemu-system-arm missing (scripts/firmware-check.sh installs it; "
                    "scripts/firmware-sil.sh fails without it)")
    elf = firmware_node()
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    log = open(tmp_path / "qemu.log", "w")
    proc = subprocess.Popen(
        ["timeout", "120", "qemu-system-arm", "-machine", "netduinoplus2", "-display", "none",
         "-semihosting-config", "enable=on,target=native",
         "-serial", f"tcp:127.0.0.1:{port},server=on,wait=on", "-kernel", elf],
        stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
    time.sleep(0.5)
    try:
        yield port, tmp_path / "qemu.log"
    finally:
        proc.terminate()
        proc.wait()
        log.close()


def collect(bus, seconds):
    out, end = [], time.time() + seconds
    while time.time() < end:
        m = bus.recv(0.05)
        if m is not None:
            out.append(m)
    return out


def test_python_can_slcan_talks_to_the_firmware(qemu_node):
    port, log = qemu_node
    with can.Bus(interface="slcan", channel=f"socket://127.0.0.1:{port}", bitrate=500_000) as bus:
        got = collect(bus, 1.5)
        beats = [m for m in got if m.arbitration_id == HEARTBEAT]
        assert beats and beats[-1].data == bytes([0x7F]), got[:5]  # pre-operational
        assert bus.get_version(1.0) == (1, 1)
        assert bus.get_serial_number(1.0) == "DEX1"
        # NMT start: refused without a policy, with emergency 0xFF05 (NoPolicy).
        bus.send(can.Message(arbitration_id=0x000, data=[0x01, NODE], is_extended_id=False))
        got = collect(bus, 1.5)
        emcy = [m for m in got if m.arbitration_id == EMCY]
        assert any(m.data[:2] == bytes([0x05, 0xFF]) for m in emcy), emcy
        assert any(m.arbitration_id == HEARTBEAT for m in got)
    text = log.read_text()
    assert "BOOT dex-node" in text and "FAULT" not in text, text
