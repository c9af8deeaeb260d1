"""Shared fixtures of the software-in-the-loop tests (tests/test_sil_*.py).

The `hil_sim` fixture builds `dex-hil-sim` with cargo (in the target directory `cargo metadata`
names: CARGO_TARGET_DIR, build.target-dir, default `target/`), the `sim` fixture starts
`hil-sim bus` with the controller node on a free port of 127.0.0.1 and stops it afterwards. Python talks to the bus with python-can's `socketcand`
interface and reads/writes the frames with cantools and the repository's DBC.
"""
import functools
import json
import re
import select
import socket
import subprocess
import time
from pathlib import Path

import can
import cantools
import pytest

ROOT = Path(__file__).resolve().parent.parent
DB = cantools.database.load_file(ROOT / "can" / "jaco.dbc")
NODE = 0x10


def rpdo_cob_id(node: int, k: int) -> int:
    """COB-ID of a controller's RPDO k (observation frame k): the CiA 301 pre-defined set for
    k < 4, then those of node + 32, + 64, + 96 (runtime/src/can/messages.rs, `rpdo_cob_id`)."""
    return 0x200 + 0x100 * (k % 4) + node + 32 * (k // 4)


def tpdo_cob_id(node: int, k: int) -> int:
    """COB-ID of a controller's TPDO k (actions 0..2, policy info 3, status 4)."""
    return 0x180 + 0x100 * (k % 4) + node + 32 * (k // 4)


def action_ids(node: int = NODE) -> list:
    return [tpdo_cob_id(node, k) for k in range(3)]


HEARTBEAT_ID = 0x700 + NODE
EMCY_ID = 0x80 + NODE
ACTION_IDS = action_ids(NODE)
POLICY_INFO_ID = tpdo_cob_id(NODE, 3)
STATUS_ID = tpdo_cob_id(NODE, 4)
PERIOD = 0.05
OBS_MESSAGES = [DB.get_message_by_name(f"OBS_{k:02d}") for k in range(15)]
ACTION_MESSAGES = [DB.get_message_by_name(f"ACTION_{k}") for k in range(3)]
STATUS_MESSAGE = DB.get_message_by_name("STATUS")
# The DBC is that of the default node; every node's frames have its layouts.
assert [m.frame_id for m in OBS_MESSAGES] == [rpdo_cob_id(NODE, k) for k in range(15)]
assert [m.frame_id for m in ACTION_MESSAGES] == ACTION_IDS and STATUS_MESSAGE.frame_id == STATUS_ID
HEAD = {"crc", "alive_counter", "sample_counter"}
OBS_SIGNALS = [s.name for m in OBS_MESSAGES for s in m.signals if s.name not in HEAD]
NMT_START, NMT_STOP, NMT_PREOP = 0x01, 0x02, 0x80
# Command limits of the action joints (+-, rad/s), as in can/jaco.dbc.
LIMITS = {f"arm_joint_{i}": 0.628 for i in (1, 2, 3)}
LIMITS.update({f"arm_joint_{i}": 0.838 for i in (4, 5, 6)})
LIMITS.update({f"finger_{i}": 5.0 for i in (1, 2, 3)})
OPERATIONAL, PREOP, STOPPED = 0x05, 0x7F, 0x04


def crc8_sae_j1850(data: bytes) -> int:
    """CRC-8/SAE-J1850: poly 0x1D, init 0xFF, no reflection, final XOR 0xFF."""
    crc = 0xFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


def protect(can_id: int, data: bytearray) -> bytearray:
    """Fills byte 0 with the E2E CRC over the data id (LE) and bytes 1..n."""
    data[0] = crc8_sae_j1850(can_id.to_bytes(2, "little") + bytes(data[1:]))
    return data


def emcy_crc_ok(can_id: int, data: bytes) -> bool:
    """The emergency's E2E protection (at its end: CRC in byte 7 over the data id and bytes 0..6,
    alive counter in the low nibble of byte 6)."""
    return len(data) == 8 and data[7] == crc8_sae_j1850(can_id.to_bytes(2, "little") + bytes(data[:7]))


@functools.cache
def cargo_target_dir() -> Path:
    """Where cargo builds this workspace (honours CARGO_TARGET_DIR and build.target-dir)."""
    meta = subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps"],
        cwd=ROOT, check=True, capture_output=True, text=True,
    )
    return Path(json.loads(meta.stdout)["target_directory"])


@pytest.fixture(scope="session")
def hil_sim() -> Path:
    subprocess.run(["cargo", "build", "-q", "-p", "dex-hil-sim"], cwd=ROOT, check=True)
    binary = cargo_target_dir() / "debug" / "hil-sim"
    assert binary.exists(), binary
    return binary


@pytest.fixture(scope="session")
def policies(hil_sim, tmp_path_factory):
    d = tmp_path_factory.mktemp("policies")
    good, other, bad = d / "jaco_64.dxpl", d / "jaco_32.dxpl", d / "mismatched.dxpl"
    subprocess.run([hil_sim, "make-policy", "--out", good, "--hidden", "64,64"], check=True)
    subprocess.run(
        [hil_sim, "make-policy", "--out", other, "--hidden", "32,32", "--seed", "2"], check=True
    )
    subprocess.run([hil_sim, "make-policy", "--out", bad, "--mismatched-layout"], check=True)
    int8 = d / "jaco_32_int8.dxpl"
    subprocess.run(
        [hil_sim, "make-policy", "--out", int8, "--hidden", "32,32", "--seed", "2", "--int8"],
        check=True,
    )
    faulting = d / "faulting.dxpl"
    subprocess.run(
        [hil_sim, "make-policy", "--out", faulting, "--hidden", "8", "--faulting"], check=True
    )
    return {"good": good, "other": other, "mismatched": bad, "int8": int8, "faulting": faulting}


class Sim:
    """A running `hil-sim bus` process with the controller node, and python-can buses on it."""

    def __init__(self, binary, policy, log, extra=()):
        args = [binary, "bus", "--port", "0", "--log", log, *extra]
        if policy is not None:
            args += ["--policy", policy]
        else:
            args += ["--controller"]
        self.log = log
        self.proc = subprocess.Popen(
            args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        ready, _, _ = select.select([self.proc.stdout], [], [], 10)
        line = self.proc.stdout.readline() if ready else ""
        m = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
        if not m:
            self.proc.kill()
            raise RuntimeError(f"hil-sim bus did not start: {line!r} {self.proc.stderr.read()}")
        self.port = int(m.group(1))
        self.buses = []
        self.sockets = []

    def bus(self):
        b = can.Bus(
            interface="socketcand", host="127.0.0.1", port=self.port, channel="vcan0", tcp_tune=True
        )
        self.buses.append(b)
        return b

    def raw(self):
        """A raw TCP connection past the greeting (for control commands or garbage)."""
        s = socket.create_connection(("127.0.0.1", self.port), timeout=2)
        self.sockets.append(s)
        assert _read_message(s) == "< hi >"
        return s

    def settle(self, *listeners, probe_id=0x7E5):
        """Returns once every python-can bus in `listeners` is subscribed: a probe frame sent from
        another connection (again every 50 ms) has reached each of them. The event to wait for
        instead of a sleep after connecting; the probe and everything before it are consumed."""
        sender = self.raw()
        sender.sendall(b"< open vcan0 >< rawmode >")
        deadline = time.monotonic() + 5.0
        for rx in listeners:
            while True:
                assert time.monotonic() < deadline, "a client did not subscribe within 5 s"
                sender.sendall(f"< send {probe_id:X} 1 A5 >".encode())
                got = collect(rx, 0.05, lambda m: m.arbitration_id == probe_id)
                if any(m.arbitration_id == probe_id for _, m in got):
                    break
        for rx in listeners:  # drop probes still queued for the ones settled first
            collect(rx, 0.05)
        sender.close()
        self.sockets.remove(sender)

    def control(self, command: str) -> str:
        s = self.raw()
        s.sendall(f"< {command} >".encode())
        reply = _read_message(s)
        s.close()
        self.sockets.remove(s)
        return reply

    def diag(self) -> dict:
        reply = self.control("diag")
        return dict(w.split("=", 1) for w in reply.strip("<> ").split()[1:] if "=" in w)

    def stats(self) -> dict:
        reply = self.control("stats")
        return dict(w.split("=", 1) for w in reply.strip("<> ").split()[1:] if "=" in w)

    def close(self):
        for b in self.buses:
            b.shutdown()
        for s in self.sockets:
            s.close()
        if self.proc.poll() is None:
            try:
                self.control("quit")
                self.proc.wait(timeout=3)
            except Exception:  # noqa: BLE001 - stop it whatever happened
                self.proc.kill()
                self.proc.wait(timeout=3)


def _read_message(s: socket.socket) -> str:
    buf = b""
    deadline = time.monotonic() + 2
    while b">" not in buf and time.monotonic() < deadline:
        chunk = s.recv(4096)
        if not chunk:
            break
        buf += chunk
    return buf[: buf.find(b">") + 1].decode()


@pytest.fixture
def sim(hil_sim, policies, tmp_path):
    """Factory: sim(policy="good"|"mismatched"|None, extra=[...]) -> running Sim."""
    made = []

    def start(policy="good", extra=()):
        path = policies[policy] if policy else None
        s = Sim(hil_sim, path, tmp_path / f"bus{len(made)}.log", extra)
        made.append(s)
        return s

    yield start
    for s in made:
        s.close()


# ---- plant side helpers ---------------------------------------------------------------------


def observation(step: int = 0) -> list:
    """A plausible observation in interface order (44 values)."""
    import math

    q = [0.3 * math.sin(0.1 * step + j) for j in range(9)]
    values = [math.sin(a) for a in q[:6]] + [math.cos(a) for a in q[:6]]
    values += q[6:9] + [0.1] * 9
    values += [0.05, 0.4, 0.02, 1.0, 0.0, 0.0, 0.0, -0.05, 0.45, 0.02, 1.0, 0.0, 0.0, 0.0]
    values += [0.01, 0.02, -0.1, 0.03, 0.04, -0.1]
    assert len(values) == 44 == len(OBS_SIGNALS)
    return values


class PlantTx:
    """Encodes observations into the 15 protected frames (the RPDOs of controller `node`) with
    cantools (one alive counter per id)."""

    def __init__(self, node=NODE):
        self.node = node
        self.counters = [0] * 15
        self.sample = 0

    def frames(self, values, sample=None, counters=None, strict=True):
        if sample is None:
            self.sample = (self.sample + 1) & 0x0F
            sample = self.sample
        named = dict(zip(OBS_SIGNALS, values))
        out = []
        for k, msg in enumerate(OBS_MESSAGES):
            counter = self.counters[k] if counters is None else counters[k]
            signals = {s.name: named.get(s.name, 0.0) for s in msg.signals if s.name not in HEAD}
            signals.update(crc=0, alive_counter=counter, sample_counter=sample)
            data = bytearray(msg.encode(signals, strict=strict))
            can_id = rpdo_cob_id(self.node, k)
            out.append(can.Message(arbitration_id=can_id, data=protect(can_id, data), is_extended_id=False))
            if counters is None:
                self.counters[k] = 0 if counter >= 14 else counter + 1
        return out

    def send(self, bus, values, **kw):
        frames = self.frames(values, **kw)
        for f in frames:
            bus.send(f)
        return frames


def nmt(bus, command, node=NODE):
    bus.send(can.Message(arbitration_id=0, data=[command, node], is_extended_id=False))


def collect(bus, seconds, stop=None):
    """Every message received for `seconds` (or until `stop(msg)` is true), with arrival times."""
    out = []
    deadline = time.monotonic() + seconds
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        msg = bus.recv(timeout=left)
        if msg is None:
            break
        out.append((time.monotonic(), msg))
        if stop is not None and stop(msg):
            break
    return out


def wait_heartbeat(bus, state, seconds=2.0, node=NODE):
    hb = 0x700 + node
    got = collect(bus, seconds, lambda m: m.arbitration_id == hb and m.data[0] == state)
    assert got and got[-1][1].arbitration_id == hb and got[-1][1].data[0] == state, (
        f"no heartbeat with state {state:#x}: {[hex(m.arbitration_id) for _, m in got][-10:]}"
    )
    assert len(got[-1][1].data) == 1, "CiA 301 heartbeat: one byte"
    # The status TPDO goes out with the heartbeat: read it too, so that what a test collects next
    # starts after both (on a timed bus it wins arbitration and came first).
    status = tpdo_cob_id(node, 4)
    if any(m.arbitration_id == status for _, m in got[-3:]):
        return got
    return got + collect(bus, 0.1, lambda m: m.arbitration_id == status)


def heartbeats(got, node=NODE):
    """(bus timestamp, heartbeat) pairs from (time, msg) pairs: the CiA 301 heartbeat's one NMT
    state byte (`nmt_state`) with the status TPDO the controller sends with it (`state`,
    `fault_code`, the envelope bits, its E2E `alive_counter`). The two are written together; on a
    timed bus the status TPDO (TPDO 4, 0x1A0 + node) wins arbitration over the
    heartbeat (0x700 + node) and is on the wire first, so the nearest one in bus time
    is taken, before or after (25 ms: half a period, as node and bus are two
    processes stamped by the wall clock, and a loaded runner can part their writes by milliseconds)."""
    hb_id, status_id = 0x700 + node, tpdo_cob_id(node, 4)
    msgs = [m for _, m in got]
    statuses = [n for n in msgs if n.arbitration_id == status_id]
    out = []
    for m in msgs:
        if m.arbitration_id != hb_id:
            continue
        assert len(m.data) == 1, m
        d = {"nmt_state": m.data[0]}
        near = [n for n in statuses if abs(n.timestamp - m.timestamp) < 0.025]
        status = min(near, key=lambda n: abs(n.timestamp - m.timestamp), default=None)
        if status is not None:
            d.update(STATUS_MESSAGE.decode(status.data, decode_choices=False))
        out.append((m.timestamp, d))
    return out


def decode_status(msgs, node=NODE):
    """The decoded status TPDOs (state, fault_code, envelope bits) of `node` among `msgs`."""
    sid = tpdo_cob_id(node, 4)
    return [STATUS_MESSAGE.decode(m.data, decode_choices=False) for m in msgs if m.arbitration_id == sid]


def decode_action(msgs, node=NODE):
    """{sample: {joint: value}} from complete action frame triples of controller `node`."""
    ids = action_ids(node)
    by_sample = {}
    for m in msgs:
        if m.arbitration_id in ids:
            msg = ACTION_MESSAGES[ids.index(m.arbitration_id)]
            d = msg.decode(m.data, decode_choices=False)
            by_sample.setdefault(d["sample_counter"], {}).update(
                {k: v for k, v in d.items() if k not in HEAD}
            )
    return {s: v for s, v in by_sample.items() if len(v) == 9}


def emcy_codes(msgs):
    return [DB.decode_message(EMCY_ID, m.data, decode_choices=False)["error_code"] for m in msgs if m.arbitration_id == EMCY_ID]


def started(s):
    """Starts the controller of bus `s` (NMT start once it is pre-operational); returns `s` and a
    python-can bus on it."""
    bus = s.bus()
    wait_heartbeat(bus, PREOP, 2.0)
    nmt(bus, NMT_START)
    wait_heartbeat(bus, OPERATIONAL, 1.0)
    return s, bus


@pytest.fixture
def operational(sim):
    """A started controller (good policy) and a python-can bus on it."""
    return started(sim())
