"""Two controllers on one bus (`hil-sim bus --node 1 --node 2`): `dexflash` flashes a different
policy file into each, both run, and each answers the observations sent to its own RPDO
identifiers with action frames on its own TPDO identifiers (runtime/src/can/messages.rs,
`rpdo_cob_id` / `tpdo_cob_id`), equal to what the same policy file computes on a controller of
its own for the same observation (the default node of another bus)."""
from conftest import (
    NMT_START, OPERATIONAL, PREOP, PlantTx, action_ids, collect, decode_action, nmt, observation,
    started, wait_heartbeat,
)
from test_dexflash import dexflash

NODES = (1, 2)


def answer(bus, node, tx, values):
    """Sends one observation to `node`'s RPDOs; (its action for that sample, every frame seen)."""
    tx.send(bus, values)
    last = action_ids(node)[2]
    got = [m for _, m in collect(bus, 0.3, lambda m: m.arbitration_id == last)]
    return decode_action(got, node=node).get(tx.sample), got


def test_two_controllers_flashed_with_different_policies_answer_their_own_observations(sim, policies):
    files = {1: policies["good"], 2: policies["other"]}
    s = sim(None, extra=["--node", "1", "--node", "2", "--watchdog-cycles", "20"])
    bus = s.bus()
    for node in NODES:
        wait_heartbeat(bus, PREOP, 2.0, node=node)
    for node in NODES:
        r = dexflash(s, files[node], node=node)
        assert r.returncode == 0, (node, r.stderr)
    # A fresh connection: the first one queued every frame of both nodes while dexflash ran.
    bus = s.bus()
    values = observation(3)
    got = {}
    for node in NODES:
        other = 3 - node
        nmt(bus, NMT_START, node=node)
        wait_heartbeat(bus, OPERATIONAL, 1.0, node=node)
        action, frames = answer(bus, node, PlantTx(node=node), values)
        assert action is not None and len(action) == 9, (node, frames)
        assert any(v != 0.0 for v in action.values())
        # The other node did not take these observations: its action frames (the safe action
        # outside operational) are all zero velocity.
        theirs = decode_action(frames, node=other)
        assert all(v == 0.0 for a in theirs.values() for v in a.values()), theirs
        got[node] = action
    assert got[1] != got[2]  # two different policies

    # Each equals the same file run alone (node 0x10 on a bus of its own), same observation.
    for node in NODES:
        name = "good" if node == 1 else "other"
        _, alone = started(sim(name))
        want, _ = answer(alone, 0x10, PlantTx(), values)
        assert want == got[node], (node, want, got[node])


def test_node_ids_outside_1_to_31_are_refused(hil_sim):
    import subprocess

    for bad in ("0", "32", "0x40"):
        r = subprocess.run(
            [hil_sim, "bus", "--port", "0", "--node", bad, "--seconds", "1"],
            capture_output=True, text=True, timeout=20,
        )
        assert r.returncode != 0 and "1..=31" in r.stderr, r.stderr
