"""Policy flashing over CAN (the runtime's A/B slots, runtime/src/slots.rs, in the hil-sim controller
node): segmented transfer into the inactive slot, verification, activation only outside operational;
an interrupted, corrupted or refused transfer leaves the active policy untouched; explicit roll-back
to the previous policy, and the automatic one (EMCY 0xFF07) when a new policy's first evaluation
faults."""
import zlib

import can

from conftest import (
    DB, LIMITS, NMT_PREOP, NMT_START, NMT_STOP, NODE, OPERATIONAL, PREOP, STOPPED, PlantTx, collect,
    decode_action, nmt, observation, wait_heartbeat,
)

REQ, RESP = 0x600 + NODE, 0x580 + NODE
POLICY_INFO = 0x290
OK, SEQUENCE, CRC, FORMAT, REFUSED, OPERATIONAL_REFUSED, NO_IMAGE = 0, 1, 3, 4, 5, 6, 7
NO_PREVIOUS = 10
EMCY = 0x080 + NODE


def request(bus, data, wait=True):
    bus.send(can.Message(arbitration_id=REQ, data=data, is_extended_id=False))
    if not wait:
        return None
    got = collect(bus, 1.0, lambda m: m.arbitration_id == RESP)
    assert got and got[-1][1].arbitration_id == RESP, "no flash response"
    return bytes(got[-1][1].data)


def flash(bus, image, crc=None, cut_at=None):
    """Init, data segments (acknowledged every 32), end. Returns the end status (or None if cut)."""
    r = request(bus, [0x01, *len(image).to_bytes(4, "little")])
    assert r == bytes([0x81, OK])
    segments = [image[i:i + 6] for i in range(0, len(image), 6)]
    for n, seg in enumerate(segments):
        if cut_at is not None and n == cut_at:
            return None
        last = n + 1 == len(segments)
        r = request(bus, [0x02, n & 0xFF, *seg], wait=(n + 1) % 32 == 0 or last)
        if r is not None:
            assert r == bytes([0x82, OK, n & 0xFF]), r
    crc = zlib.crc32(image) if crc is None else crc
    return request(bus, [0x03, *crc.to_bytes(4, "little")])[1]


def status(bus):
    r = request(bus, [0x06])
    return r[1], int.from_bytes(r[2:6], "little")


def runs_policy(bus, tx=None):
    """Start, one observation, an answer, stop again. Pass the same `tx` to calls after the first
    (its end-to-end counters run on; a fresh sender's first observation is dropped)."""
    nmt(bus, NMT_START)
    wait_heartbeat(bus, OPERATIONAL, 1.0)
    tx = PlantTx() if tx is None else tx
    tx.send(bus, observation(1))
    got = collect(bus, 0.2, lambda m: m.arbitration_id == 0x282)
    nmt(bus, NMT_STOP)
    wait_heartbeat(bus, STOPPED, 1.0)
    return tx.sample in decode_action([m for _, m in got])


def header_info(image):
    """(format version, layout hash) from a policy file's header (docs/policy-format.md)."""
    return int.from_bytes(image[4:6], "little"), int.from_bytes(image[8:12], "little")


def policy_info(bus):
    """(format version, layout hash) of the next policy-info frame. Call it right after the
    activation response: the controller announces the file at its next cycle, and any other
    request's wait in between would swallow the frame."""
    got = collect(bus, 0.3, lambda m: m.arbitration_id == POLICY_INFO)
    assert got and got[-1][1].arbitration_id == POLICY_INFO, "no policy-info frame"
    d = DB.decode_message(POLICY_INFO, got[-1][1].data, decode_choices=False)
    return d["format_version"], d["layout_hash"]


def test_flash_verify_activate(sim, policies):
    s = sim("good")
    bus = s.bus()
    old = policies["good"].read_bytes()
    new = policies["other"].read_bytes()
    wait_heartbeat(bus, PREOP, 2.0)
    assert status(bus) == (0, zlib.crc32(old))
    assert flash(bus, new) == OK
    assert status(bus)[0] == 2  # verified, not active yet
    assert status(bus)[1] == zlib.crc32(old)
    assert request(bus, [0x04]) == bytes([0x84, OK])
    assert policy_info(bus) == header_info(new)  # policy info announced again
    assert status(bus) == (0, zlib.crc32(new))
    assert runs_policy(bus)


def test_an_int8_policy_is_flashed_and_run_like_an_f32_one(sim, policies):
    # The int8 twin (format version 2) of `other`: a quarter of the weight bytes over the bus, and
    # its commands within 1% of each joint's range of the f32 policy's for the same observation.
    s = sim("good")
    bus = s.bus()
    f32_image = policies["other"].read_bytes()
    int8_image = policies["int8"].read_bytes()
    assert int8_image[4:6] == (2).to_bytes(2, "little") and len(int8_image) < len(f32_image)
    wait_heartbeat(bus, PREOP, 2.0)
    tx = PlantTx()  # one sender: its E2E counters run on across both activations

    def commands(image):
        assert flash(bus, image) == OK
        assert request(bus, [0x04]) == bytes([0x84, OK])
        # The controller runs this file, not the previous one: its policy-info frame names the
        # file's format version and layout hash (the int8 file says 2, the f32 file 1).
        assert policy_info(bus) == header_info(image)
        assert status(bus) == (0, zlib.crc32(image))
        nmt(bus, NMT_START)
        wait_heartbeat(bus, OPERATIONAL, 1.0)
        tx.send(bus, observation(1))
        got = collect(bus, 0.2, lambda m: m.arbitration_id == 0x282)
        nmt(bus, NMT_STOP)
        wait_heartbeat(bus, STOPPED, 1.0)
        nmt(bus, NMT_PREOP)  # back to pre-operational for the next activation
        wait_heartbeat(bus, PREOP, 1.0)
        return decode_action([m for _, m in got])[tx.sample]

    assert header_info(f32_image)[0] == 1 and header_info(int8_image)[0] == 2
    a, b = commands(f32_image), commands(int8_image)
    assert a != b, "int8 commands identical to the f32 ones: is the int8 file running?"
    for name, limit in LIMITS.items():
        assert abs(a[name] - b[name]) <= 0.01 * 2 * limit, (name, a[name], b[name])


def test_interrupted_transfer_leaves_the_active_policy(sim, policies):
    s = sim("good")
    bus = s.bus()
    old = policies["good"].read_bytes()
    wait_heartbeat(bus, PREOP, 2.0)
    assert flash(bus, policies["other"].read_bytes(), cut_at=200) is None
    assert status(bus) == (1, zlib.crc32(old))  # still receiving, old one active
    assert request(bus, [0x04]) == bytes([0x84, NO_IMAGE])
    # A segment out of sequence aborts the transfer.
    assert request(bus, [0x02, 0x55, 1, 2, 3]) == bytes([0x82, SEQUENCE, 0x55])
    assert status(bus) == (0, zlib.crc32(old))
    assert runs_policy(bus)


def test_corrupted_or_refused_images_are_rejected(sim, policies):
    s = sim("good")
    bus = s.bus()
    old = policies["good"].read_bytes()
    new = bytearray(policies["other"].read_bytes())
    wait_heartbeat(bus, PREOP, 2.0)
    good_crc = zlib.crc32(new)
    new[len(new) // 2] ^= 0x01
    assert flash(bus, bytes(new), crc=good_crc) == CRC  # corrupted on the way
    assert flash(bus, bytes(new)) == FORMAT  # transfer intact, file CRC wrong
    assert flash(bus, policies["mismatched"].read_bytes()) == REFUSED  # layout
    assert request(bus, [0x04]) == bytes([0x84, NO_IMAGE])
    assert status(bus) == (0, zlib.crc32(old))
    assert runs_policy(bus)


def test_activation_is_refused_while_operational(sim, policies):
    s = sim("good")
    bus = s.bus()
    wait_heartbeat(bus, PREOP, 2.0)
    new = policies["other"].read_bytes()
    assert flash(bus, new) == OK
    nmt(bus, NMT_START)
    wait_heartbeat(bus, OPERATIONAL, 1.0)
    assert request(bus, [0x04]) == bytes([0x84, OPERATIONAL_REFUSED])
    nmt(bus, NMT_STOP)
    wait_heartbeat(bus, STOPPED, 1.0)
    assert request(bus, [0x04]) == bytes([0x84, OK])
    assert status(bus) == (0, zlib.crc32(new))


def flags(bus):
    """Byte 6 of the status response: bit 0 a previous policy is kept, bit 1 on trial."""
    r = request(bus, [0x06])
    assert len(r) == 7, r
    return r[6]


def test_explicit_roll_back_to_the_previous_policy(sim, policies):
    s = sim("good")
    bus = s.bus()
    old = policies["good"].read_bytes()
    new = policies["other"].read_bytes()
    wait_heartbeat(bus, PREOP, 2.0)
    tx = PlantTx()
    assert request(bus, [0x07]) == bytes([0x87, NO_PREVIOUS])  # only one policy so far
    assert flash(bus, new) == OK
    assert request(bus, [0x04]) == bytes([0x84, OK])
    assert policy_info(bus) == header_info(new)
    assert flags(bus) == 0b11  # previous kept, new one on trial
    assert runs_policy(bus, tx)
    assert flags(bus) == 0b01  # evaluated: no longer on trial
    # Not while operational.
    nmt(bus, NMT_START)
    wait_heartbeat(bus, OPERATIONAL, 1.0)
    assert request(bus, [0x07]) == bytes([0x87, OPERATIONAL_REFUSED])
    nmt(bus, NMT_STOP)
    wait_heartbeat(bus, STOPPED, 1.0)
    assert request(bus, [0x07]) == bytes([0x87, OK])
    assert policy_info(bus) == header_info(old)
    assert status(bus) == (0, zlib.crc32(old))
    assert runs_policy(bus, tx)
    assert request(bus, [0x07]) == bytes([0x87, OK])  # and forward again
    assert status(bus) == (0, zlib.crc32(new))


def test_a_policy_faulting_at_its_first_evaluation_is_rolled_back_with_emcy_0xff07(sim, policies):
    s = sim("good")
    bus = s.bus()
    old = policies["good"].read_bytes()
    bad = policies["faulting"].read_bytes()
    wait_heartbeat(bus, PREOP, 2.0)
    tx = PlantTx()
    assert flash(bus, bad) == OK  # a valid file: it verifies
    assert request(bus, [0x04]) == bytes([0x84, OK])
    assert status(bus) == (0, zlib.crc32(bad))
    nmt(bus, NMT_START)
    wait_heartbeat(bus, OPERATIONAL, 1.0)
    tx.send(bus, observation(1))
    got = [m for _, m in collect(bus, 0.3) if m.arbitration_id in (EMCY, 0x700 + NODE)]
    emcy = [m for m in got if m.arbitration_id == EMCY]
    assert len(emcy) == 1, got
    d = DB.decode_message(EMCY, emcy[0].data, decode_choices=False)
    assert (d["error_code"], d["fault_code"]) == (0xFF07, 7), d
    hb = [m for m in got if m.arbitration_id == 0x700 + NODE]
    assert hb and hb[0].data[0] == STOPPED and hb[0].data[3] == 7, hb
    assert status(bus) == (0, zlib.crc32(old))  # the previous policy is active again
    assert flags(bus) == 0  # the faulty one is not kept for a roll-back
    assert s.diag()["state"] == "SafeStop" and s.diag()["fault"] == "PolicyRolledBack"
    # NMT start runs the old policy (error reset first).
    assert runs_policy(bus, tx)
