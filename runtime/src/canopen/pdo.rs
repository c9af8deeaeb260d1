//! The PDO communication and mapping objects (CiA 301, and CANopen FD, CiA 1301, for PDOs up to
//! 64 bytes) that describe the controller's frames, and the manufacturer objects they map: the
//! frame layouts of [`crate::can::messages`] (classic) and [`crate::can::fd_messages`] (FD) as a
//! CANopen tool reads them from the EDS (`runtime/tests/eds.rs` checks these tables against the
//! codecs' identifiers, frame lengths and bytes). One table per [`FrameLayout`] ([`objects`]):
//! [`OBJECTS`] for the classic layout, [`FD_OBJECTS`] for the FD layout; the SDO server serves
//! the one of its controller's layout and the EDS writer lists it (`can/jaco.eds`,
//! `can/jaco_fd.eds`). The mapping is fixed: every object here is read-only.
//!
//! Classic layout ([`OBJECTS`]):
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
//! FD layout ([`FD_OBJECTS`]): RPDO 0-1 and TPDO 0 are the FD frames, TPDO 3-4 (policy
//! information, status) stay the classic frames; there are no RPDO 2-14 and no TPDO 1-2.
//!
//! | index | object |
//! |---|---|
//! | 0x1400, 0x1401 | RPDO 0, 1 communication (COB-IDs `0x200`, `0x300` + node), transmission type 0xFE |
//! | 0x1600 + k, k = 0, 1 | RPDO k mapping, 24 entries (48 bytes): 0x2101:k+1 (E2E header), observation values 22k+1..22k+22 of 0x2100, a dummy INTEGER16 (bytes 46-47) |
//! | 0x1800, 0x1803, 0x1804 | TPDO 0, 3, 4 communication, as classic |
//! | 0x1A00 | TPDO 0 mapping, 10 entries (20 bytes): 0x2201:1 (E2E header), action values 1..9 of 0x2200 |
//! | 0x1A03, 0x1A04 | policy information and status, as classic |
//! | 0x2100, 0x2200, 0x2201 | as classic (0x2201:2, :3 stay 0: no TPDO 1-2 is sent) |
//! | 0x2101 | observation E2E headers: 2 x UNSIGNED16, of the two FD observation frames |
//!
//! COB-IDs are `$NODEID`-relative in the EDS; a read of sub-index 1 answers the node's own.
//! One deviation from CiA 301, on purpose: the action TPDOs also go out outside operational,
//! carrying the safe action (zero velocity) every cycle, where CiA 301 sends no PDO; a master
//! must expect them in every NMT state. Observations are only evaluated in operational.

use super::od::{Access, DataType, Object, ObjectKind, SubObject, Value};
use crate::can::fd_messages::{FD_ACTION_LEN, FD_OBS_LEN, FD_VALUES_PER_OBS_FRAME};
use crate::can::layout::FrameLayout;
use crate::can::messages::{rpdo_cob_id, tpdo_cob_id};
use crate::interface::{ACT_DIM, OBS_DIM};

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

/// A PDO communication parameter record: COB-ID `$cob` relative to the node id, transmission
/// type [`TRANSMISSION_TYPE`].
macro_rules! pdo_comm {
    ($index:expr, $name:expr, $cob_name:expr, $cob:expr) => {
        Object {
            index: $index,
            name: $name,
            kind: ObjectKind::Record,
            subs: &[
                sub(0, "Highest sub-index supported", U8, Value::Const(2)),
                sub(1, $cob_name, U32, Value::NodeId($cob as u32)),
                sub(2, "Transmission type", U8, Value::Const(TRANSMISSION_TYPE)),
            ],
        }
    };
}

/// RPDO `$k` (number `$n` = k + 1): its communication record at 0x1400 + k.
macro_rules! rpdo_comm {
    ($k:literal, $n:literal) => {
        pdo_comm!(
            0x1400 + $k,
            concat!("RPDO ", $n, " communication parameter"),
            "COB-ID used by RPDO",
            rpdo_cob_id(0, $k)
        )
    };
}

/// TPDO `$k` (number `$n` = k + 1): its communication record at 0x1800 + k.
macro_rules! tpdo_comm {
    ($k:literal, $n:literal) => {
        pdo_comm!(
            0x1800 + $k,
            concat!("TPDO ", $n, " communication parameter"),
            "COB-ID used by TPDO",
            tpdo_cob_id(0, $k)
        )
    };
}

/// A mapping record of four entries: the frame's E2E header, then three 16-bit values.
macro_rules! pdo_map {
    ($index:expr, $name:expr, $e2e:expr, $k:expr, [$a:expr, $b:expr, $c:expr]) => {
        Object {
            index: $index,
            name: $name,
            kind: ObjectKind::Record,
            subs: &[
                sub(0, "Number of mapped objects", U8, Value::Const(4)),
                sub(
                    1,
                    "Mapped object 1",
                    U32,
                    Value::Const(map_entry($e2e, $k + 1, 16)),
                ),
                sub(2, "Mapped object 2", U32, Value::Const($a)),
                sub(3, "Mapped object 3", U32, Value::Const($b)),
                sub(4, "Mapped object 4", U32, Value::Const($c)),
            ],
        }
    };
}

/// RPDO `$k`'s mapping at 0x1600 + k: observation values 3k+1..3k+3 of 0x2100.
macro_rules! rpdo_map {
    ($k:literal, $n:literal) => {
        pdo_map!(
            0x1600 + $k,
            concat!("RPDO ", $n, " mapping parameter"),
            OBSERVATION_E2E,
            $k,
            [
                observation_entry($k, 0),
                observation_entry($k, 1),
                observation_entry($k, 2)
            ]
        )
    };
}

/// TPDO `$k`'s mapping at 0x1A00 + k (action frames): action values 3k+1..3k+3 of 0x2200.
macro_rules! action_map {
    ($k:literal, $n:literal) => {
        pdo_map!(
            0x1A00 + $k,
            concat!("TPDO ", $n, " mapping parameter"),
            TPDO_E2E,
            $k,
            [
                map_entry(ACTION_VALUES, 3 * $k + 1, 16),
                map_entry(ACTION_VALUES, 3 * $k + 2, 16),
                map_entry(ACTION_VALUES, 3 * $k + 3, 16)
            ]
        )
    };
}

/// An array of live values: sub-index 0 their count, then `$prefix 1`, `$prefix 2`, ...
macro_rules! live_array {
    ($index:expr, $name:expr, $prefix:literal, $ty:expr, [$($i:literal),+]) => {
        Object {
            index: $index,
            name: $name,
            kind: ObjectKind::Array,
            subs: &[
                sub(0, "Highest sub-index supported", U8, Value::Const([$($i),+].len() as u32)),
                $(sub($i, concat!($prefix, " ", $i), $ty, Value::Live),)+
            ],
        }
    };
}

/// Mapping entry `slot` (0..3) of observation frame `k`: observation value 3k + slot + 1 of
/// 0x2100, or the dummy INTEGER16 past the last value.
const fn observation_entry(k: u8, slot: u8) -> u32 {
    let value = 3 * k + slot + 1;
    if (value as usize) <= OBS_DIM {
        map_entry(OBSERVATION_VALUES, value, 16)
    } else {
        map_entry(DUMMY_INTEGER16, 0, 16)
    }
}

/// TPDO 3's mapping (policy information), the same in both layouts.
const POLICY_INFO_MAP: Object = Object {
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
};

/// TPDO 4's mapping (status), the same in both layouts.
const STATUS_MAP: Object = Object {
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
};

/// 0x2100, the same in both layouts.
const OBSERVATION_VALUES_ARRAY: Object = live_array!(
    OBSERVATION_VALUES,
    "Observation values",
    "Observation value",
    I16,
    [
        1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25,
        26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 37, 38, 39, 40, 41, 42, 43, 44
    ]
);

/// 0x2200, the same in both layouts.
const ACTION_VALUES_ARRAY: Object = live_array!(
    ACTION_VALUES,
    "Action values",
    "Action value",
    I16,
    [1, 2, 3, 4, 5, 6, 7, 8, 9]
);

/// 0x2201, the same in both layouts (in the FD layout sub-indices 2 and 3 stay 0: no TPDO 1-2).
const TPDO_E2E_ARRAY: Object = live_array!(
    TPDO_E2E,
    "TPDO E2E headers",
    "TPDO E2E header",
    U16,
    [1, 2, 3, 4, 5]
);

/// The PDO communication and mapping objects and the manufacturer objects they map, in index
/// order (the table above). Identifiers come from [`rpdo_cob_id`] / [`tpdo_cob_id`] for node 0
/// (the EDS's `$NODEID` offsets), mappings from the frame layout: nothing here is copied by hand.
pub const OBJECTS: [Object; 44] = [
    rpdo_comm!(0, 1),
    rpdo_comm!(1, 2),
    rpdo_comm!(2, 3),
    rpdo_comm!(3, 4),
    rpdo_comm!(4, 5),
    rpdo_comm!(5, 6),
    rpdo_comm!(6, 7),
    rpdo_comm!(7, 8),
    rpdo_comm!(8, 9),
    rpdo_comm!(9, 10),
    rpdo_comm!(10, 11),
    rpdo_comm!(11, 12),
    rpdo_comm!(12, 13),
    rpdo_comm!(13, 14),
    rpdo_comm!(14, 15),
    rpdo_map!(0, 1),
    rpdo_map!(1, 2),
    rpdo_map!(2, 3),
    rpdo_map!(3, 4),
    rpdo_map!(4, 5),
    rpdo_map!(5, 6),
    rpdo_map!(6, 7),
    rpdo_map!(7, 8),
    rpdo_map!(8, 9),
    rpdo_map!(9, 10),
    rpdo_map!(10, 11),
    rpdo_map!(11, 12),
    rpdo_map!(12, 13),
    rpdo_map!(13, 14),
    rpdo_map!(14, 15),
    tpdo_comm!(0, 1),
    tpdo_comm!(1, 2),
    tpdo_comm!(2, 3),
    tpdo_comm!(3, 4),
    tpdo_comm!(4, 5),
    action_map!(0, 1),
    action_map!(1, 2),
    action_map!(2, 3),
    POLICY_INFO_MAP,
    STATUS_MAP,
    OBSERVATION_VALUES_ARRAY,
    live_array!(
        OBSERVATION_E2E,
        "Observation E2E headers",
        "Observation frame E2E header",
        U16,
        [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15]
    ),
    ACTION_VALUES_ARRAY,
    TPDO_E2E_ARRAY,
];

/// A mapping record whose entry at sub-index `i` (the listed ones, 1..n) is `$entry($k, i)`.
macro_rules! map_record {
    ($index:expr, $name:expr, $entry:ident, $k:expr, [$($i:literal),+]) => {
        Object {
            index: $index,
            name: $name,
            kind: ObjectKind::Record,
            subs: &[
                sub(0, "Number of mapped objects", U8, Value::Const([$($i),+].len() as u32)),
                $(sub($i, concat!("Mapped object ", $i), U32, Value::Const($entry($k, $i))),)+
            ],
        }
    };
}

/// Mapping entry `i` (1..=24) of FD observation frame `k`: the frame's E2E header (0x2101:k+1),
/// then its values 22k+1.. of 0x2100 (two bytes each, as [`crate::can::fd_messages`] writes them
/// after the header), the dummy INTEGER16 for the padding past the last value.
const fn fd_observation_entry(k: u8, i: u8) -> u32 {
    if i == 1 {
        return map_entry(OBSERVATION_E2E, k + 1, 16);
    }
    let slot = (i - 2) as usize;
    let value = k as usize * FD_VALUES_PER_OBS_FRAME + slot;
    if slot < FD_VALUES_PER_OBS_FRAME && value < OBS_DIM {
        map_entry(OBSERVATION_VALUES, value as u8 + 1, 16)
    } else {
        map_entry(DUMMY_INTEGER16, 0, 16)
    }
}

/// Mapping entry `i` (1..=10) of the FD action frame (TPDO 0): its E2E header (0x2201:1), then
/// the action values of 0x2200.
const fn fd_action_entry(_k: u8, i: u8) -> u32 {
    if i == 1 {
        return map_entry(TPDO_E2E, 1, 16);
    }
    if (i as usize - 1) <= ACT_DIM {
        map_entry(ACTION_VALUES, i - 1, 16)
    } else {
        map_entry(DUMMY_INTEGER16, 0, 16)
    }
}

/// FD RPDO `$k`'s mapping at 0x1600 + k: 24 entries of 16 bits, the 48 bytes of the frame.
macro_rules! fd_rpdo_map {
    ($k:literal, $n:literal) => {
        map_record!(
            0x1600 + $k,
            concat!("RPDO ", $n, " mapping parameter"),
            fd_observation_entry,
            $k,
            [
                1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23,
                24
            ]
        )
    };
}

/// The bits a PDO mapping record maps: the sum of its entries' lengths (sub-indices 1..).
const fn mapped_bits(object: &Object) -> u32 {
    let mut bits = 0;
    let mut s = 1;
    while s < object.subs.len() {
        if let Value::Const(entry) = object.subs[s].value {
            bits += entry & 0xFF;
        }
        s += 1;
    }
    bits
}

/// FD RPDO 0's mapping.
const FD_RPDO_MAP_0: Object = fd_rpdo_map!(0, 1);
/// FD RPDO 1's mapping.
const FD_RPDO_MAP_1: Object = fd_rpdo_map!(1, 2);
/// The FD action frame's mapping (TPDO 0).
const FD_ACTION_MAP: Object = map_record!(
    0x1A00,
    "TPDO 1 mapping parameter",
    fd_action_entry,
    0,
    [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]
);

// The FD mappings are exactly as long as the FD frames.
const _: () = assert!(mapped_bits(&FD_RPDO_MAP_0) as usize == 8 * FD_OBS_LEN);
const _: () = assert!(mapped_bits(&FD_RPDO_MAP_1) as usize == 8 * FD_OBS_LEN);
const _: () = assert!(mapped_bits(&FD_ACTION_MAP) as usize == 8 * FD_ACTION_LEN);

/// The PDO objects of the FD layout ([`crate::can::fd_messages`]), in index order (the FD table
/// above): the two FD observation RPDOs, the FD action TPDO, the classic policy-information and
/// status TPDOs and the objects they map. Identifiers and mappings come from the same functions
/// and constants as the codec's.
pub const FD_OBJECTS: [Object; 14] = [
    rpdo_comm!(0, 1),
    rpdo_comm!(1, 2),
    FD_RPDO_MAP_0,
    FD_RPDO_MAP_1,
    tpdo_comm!(0, 1),
    tpdo_comm!(3, 4),
    tpdo_comm!(4, 5),
    FD_ACTION_MAP,
    POLICY_INFO_MAP,
    STATUS_MAP,
    OBSERVATION_VALUES_ARRAY,
    live_array!(
        OBSERVATION_E2E,
        "Observation E2E headers",
        "Observation frame E2E header",
        U16,
        [1, 2]
    ),
    ACTION_VALUES_ARRAY,
    TPDO_E2E_ARRAY,
];

/// The PDO objects of a controller in `layout`: what its SDO server serves and its EDS lists.
pub const fn objects(layout: FrameLayout) -> &'static [Object] {
    match layout {
        FrameLayout::Classic => &OBJECTS,
        FrameLayout::Fd => &FD_OBJECTS,
    }
}
