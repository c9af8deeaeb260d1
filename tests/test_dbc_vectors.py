"""cantools, reading can/jaco.dbc, produces and parses the same bytes as the Rust codec.

The vectors in tests/can/vectors.json were made by the Rust codec
(`cargo run -p dex-runtime --example make_can_vectors`; a Rust test keeps them current).
The CRC-8/SAE-J1850 of every protected frame is also recomputed here from its definition.
"""
import json
import math
from pathlib import Path

import cantools
import pytest

from conftest import crc8_sae_j1850

ROOT = Path(__file__).resolve().parent.parent
DB = cantools.database.load_file(ROOT / "can" / "jaco.dbc")
VECTORS = json.loads((ROOT / "tests" / "can" / "vectors.json").read_text())
UNPROTECTED = {"NMT", "HEARTBEAT"}
TAIL_PROTECTED = {"EMCY"}  # CiA 301 bytes 0-2 first: the CRC in byte 7, the counter in byte 6


def test_reference_crc_check_value():
    assert crc8_sae_j1850(b"123456789") == 0x4B


def test_every_message_of_the_dbc_has_vectors():
    assert {m.name for m in DB.messages} == {v["message"] for v in VECTORS}


@pytest.mark.parametrize("vector", VECTORS, ids=lambda v: v["message"])
def test_cantools_encodes_the_same_bytes(vector):
    message = DB.get_message_by_frame_id(vector["id"])
    assert message.name == vector["message"]
    data = bytes.fromhex(vector["data"])
    encoded = message.encode(vector["signals"], scaling=True, strict=True)
    assert encoded[: len(data)] == data
    assert len(encoded) == message.length == len(data)


@pytest.mark.parametrize("vector", VECTORS, ids=lambda v: v["message"])
def test_cantools_decodes_the_rust_bytes(vector):
    decoded = DB.decode_message(vector["id"], bytes.fromhex(vector["data"]), decode_choices=False)
    assert set(decoded) == set(vector["signals"])
    for name, want in vector["signals"].items():
        assert math.isclose(decoded[name], want, rel_tol=1e-6, abs_tol=1e-7), name


@pytest.mark.parametrize(
    "vector", [v for v in VECTORS if v["message"] in TAIL_PROTECTED], ids=lambda v: v["message"]
)
def test_tail_e2e_crc_matches_the_reference(vector):
    data = bytes.fromhex(vector["data"])
    data_id = vector["id"].to_bytes(2, "little")
    assert data[7] == crc8_sae_j1850(data_id + data[:7])
    assert data[6] & 0x0F <= 14


@pytest.mark.parametrize(
    "vector",
    [v for v in VECTORS if v["message"] not in UNPROTECTED | TAIL_PROTECTED],
    ids=lambda v: v["message"],
)
def test_e2e_crc_matches_the_reference(vector):
    data = bytes.fromhex(vector["data"])
    data_id = vector["id"].to_bytes(2, "little")
    assert data[0] == crc8_sae_j1850(data_id + data[1:])
    assert data[1] & 0x0F <= 14
