//! The PDO communication and mapping objects (CiA 301) that describe the controller's frames,
//! and the manufacturer objects they map: the frame layouts of [`crate::can::messages`] as a
//! CANopen tool reads them from the EDS (`runtime/tests/eds.rs` checks these tables against the
//! codec's identifiers and frame lengths). The mapping is fixed: every object here is read-only.
//!
//! | index | object |
//! |---|---|
//! | 0x1400 + k, k = 0..14 | RPDO k communication: COB-ID [`crate::can::messages::rpdo_cob_id`], transmission type 0xFE |
//! | 0x1600 + k | RPDO k mapping: 0x2101:k+1 (E2E header, 16 bits), three observation values of 0x2100 (a dummy INTEGER16 after the last) |
//! | 0x1800 + k, k = 0..4 | TPDO k communication: COB-ID [`crate::can::messages::tpdo_cob_id`], transmission type 0xFE |
//! | 0x1A00 + k | TPDO k mapping: 0x2201:k+1 (E2E header), then three action values of 0x2200 (k < 3), 0x2000:1, :2, :4 (policy information, k = 3) or 0x2002:1, :2, 0x2001 (status, k = 4) |
//! | 0x2100 | observation values: 44 x INTEGER16, the raw values of the last complete observation |
//! | 0x2101 | observation E2E headers: 15 x UNSIGNED16, bytes 0-1 of the last accepted frame k (CRC, counter and sample nibble) |
//! | 0x2200 | action values: 9 x INTEGER16, the raw values of the last action sent |
//! | 0x2201 | TPDO E2E headers: 5 x UNSIGNED16, bytes 0-1 of the last frame sent on TPDO k |
//!
//! COB-IDs are `$NODEID`-relative in the EDS; a read of sub-index 1 answers the node's own.
//! One deviation from CiA 301, on purpose: the action TPDOs also go out outside operational,
//! carrying the safe action (zero velocity) every cycle, where CiA 301 sends no PDO; a master
//! must expect them in every NMT state. Observations are only evaluated in operational.

use super::od::{Access, DataType, Object, ObjectKind, SubObject, Value};

const fn sub(sub: u8, name: &'static str, data_type: DataType, value: Value) -> SubObject {
    SubObject {
        sub,
        name,
        data_type,
        access: Access::ReadOnly,
        value,
    }
}

const U8: DataType = DataType::Unsigned8;
const U16: DataType = DataType::Unsigned16;
const U32: DataType = DataType::Unsigned32;
const I16: DataType = DataType::Integer16;

/// A mapping entry: object `index`:`sub`, `bits` long (CiA 301's UNSIGNED32 layout).
pub const fn map_entry(index: u16, sub: u8, bits: u8) -> u32 {
    ((index as u32) << 16) | ((sub as u32) << 8) | bits as u32
}

/// Transmission type of every PDO: event-driven (manufacturer-specific, 0xFE). An observation
/// frame is taken when it arrives, the actions go out when an observation completes, the
/// policy information and status on their events (see [`crate::can::messages`]).
pub const TRANSMISSION_TYPE: u32 = 0xFE;
/// Index of the observation values.
pub const OBSERVATION_VALUES: u16 = 0x2100;
/// Index of the observation frames' E2E headers.
pub const OBSERVATION_E2E: u16 = 0x2101;
/// Index of the action values.
pub const ACTION_VALUES: u16 = 0x2200;
/// Index of the TPDOs' E2E headers.
pub const TPDO_E2E: u16 = 0x2201;
/// The dummy INTEGER16 entry (CiA 301 data type 0x0003) that pads the last observation frame.
pub const DUMMY_INTEGER16: u16 = 0x0003;

/// The PDO communication and mapping objects and the manufacturer objects they map, in index
/// order (the table above).
pub const OBJECTS: [Object; 44] = [
    Object {
        index: 0x1400,
        name: "RPDO 1 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x200)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1401,
        name: "RPDO 2 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x300)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1402,
        name: "RPDO 3 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x400)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1403,
        name: "RPDO 4 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x500)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1404,
        name: "RPDO 5 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x220)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1405,
        name: "RPDO 6 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x320)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1406,
        name: "RPDO 7 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x420)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1407,
        name: "RPDO 8 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x520)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1408,
        name: "RPDO 9 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x240)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1409,
        name: "RPDO 10 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x340)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x140A,
        name: "RPDO 11 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x440)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x140B,
        name: "RPDO 12 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x540)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x140C,
        name: "RPDO 13 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x260)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x140D,
        name: "RPDO 14 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x360)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x140E,
        name: "RPDO 15 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by RPDO", U32, Value::NodeId(0x460)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1600,
        name: "RPDO 1 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 1, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 1, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 2, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 3, 16)),
            ),
        ],
    },
    Object {
        index: 0x1601,
        name: "RPDO 2 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 2, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 4, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 5, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 6, 16)),
            ),
        ],
    },
    Object {
        index: 0x1602,
        name: "RPDO 3 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 3, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 7, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 8, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 9, 16)),
            ),
        ],
    },
    Object {
        index: 0x1603,
        name: "RPDO 4 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 4, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 10, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 11, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 12, 16)),
            ),
        ],
    },
    Object {
        index: 0x1604,
        name: "RPDO 5 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 5, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 13, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 14, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 15, 16)),
            ),
        ],
    },
    Object {
        index: 0x1605,
        name: "RPDO 6 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 6, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 16, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 17, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 18, 16)),
            ),
        ],
    },
    Object {
        index: 0x1606,
        name: "RPDO 7 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 7, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 19, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 20, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 21, 16)),
            ),
        ],
    },
    Object {
        index: 0x1607,
        name: "RPDO 8 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 8, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 22, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 23, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 24, 16)),
            ),
        ],
    },
    Object {
        index: 0x1608,
        name: "RPDO 9 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 9, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 25, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 26, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 27, 16)),
            ),
        ],
    },
    Object {
        index: 0x1609,
        name: "RPDO 10 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 10, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 28, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 29, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 30, 16)),
            ),
        ],
    },
    Object {
        index: 0x160A,
        name: "RPDO 11 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 11, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 31, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 32, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 33, 16)),
            ),
        ],
    },
    Object {
        index: 0x160B,
        name: "RPDO 12 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 12, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 34, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 35, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 36, 16)),
            ),
        ],
    },
    Object {
        index: 0x160C,
        name: "RPDO 13 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 13, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 37, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 38, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 39, 16)),
            ),
        ],
    },
    Object {
        index: 0x160D,
        name: "RPDO 14 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 14, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 40, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 41, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 42, 16)),
            ),
        ],
    },
    Object {
        index: 0x160E,
        name: "RPDO 15 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(OBSERVATION_E2E, 15, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 43, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(OBSERVATION_VALUES, 44, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(DUMMY_INTEGER16, 0, 16)),
            ),
        ],
    },
    Object {
        index: 0x1800,
        name: "TPDO 1 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by TPDO", U32, Value::NodeId(0x180)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1801,
        name: "TPDO 2 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by TPDO", U32, Value::NodeId(0x280)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1802,
        name: "TPDO 3 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by TPDO", U32, Value::NodeId(0x380)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1803,
        name: "TPDO 4 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by TPDO", U32, Value::NodeId(0x480)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1804,
        name: "TPDO 5 communication parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(2)),
            sub(1, "COB-ID used by TPDO", U32, Value::NodeId(0x1A0)),
            sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
        ],
    },
    Object {
        index: 0x1A00,
        name: "TPDO 1 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(TPDO_E2E, 1, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 1, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 2, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 3, 16)),
            ),
        ],
    },
    Object {
        index: 0x1A01,
        name: "TPDO 2 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(TPDO_E2E, 2, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 4, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 5, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 6, 16)),
            ),
        ],
    },
    Object {
        index: 0x1A02,
        name: "TPDO 3 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(TPDO_E2E, 3, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 7, 16)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 8, 16)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(ACTION_VALUES, 9, 16)),
            ),
        ],
    },
    Object {
        index: 0x1A03,
        name: "TPDO 4 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(TPDO_E2E, 4, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(0x2000, 1, 32)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(0x2000, 2, 8)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(0x2000, 4, 8)),
            ),
        ],
    },
    Object {
        index: 0x1A04,
        name: "TPDO 5 mapping parameter",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Number of mapped objects", U8, Value::Const(4)),
            sub(
                1,
                "Mapped object 1",
                U32,
                Value::Const(map_entry(TPDO_E2E, 5, 16)),
            ),
            sub(
                2,
                "Mapped object 2",
                U32,
                Value::Const(map_entry(0x2002, 1, 8)),
            ),
            sub(
                3,
                "Mapped object 3",
                U32,
                Value::Const(map_entry(0x2002, 2, 8)),
            ),
            sub(
                4,
                "Mapped object 4",
                U32,
                Value::Const(map_entry(0x2001, 0, 8)),
            ),
        ],
    },
    Object {
        index: 0x2100,
        name: "Observation values",
        kind: ObjectKind::Array,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(44)),
            sub(1, "Observation value 1", I16, Value::Live),
            sub(2, "Observation value 2", I16, Value::Live),
            sub(3, "Observation value 3", I16, Value::Live),
            sub(4, "Observation value 4", I16, Value::Live),
            sub(5, "Observation value 5", I16, Value::Live),
            sub(6, "Observation value 6", I16, Value::Live),
            sub(7, "Observation value 7", I16, Value::Live),
            sub(8, "Observation value 8", I16, Value::Live),
            sub(9, "Observation value 9", I16, Value::Live),
            sub(10, "Observation value 10", I16, Value::Live),
            sub(11, "Observation value 11", I16, Value::Live),
            sub(12, "Observation value 12", I16, Value::Live),
            sub(13, "Observation value 13", I16, Value::Live),
            sub(14, "Observation value 14", I16, Value::Live),
            sub(15, "Observation value 15", I16, Value::Live),
            sub(16, "Observation value 16", I16, Value::Live),
            sub(17, "Observation value 17", I16, Value::Live),
            sub(18, "Observation value 18", I16, Value::Live),
            sub(19, "Observation value 19", I16, Value::Live),
            sub(20, "Observation value 20", I16, Value::Live),
            sub(21, "Observation value 21", I16, Value::Live),
            sub(22, "Observation value 22", I16, Value::Live),
            sub(23, "Observation value 23", I16, Value::Live),
            sub(24, "Observation value 24", I16, Value::Live),
            sub(25, "Observation value 25", I16, Value::Live),
            sub(26, "Observation value 26", I16, Value::Live),
            sub(27, "Observation value 27", I16, Value::Live),
            sub(28, "Observation value 28", I16, Value::Live),
            sub(29, "Observation value 29", I16, Value::Live),
            sub(30, "Observation value 30", I16, Value::Live),
            sub(31, "Observation value 31", I16, Value::Live),
            sub(32, "Observation value 32", I16, Value::Live),
            sub(33, "Observation value 33", I16, Value::Live),
            sub(34, "Observation value 34", I16, Value::Live),
            sub(35, "Observation value 35", I16, Value::Live),
            sub(36, "Observation value 36", I16, Value::Live),
            sub(37, "Observation value 37", I16, Value::Live),
            sub(38, "Observation value 38", I16, Value::Live),
            sub(39, "Observation value 39", I16, Value::Live),
            sub(40, "Observation value 40", I16, Value::Live),
            sub(41, "Observation value 41", I16, Value::Live),
            sub(42, "Observation value 42", I16, Value::Live),
            sub(43, "Observation value 43", I16, Value::Live),
            sub(44, "Observation value 44", I16, Value::Live),
        ],
    },
    Object {
        index: 0x2101,
        name: "Observation E2E headers",
        kind: ObjectKind::Array,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(15)),
            sub(1, "Observation frame E2E header 1", U16, Value::Live),
            sub(2, "Observation frame E2E header 2", U16, Value::Live),
            sub(3, "Observation frame E2E header 3", U16, Value::Live),
            sub(4, "Observation frame E2E header 4", U16, Value::Live),
            sub(5, "Observation frame E2E header 5", U16, Value::Live),
            sub(6, "Observation frame E2E header 6", U16, Value::Live),
            sub(7, "Observation frame E2E header 7", U16, Value::Live),
            sub(8, "Observation frame E2E header 8", U16, Value::Live),
            sub(9, "Observation frame E2E header 9", U16, Value::Live),
            sub(10, "Observation frame E2E header 10", U16, Value::Live),
            sub(11, "Observation frame E2E header 11", U16, Value::Live),
            sub(12, "Observation frame E2E header 12", U16, Value::Live),
            sub(13, "Observation frame E2E header 13", U16, Value::Live),
            sub(14, "Observation frame E2E header 14", U16, Value::Live),
            sub(15, "Observation frame E2E header 15", U16, Value::Live),
        ],
    },
    Object {
        index: 0x2200,
        name: "Action values",
        kind: ObjectKind::Array,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(9)),
            sub(1, "Action value 1", I16, Value::Live),
            sub(2, "Action value 2", I16, Value::Live),
            sub(3, "Action value 3", I16, Value::Live),
            sub(4, "Action value 4", I16, Value::Live),
            sub(5, "Action value 5", I16, Value::Live),
            sub(6, "Action value 6", I16, Value::Live),
            sub(7, "Action value 7", I16, Value::Live),
            sub(8, "Action value 8", I16, Value::Live),
            sub(9, "Action value 9", I16, Value::Live),
        ],
    },
    Object {
        index: 0x2201,
        name: "TPDO E2E headers",
        kind: ObjectKind::Array,
        subs: &[
            sub(0, "Highest sub-index supported", U8, Value::Const(5)),
            sub(1, "TPDO E2E header 1", U16, Value::Live),
            sub(2, "TPDO E2E header 2", U16, Value::Live),
            sub(3, "TPDO E2E header 3", U16, Value::Live),
            sub(4, "TPDO E2E header 4", U16, Value::Live),
            sub(5, "TPDO E2E header 5", U16, Value::Live),
        ],
    },
];
