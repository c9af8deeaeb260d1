"""`dexflash` (dexstack/python/dexstack/flash.py, the `dexflash` entry point in .venv/bin) against a
`hil-sim bus` with the controller node: a good file flashed and run, --info, --dry-run (no program
data on the bus), --rollback, and the refusals (a corrupt file, a node nobody answers, a layout
mismatch, a file the node refuses, a transfer cut by bus-off): non-zero exit, one line on stderr,
the node's policy unchanged."""
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import pytest

from conftest import NODE, OPERATIONAL, PREOP, wait_heartbeat
from test_sil_flash import flash_status, program_id, runs_policy, sdo_node

BIN = Path(sys.executable).parent / "dexflash"
SDO_REQUEST = 0x600 + NODE
EXIT_FILE, EXIT_TIMEOUT, EXIT_ABORT, EXIT_CHECK = 3, 4, 5, 6


def dexflash(s, *args, node=NODE, timeout=60):
    """Runs the installed `dexflash` on bus `s` (socketcand, the bus's port); CompletedProcess."""
    cmd = [
        str(BIN), "--node", str(node), "-i", "socketcand", "-c", "vcan0",
        "-o", "host=127.0.0.1", "-o", f"port={s.port}", "-q", *map(str, args),
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


class Sniffer:
    """Every frame on the bus from now on, read by a thread on a connection of its own."""

    def __init__(self, s):
        self.bus = s.bus()
        self.frames = []
        self.running = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while self.running:
            m = self.bus.recv(timeout=0.05)
            if m is not None:
                self.frames.append(m)

    def sdo_requests(self):
        """The data of every SDO request to the node seen so far (stops the sniffer)."""
        time.sleep(0.1)
        self.running = False
        self.thread.join(timeout=2)
        return [bytes(m.data) for m in self.frames if m.arbitration_id == SDO_REQUEST]


def downloads(requests):
    """The download requests (initiate download, block download) among SDO requests."""
    return [d for d in requests if d[0] >> 5 in (1, 6)]


def one_line_error(r, *words):
    assert r.returncode != 0, r.stdout
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("dexflash: ")
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def test_the_entry_point_is_installed():
    assert BIN.exists(), "no .venv/bin/dexflash: run scripts/setup-python.sh"
    r = subprocess.run([str(BIN), "--help"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 0 and "--rollback" in r.stdout and "--dry-run" in r.stdout


def test_flash_a_good_file_and_the_node_runs_it(sim, policies):
    s = sim("good")
    bus = s.bus()
    wait_heartbeat(bus, PREOP, 2.0)
    new = policies["other"].read_bytes()
    r = dexflash(s, policies["other"])
    assert r.returncode == 0, r.stderr
    assert f"0x{zlib.crc32(new):08X}" in r.stdout.splitlines()[-1]  # the new policy printed
    assert "block transfer" in r.stdout
    node = sdo_node(s)
    assert program_id(node) == zlib.crc32(new)
    assert node.sdo.upload(0x2000, 3) == zlib.crc32(new).to_bytes(4, "little")
    assert runs_policy(bus)


def test_flash_with_start_leaves_the_node_operational(sim, policies):
    s = sim("good")
    bus = s.bus()
    wait_heartbeat(bus, PREOP, 2.0)
    r = dexflash(s, policies["other"], "--start")
    assert r.returncode == 0, r.stderr
    wait_heartbeat(bus, OPERATIONAL, 1.5)


def test_info(sim, policies):
    s = sim("good")
    wait_heartbeat(s.bus(), PREOP, 2.0)
    sniffer = Sniffer(s)
    r = dexflash(s, "--info")
    assert r.returncode == 0, r.stderr
    crc = zlib.crc32(policies["good"].read_bytes())
    assert f"program id (0x1F56:1): 0x{crc:08X}" in r.stdout
    assert "product 0x44584A43" in r.stdout
    assert "PRE-OPERATIONAL" in r.stdout
    layout = int.from_bytes(policies["good"].read_bytes()[8:12], "little")
    assert f"layout hash 0x{layout:08X}" in r.stdout
    assert "nothing staged" in r.stdout
    requests = sniffer.sdo_requests()
    assert requests and not downloads(requests)  # read, nothing written


def test_dry_run_sends_no_program_data(sim, policies):
    s = sim("good")
    wait_heartbeat(s.bus(), PREOP, 2.0)
    sniffer = Sniffer(s)
    r = dexflash(s, policies["other"], "--dry-run")
    assert r.returncode == 0, r.stderr
    assert "dry run: nothing sent" in r.stdout
    requests = sniffer.sdo_requests()
    assert requests, "dexflash read nothing"
    assert all(d[0] >> 5 == 2 for d in requests), [d.hex() for d in requests]  # uploads only
    node = sdo_node(s)
    assert program_id(node) == zlib.crc32(policies["good"].read_bytes())
    assert int.from_bytes(node.sdo.upload(0x1F57, 1), "little") & 0x100 == 0  # nothing staged


def test_rollback(sim, policies):
    s = sim("good")
    wait_heartbeat(s.bus(), PREOP, 2.0)
    old, new = policies["good"].read_bytes(), policies["other"].read_bytes()
    r = dexflash(s, "--rollback")  # nothing to roll back to yet
    one_line_error(r, "0x08000024")
    assert r.returncode == EXIT_ABORT
    assert dexflash(s, policies["other"]).returncode == 0
    r = dexflash(s, "--rollback")
    assert r.returncode == 0, r.stderr
    assert f"0x{zlib.crc32(old):08X}" in r.stdout.splitlines()[-1]
    node = sdo_node(s)
    assert program_id(node) == zlib.crc32(old)
    assert zlib.crc32(new) != zlib.crc32(old)


def test_a_corrupt_file_is_refused_and_the_node_keeps_its_policy(sim, policies, tmp_path):
    s = sim("good")
    wait_heartbeat(s.bus(), PREOP, 2.0)
    data = bytearray(policies["other"].read_bytes())
    data[len(data) // 2] ^= 0x01
    bad = tmp_path / "corrupt.dxpl"
    bad.write_bytes(bytes(data))
    sniffer = Sniffer(s)
    r = dexflash(s, bad)
    one_line_error(r, "corrupt", "CRC-32")
    assert r.returncode == EXIT_FILE
    node = sdo_node(s)
    assert program_id(node) == zlib.crc32(policies["good"].read_bytes())
    assert not downloads(sniffer.sdo_requests())
    for broken, words in (
        (b"NOPE" + bytes(data[4:]), ("not a policy file",)),
        (bytes(data[:100]), ("truncated",)),
        (bytes(data[:4]) + b"\x09\x00" + bytes(data[6:]), ("format version 9",)),
    ):
        bad.write_bytes(broken)
        r = dexflash(s, bad)
        one_line_error(r, *words)
        assert r.returncode == EXIT_FILE


def test_a_layout_mismatch_is_refused_before_the_download(sim, policies):
    s = sim("good")
    wait_heartbeat(s.bus(), PREOP, 2.0)
    sniffer = Sniffer(s)
    r = dexflash(s, policies["mismatched"])
    one_line_error(r, "layout mismatch")
    assert r.returncode == EXIT_CHECK
    requests = sniffer.sdo_requests()
    assert requests and not downloads(requests)


def test_a_file_the_node_refuses_is_an_abort_and_nothing_starts(sim, policies):
    """Without a policy the node's layout is unknown to dexflash: the node's own check refuses
    the file at the end of the download (0x0800_0020), and dexflash does not start anything."""
    s = sim(None)
    wait_heartbeat(s.bus(), PREOP, 2.0)
    sniffer = Sniffer(s)
    r = dexflash(s, policies["mismatched"])
    one_line_error(r, "0x08000020", "refused")
    assert r.returncode == EXIT_ABORT
    node = sdo_node(s)
    assert program_id(node) == 0
    requests = sniffer.sdo_requests()
    assert downloads(requests)  # it was sent
    assert not [d for d in downloads(requests) if d[1:4] == bytes([0x51, 0x1F, 0x01])]  # no start


def test_a_node_nobody_answers_fails_within_the_timeout(sim, policies):
    s = sim("good")
    wait_heartbeat(s.bus(), PREOP, 2.0)
    t0 = time.monotonic()
    r = dexflash(s, policies["other"], "--timeout", "0.5", node=NODE + 1)
    elapsed = time.monotonic() - t0
    one_line_error(r, f"node {NODE + 1} does not answer")
    assert r.returncode == EXIT_TIMEOUT
    assert elapsed < 10, elapsed  # 0.5 s SDO timeout + start-up of python
    assert program_id(sdo_node(s)) == zlib.crc32(policies["good"].read_bytes())


def test_an_operational_node_is_brought_to_pre_operational_first(operational, policies):
    s, bus = operational
    new = policies["other"].read_bytes()
    r = dexflash(s, policies["other"])
    assert r.returncode == 0, r.stderr
    wait_heartbeat(bus, PREOP, 1.5)
    assert program_id(sdo_node(s)) == zlib.crc32(new)


def test_a_transfer_cut_by_bus_off_fails_and_the_node_keeps_its_policy(sim, policies):
    """The bus goes off (the bus's fault injection, every frame lost) as soon as dexflash opens
    its block download: dexflash stops with a clear error and a non-zero exit, and once the bus
    is back the node still runs its previous policy with nothing staged."""
    s = sim("good")
    bus = s.bus()
    wait_heartbeat(bus, PREOP, 2.0)
    watcher = s.bus()
    cut = threading.Event()

    def cut_at_the_block_download():
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not cut.is_set():
            m = watcher.recv(timeout=0.05)
            # Block download initiate: client command specifier 6 (0xC0 | flags).
            if m is not None and m.arbitration_id == SDO_REQUEST and m.data[0] >> 5 == 6:
                s.control("fault busoff 0")
                cut.set()

    t = threading.Thread(target=cut_at_the_block_download, daemon=True)
    t.start()
    r = dexflash(s, policies["other"], "--timeout", "0.5")
    t.join(timeout=5)
    assert cut.is_set(), "the download never started"
    line = one_line_error(r)
    assert r.returncode in (EXIT_TIMEOUT, EXIT_ABORT), line
    s.control("fault clear")
    wait_heartbeat(bus, PREOP, 3.0)
    node = sdo_node(s)
    assert program_id(node) == zlib.crc32(policies["good"].read_bytes())
    staged, _, downloading = flash_status(node)
    assert not staged and not downloading
    assert runs_policy(bus)
