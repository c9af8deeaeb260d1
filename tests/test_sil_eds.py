"""The controller's EDSs (can/jaco.eds for the classic layout, can/jaco_fd.eds for the CAN FD
layout; generated from the SDO server's object tables by runtime/src/canopen/eds.rs) with a stock
CANopen tool: the `canopen` library imports each without a warning, and a running controller node
of that layout (`hil-sim bus`, `hil-sim bus --fd`) answers an SDO upload of every readable object
it lists, with a value of the listed data type's size and, where the EDS gives a default, that
value."""
import gc
import logging
import warnings
from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo import SdoAbortedError

from conftest import NODE, PREOP, rpdo_cob_id, tpdo_cob_id, wait_heartbeat

CAN = Path(__file__).resolve().parent.parent / "can"
EDS = CAN / "jaco.eds"
FD_EDS = CAN / "jaco_fd.eds"
NO_DATA = 0x0800_0024
SIZES = {0x03: 2, 0x05: 1, 0x06: 2, 0x07: 4}  # INTEGER16, UNSIGNED8/16/32
PDO_OBJECTS = [*range(0x1400, 0x140F), *range(0x1600, 0x160F), *range(0x1800, 0x1805), *range(0x1A00, 0x1A05)]
# The FD layout: RPDO 0-1 (the two 48-byte observation frames), TPDO 0 (the 20-byte action
# frame), TPDO 3-4 (policy information, status: classic frames).
FD_PDO_OBJECTS = [0x1400, 0x1401, 0x1600, 0x1601, 0x1800, 0x1803, 0x1804, 0x1A00, 0x1A03, 0x1A04]
READABLE = ("ro", "rw", "const", "rwr", "rww")
# Each EDS with the bus flags of a node of its layout.
LAYOUTS = {"classic": (EDS, ()), "fd": (FD_EDS, ("--fd",))}


class Records(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.records = []

    def emit(self, record):
        self.records.append(record)


def import_quietly(eds=EDS):
    """canopen.import_od of `eds`; (dictionary, Python warnings, canopen log records)."""
    handler = Records()
    log = logging.getLogger("canopen")
    log.addHandler(handler)
    old_level = log.level
    log.setLevel(logging.WARNING)
    # Other tests' garbage (unclosed pipes: ResourceWarning) is collected before, not during the
    # import, so that what is recorded is the import's own.
    gc.collect()
    gc.disable()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            od = canopen.import_od(str(eds), NODE)
    finally:
        gc.enable()
        log.removeHandler(handler)
        log.setLevel(old_level)
    return od, caught, handler.records


def variables(od):
    """Every ODVariable of the dictionary, in index and sub-index order (not the dummy data type
    entries below 0x1000 that [DummyUsage] declares: no objects of the device)."""
    out = []
    for index in sorted(i for i in od.indices if i >= 0x1000):
        obj = od[index]
        if isinstance(obj, ODVariable):
            out.append(obj)
        else:
            assert isinstance(obj, (ODRecord, ODArray)), obj
            out += [obj[s] for s in sorted(obj.subindices)]
    return out


@pytest.mark.parametrize("layout", LAYOUTS)
def test_the_eds_imports_without_warnings(layout):
    od, caught, records = import_quietly(LAYOUTS[layout][0])
    assert not caught, [str(w.message) for w in caught]
    assert not records, [r.getMessage() for r in records]
    assert od.device_information.product_number == 0x44584A43
    # The objects docs/runtime.md lists, and nothing else.
    assert sorted(od.indices) == sorted([
        0x0003,  # the INTEGER16 dummy that pads the last observation RPDO (FD: both)
        0x1000, 0x1001, 0x1003, 0x1017, 0x1018, 0x1029,
        *(PDO_OBJECTS if layout == "classic" else FD_PDO_OBJECTS), 0x1F50, 0x1F51, 0x1F56,
        0x1F57, 0x2000, 0x2001, 0x2002, 0x2100, 0x2101, 0x2200, 0x2201,
    ])
    assert len(od[0x2101].subindices) == (16 if layout == "classic" else 3)
    assert od[0x1F50][1].data_type == 0x0F and od[0x1F50][1].access_type == "wo"
    assert od[0x1F51][1].access_type == "rw"
    assert len(od[0x1003].subindices) == 9 and len(od[0x2000].subindices) == 6
    for var in variables(od):
        assert var.data_type in (0x03, 0x05, 0x06, 0x07, 0x0F), var.name
    # The identity in the device info agrees with 0x1018's defaults.
    assert od[0x1018][2].default == od.device_information.product_number
    assert od[0x1018][3].default == od.device_information.revision_number


def start_eds_node(sim, layout):
    """A controller of `layout` (good policy, pre-operational) and a canopen node on its EDS;
    (node, network)."""
    eds, flags = LAYOUTS[layout]
    s = sim("good", extra=flags)
    wait_heartbeat(s.bus(), PREOP, 2.0)
    bus = s.bus()
    s.buses.remove(bus)  # the network shuts it down
    network = canopen.Network(bus)
    network.connect()
    node = network.add_node(NODE, str(eds))
    node.sdo.RESPONSE_TIMEOUT = 2.0
    return node, network


@pytest.fixture
def eds_node(sim):
    """A classic controller (good policy, pre-operational) and a canopen node on its EDS."""
    node, network = start_eds_node(sim, "classic")
    yield node
    network.disconnect()


@pytest.fixture(params=list(LAYOUTS))
def any_eds_node(sim, request):
    """eds_node in each layout: the classic node on jaco.eds, the FD node on jaco_fd.eds."""
    node, network = start_eds_node(sim, request.param)
    yield node
    network.disconnect()


def test_every_readable_object_of_the_eds_answers_an_upload(any_eds_node):
    node = any_eds_node
    errors = int(node.sdo[0x1003][0].raw)
    seen = 0
    for var in variables(node.object_dictionary):
        if var.access_type not in READABLE:
            continue
        if var.index == 0x1003 and var.subindex > errors:
            # An empty slot of the error history exists and reads as "no data".
            with pytest.raises(SdoAbortedError) as e:
                node.sdo.upload(var.index, var.subindex)
            assert e.value.code == NO_DATA
            continue
        raw = node.sdo.upload(var.index, var.subindex)
        assert len(raw) == SIZES[var.data_type], f"{var.index:#06x}:{var.subindex} {var.name}"
        # The EDS's data type decodes the uploaded bytes (decoded from this one upload: a second
        # one may land in another control cycle, and the PDO objects' E2E headers change every
        # cycle, as CI once saw).
        value = var.decode_raw(raw)
        assert value == int.from_bytes(raw, "little", signed=var.data_type == 0x03)
        if var.default is not None:
            assert value == var.default, f"{var.index:#06x}:{var.subindex} {var.name}: {value} != default {var.default}"
        seen += 1
    assert seen >= 25  # 1000, 1001, 1003:0, 1017, 1018:0-4, 1029:0-1, 1F5x:0-1 (no 1F50:1), 2000:0-5, 2001


def test_identity_and_device_type_equal_the_eds(eds_node):
    node = eds_node
    od = node.object_dictionary
    assert node.sdo[0x1000].raw == od[0x1000].default == 0
    for sub in range(5):
        assert od[0x1018][sub].default is not None
        assert node.sdo[0x1018][sub].raw == od[0x1018][sub].default
    # The active policy's objects are the good policy's (not in the EDS: live values).
    assert node.sdo[0x2000][3].raw == node.sdo[0x1F56][1].raw != 0


def test_write_only_program_data_is_refused_for_upload(eds_node):
    with pytest.raises(SdoAbortedError) as e:
        eds_node.sdo.upload(0x1F50, 1)
    assert e.value.code == 0x0601_0001  # write only
    with pytest.raises(SdoAbortedError) as e:
        eds_node.sdo.upload(0x1018, 5)  # beyond the EDS's sub-indices
    assert e.value.code == 0x0609_0011
    with pytest.raises(SdoAbortedError) as e:
        eds_node.sdo.upload(0x1005, 0)  # not in the EDS
    assert e.value.code == 0x0602_0000


def test_the_fd_node_answers_the_fd_mapping_and_not_the_classic_pdos(sim):
    """Over SDO (not the EDS): the FD node's RPDO 0 maps 24 16-bit entries (48 bytes), its TPDO 0
    10 (20 bytes); the classic PDOs it has not are absent; the classic node still answers them."""
    node, network = start_eds_node(sim, "fd")
    try:
        assert node.sdo.upload(0x1600, 0) == bytes([24])
        entries = [int.from_bytes(node.sdo.upload(0x1600, s), "little") for s in range(1, 25)]
        assert entries == [0x2101_0110, *[0x2100_0010 | v << 8 for v in range(1, 23)], 0x0003_0010]
        assert node.sdo.upload(0x1A00, 0) == bytes([10])
        assert int.from_bytes(node.sdo.upload(0x1A00, 10), "little") == 0x2200_0910
        assert int.from_bytes(node.sdo.upload(0x1401, 1), "little") == rpdo_cob_id(NODE, 1)
        for index in (0x1402, 0x1602, 0x1801, 0x1A01, 0x1A02):
            with pytest.raises(SdoAbortedError) as e:
                node.sdo.upload(index, 0)
            assert e.value.code == 0x0602_0000
    finally:
        network.disconnect()
    node, network = start_eds_node(sim, "classic")
    try:
        assert node.sdo.upload(0x1600, 0) == bytes([4])
        assert int.from_bytes(node.sdo.upload(0x1A01, 1), "little") == 0x2201_0210
    finally:
        network.disconnect()


def test_pdo_configuration_from_the_eds():
    """canopen reads the PDO communication and mapping objects from the EDS (no SDO): the
    node-derived COB-IDs (RPDO k = observation frame k; TPDO 0-2 actions, 3 policy info, 4
    status) and mappings as long as the frames."""
    for node_id in (1, NODE, 31):
        network = canopen.Network()
        node = network.add_node(node_id, str(EDS))
        node.rpdo.read(from_od=True)
        node.tpdo.read(from_od=True)
        rpdos = [node.rpdo[k + 1] for k in range(15)]
        tpdos = [node.tpdo[k + 1] for k in range(5)]
        assert [p.cob_id for p in rpdos] == [rpdo_cob_id(node_id, k) for k in range(15)]
        assert [p.cob_id for p in tpdos] == [tpdo_cob_id(node_id, k) for k in range(5)]
        assert all(p.enabled and p.trans_type == 0xFE for p in rpdos + tpdos)
        assert [p.length for p in rpdos] == [64] * 15
        assert [p.length for p in tpdos] == [64, 64, 64, 64, 40]
        assert [(v.index, v.subindex) for v in tpdos[4]] == [
            (0x2201, 5), (0x2002, 1), (0x2002, 2), (0x2001, 0),
        ]
        assert [v.index for v in rpdos[14]] == [0x2101, 0x2100, 0x2100, 0x0003]


def test_stock_canopen_heartbeat_nmt_and_emcy(eds_node):
    """canopen's own NMT master and EMCY consumer on the node: the one-byte heartbeat gives
    `wait_for_heartbeat` the states, and the watchdog's emergency arrives as error code 0x8250
    (RPDO timeout) with the error register (generic + communication) in byte 2."""
    node = eds_node
    assert node.nmt.wait_for_heartbeat(2.0) == "PRE-OPERATIONAL"
    node.nmt.state = "OPERATIONAL"
    # No observations follow: the watchdog stops the node after 3 periods.
    emcy = node.emcy.wait(0x8250, timeout=2.0)
    assert emcy is not None and emcy.code == 0x8250, node.emcy.log
    assert emcy.register == 0x11
    assert emcy.data[:2] == bytes([1, 3])  # fault code 1 (observation timeout), safe-stop
    assert node.nmt.wait_for_heartbeat(2.0) == "STOPPED"
    node.nmt.state = "PRE-OPERATIONAL"
    assert node.nmt.wait_for_heartbeat(2.0) == "PRE-OPERATIONAL"
    # 0x1003 holds the same code (fault code in bits 16-23).
    assert node.sdo[0x1003][1].raw == 0x0001_8250


def test_fd_pdo_configuration_from_the_eds():
    """canopen reads the FD layout's PDOs from jaco_fd.eds (no SDO): RPDO 0-1 of 48 bytes
    (header, 22 values, dummy), TPDO 0 of 20 bytes (header, 9 actions), TPDO 3-4 as classic."""
    for node_id in (1, NODE, 31):
        network = canopen.Network()
        node = network.add_node(node_id, str(FD_EDS))
        node.rpdo.read(from_od=True)
        node.tpdo.read(from_od=True)
        rpdos = [node.rpdo[k + 1] for k in range(2)]
        tpdos = {k: node.tpdo[k + 1] for k in (0, 3, 4)}
        assert [p.cob_id for p in rpdos] == [rpdo_cob_id(node_id, k) for k in range(2)]
        assert {k: p.cob_id for k, p in tpdos.items()} == {k: tpdo_cob_id(node_id, k) for k in tpdos}
        assert all(p.enabled and p.trans_type == 0xFE for p in [*rpdos, *tpdos.values()])
        assert [p.length for p in rpdos] == [48 * 8] * 2
        assert [tpdos[k].length for k in (0, 3, 4)] == [20 * 8, 64, 40]
        for k, p in enumerate(rpdos):
            assert [(v.index, v.subindex) for v in p] == [
                (0x2101, k + 1), *[(0x2100, 22 * k + s) for s in range(1, 23)], (0x0003, 0),
            ]
        assert [(v.index, v.subindex) for v in tpdos[0]] == [
            (0x2201, 1), *[(0x2200, s) for s in range(1, 10)],
        ]
        # Only these PDOs: no RPDO 2-14, no TPDO 1-2.
        assert [p.cob_id for p in node.rpdo.map.values() if p.cob_id] == [p.cob_id for p in rpdos]
