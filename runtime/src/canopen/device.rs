//! The controller's communication and manufacturer objects (CiA 301), and the whole dictionary
//! the SDO server serves: these objects, then program download ([`super::program`]).
//!
//! | index | sub | object | type | access |
//! |---|---|---|---|---|
//! | 0x1000 | 0 | device type (no CiA device profile: 0) | u32 | ro |
//! | 0x1001 | 0 | error register (bit 0 generic, bit 4 communication, bit 7 manufacturer) | u8 | ro |
//! | 0x1003 | 0 | pre-defined error field: number of errors (write 0 to clear) | u8 | rw |
//! | 0x1003 | 1..=8 | the emergency codes sent, newest first (code u16, fault code in bits 16-23) | u32 | ro |
//! | 0x1017 | 0 | producer heartbeat time, ms | u16 | rw |
//! | 0x1018 | 0..=4 | identity: 4, vendor id, product code, revision, serial number | u8, u32 | ro |
//! | 0x1029 | 0..=1 | error behaviour: 1; communication error (0 pre-operational, 1 no change, 2 stopped) | u8 | ro, rw |
//! | 0x2000 | 0..=5 | active policy: 5; layout hash u32, format version u8, file CRC u32, task u8, slot generation u32 | | ro |
//! | 0x2001 | 0 | safety envelope status (the envelope's status byte) | u8 | ro |
//! | 0x2002 | 0..=2 | controller status: 2; controller state u8, fault code u8 | | ro |
//!
//! and the PDO objects of the controller's frame layout ([`super::pdo::objects`]: 0x1400..,
//! 0x1600.., 0x1800.., 0x1A00.., and the mapped observation and action values and E2E headers
//! 0x2100, 0x2101, 0x2200, 0x2201; classic or CAN FD, [`DeviceHost::layout`]).
//!
//! Values the controller owns (its state, its policy, the envelope) are read through
//! [`DeviceHost`]; what the dictionary owns (heartbeat time, error history, error behaviour) is in
//! [`DeviceState`].

use super::abort::SdoAbort;
use super::od::{
    Access, DataType, Entry, Object, ObjectDictionary, ObjectKind, SubObject, Value, basic_entry,
    find, read_value,
};
use super::pdo;
use super::program::{ProgramHost, ProgramObjects, is_program_object};
use crate::can::layout::FrameLayout;

/// Most emergency codes kept in 0x1003.
pub const ERROR_HISTORY: usize = 8;

const fn sub(
    sub: u8,
    name: &'static str,
    data_type: DataType,
    access: Access,
    value: Value,
) -> SubObject {
    SubObject {
        sub,
        name,
        data_type,
        access,
        value,
    }
}

const fn error_field(n: u8, name: &'static str) -> SubObject {
    sub(n, name, DataType::Unsigned32, Access::ReadOnly, Value::Live)
}

const U8: DataType = DataType::Unsigned8;
const U16: DataType = DataType::Unsigned16;
const U32: DataType = DataType::Unsigned32;
const RO: Access = Access::ReadOnly;
const RW: Access = Access::ReadWrite;

/// The communication and manufacturer objects the dictionary serves (the table above): access
/// and size of every request come from here ([`ObjectDictionary::entry`]), and `can/jaco.eds`
/// is generated from it (with [`super::program::OBJECTS`]).
pub const OBJECTS: [Object; 9] = [
    Object {
        index: 0x1000,
        name: "Device type",
        kind: ObjectKind::Var,
        subs: &[sub(0, "Device type", U32, RO, Value::Const(0))],
    },
    Object {
        index: 0x1001,
        name: "Error register",
        kind: ObjectKind::Var,
        subs: &[sub(0, "Error register", U8, RO, Value::Live)],
    },
    Object {
        index: 0x1003,
        name: "Pre-defined error field",
        kind: ObjectKind::Array,
        subs: &[
            sub(0, "Number of errors", U8, RW, Value::Stored),
            error_field(1, "Standard error field 1"),
            error_field(2, "Standard error field 2"),
            error_field(3, "Standard error field 3"),
            error_field(4, "Standard error field 4"),
            error_field(5, "Standard error field 5"),
            error_field(6, "Standard error field 6"),
            error_field(7, "Standard error field 7"),
            error_field(8, "Standard error field 8"),
        ],
    },
    Object {
        index: 0x1017,
        name: "Producer heartbeat time",
        kind: ObjectKind::Var,
        subs: &[sub(0, "Producer heartbeat time", U16, RW, Value::Stored)],
    },
    Object {
        index: 0x1018,
        name: "Identity object",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, RO, Value::Const(4)),
            sub(1, "Vendor-ID", U32, RO, Value::Stored),
            sub(2, "Product code", U32, RO, Value::Stored),
            sub(3, "Revision number", U32, RO, Value::Stored),
            sub(4, "Serial number", U32, RO, Value::Stored),
        ],
    },
    Object {
        index: 0x1029,
        name: "Error behaviour",
        kind: ObjectKind::Array,
        subs: &[
            sub(0, "Highest sub-index supported", U8, RO, Value::Const(1)),
            sub(1, "Communication error", U8, RW, Value::Stored),
        ],
    },
    Object {
        index: 0x2000,
        name: "Active policy",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, RO, Value::Const(5)),
            sub(1, "Layout hash", U32, RO, Value::Live),
            sub(2, "Format version", U8, RO, Value::Live),
            sub(3, "File CRC-32", U32, RO, Value::Live),
            sub(4, "Task", U8, RO, Value::Live),
            sub(5, "Slot generation", U32, RO, Value::Live),
        ],
    },
    Object {
        index: 0x2001,
        name: "Envelope status",
        kind: ObjectKind::Var,
        subs: &[sub(0, "Envelope status", U8, RO, Value::Live)],
    },
    Object {
        index: 0x2002,
        name: "Controller status",
        kind: ObjectKind::Record,
        subs: &[
            sub(0, "Highest sub-index supported", U8, RO, Value::Const(2)),
            sub(1, "Controller state", U8, RO, Value::Live),
            sub(2, "Fault code", U8, RO, Value::Live),
        ],
    },
];

/// The identity the node reports in 0x1018.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Identity {
    /// Vendor id (CiA-assigned; 0 for none).
    pub vendor: u32,
    /// Product code.
    pub product: u32,
    /// Revision number (major in the high 16 bits, minor in the low).
    pub revision: u32,
    /// Serial number.
    pub serial: u32,
}

impl Default for Identity {
    fn default() -> Self {
        Identity {
            vendor: 0,
            product: 0x4458_4A43, // "DXJC"
            revision: 0x0001_0000,
            serial: 0,
        }
    }
}

/// What the controller knows of its active policy (0x2000; the file's CRC and slot generation
/// come from the slots).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ActivePolicy {
    /// Layout hash of the file.
    pub layout_hash: u32,
    /// Format version.
    pub format_version: u16,
    /// Task code (order of `dex_policy::Task`).
    pub task: u8,
}

/// What the communication objects read from the controller.
pub trait DeviceHost {
    /// The error register (0x1001).
    fn error_register(&self) -> u8;
    /// The active policy, if any.
    fn active_policy(&self) -> Option<ActivePolicy>;
    /// The safety envelope's status byte (0x2001).
    fn envelope_status(&self) -> u8;
    /// The controller state's code (0x2002:1: 0 boot, 1 pre-operational, 2 operational,
    /// 3 safe-stop, 4 fault).
    fn controller_state(&self) -> u8;
    /// The latched fault code (0x2002:2; 0: none).
    fn fault_code(&self) -> u8;
    /// The node id (the COB-IDs of the PDO communication objects).
    fn node_id(&self) -> u8;
    /// The frame layout of the observation and the action: which PDO objects the dictionary
    /// serves ([`pdo::objects`]).
    fn layout(&self) -> FrameLayout;
    /// Raw value `index` of the last complete observation (0x2100:index+1).
    fn observation_raw(&self, index: usize) -> i16;
    /// Raw value `index` of the last action sent (0x2200:index+1).
    fn action_raw(&self, index: usize) -> i16;
    /// Bytes 0-1 (CRC, counter and sample nibble; little-endian) of the last accepted
    /// observation frame `k` (0x2101:k+1; 0 before one).
    fn observation_header(&self, k: usize) -> u16;
    /// Bytes 0-1 of the last frame sent on TPDO `k` (0x2201:k+1; 0 before one).
    fn tpdo_header(&self, k: usize) -> u16;
}

/// A sub-object of the dictionary's basic objects: [`OBJECTS`], then the PDO objects of
/// `layout`.
fn find_basic(layout: FrameLayout, index: u16, sub: u8) -> Result<&'static SubObject, SdoAbort> {
    match find(&OBJECTS, index, sub) {
        Err(SdoAbort::NoObject) => find(pdo::objects(layout), index, sub),
        other => other,
    }
}

/// What the dictionary keeps between requests.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceState {
    /// Identity (0x1018).
    pub identity: Identity,
    /// Producer heartbeat time in ms (0x1017; 0: no heartbeat).
    pub heartbeat_ms: u16,
    /// Communication error behaviour (0x1029:1).
    pub error_behaviour: u8,
    history: heapless::Deque<u32, ERROR_HISTORY>,
}

impl DeviceState {
    /// A state with `identity`, a heartbeat every `heartbeat_ms`, errors leading to
    /// pre-operational.
    pub fn new(identity: Identity, heartbeat_ms: u16) -> Self {
        DeviceState {
            identity,
            heartbeat_ms,
            error_behaviour: 0,
            history: heapless::Deque::new(),
        }
    }

    /// Records an emergency sent (newest first in 0x1003; the oldest is dropped when full).
    pub fn record_emergency(&mut self, code: u16, fault: u8) {
        if self.history.is_full() {
            let _ = self.history.pop_back();
        }
        let _ = self
            .history
            .push_front(u32::from(code) | (u32::from(fault) << 16));
    }

    /// The value of a [`Value::Stored`] object of [`OBJECTS`] (`None` for any other): what the
    /// dictionary keeps, read by the server and, for the default state, written into the EDS.
    pub fn stored(&self, index: u16, sub: u8) -> Option<u32> {
        let id = &self.identity;
        match (index, sub) {
            (0x1003, 0) => Some(self.history.len() as u32),
            (0x1017, 0) => Some(u32::from(self.heartbeat_ms)),
            (0x1018, 1) => Some(id.vendor),
            (0x1018, 2) => Some(id.product),
            (0x1018, 3) => Some(id.revision),
            (0x1018, 4) => Some(id.serial),
            (0x1029, 1) => Some(u32::from(self.error_behaviour)),
            _ => None,
        }
    }

    /// The recorded emergencies, newest first.
    pub fn errors(&self) -> impl Iterator<Item = u32> + '_ {
        self.history.iter().copied()
    }
}

/// The node's whole dictionary for one SDO request: the communication and manufacturer objects,
/// then program download.
pub struct DeviceObjects<'a, 'r, H: DeviceHost + ProgramHost> {
    /// What the dictionary keeps.
    pub state: &'a mut DeviceState,
    /// Program download over the slots and the controller.
    pub program: ProgramObjects<'a, 'r, H>,
    /// A pending 1-2 byte write (heartbeat time, error behaviour, error history), applied at its end.
    pending: [u8; 2],
}

impl<'a, 'r, H: DeviceHost + ProgramHost> DeviceObjects<'a, 'r, H> {
    /// The dictionary over `state` and `program`.
    pub fn new(state: &'a mut DeviceState, program: ProgramObjects<'a, 'r, H>) -> Self {
        DeviceObjects {
            state,
            program,
            pending: [0; 2],
        }
    }

    fn host(&self) -> &H {
        &*self.program.host
    }

    /// The value of a basic object as little-endian bytes and its length.
    fn value(&self, index: u16, sub: u8) -> Result<([u8; 4], usize), SdoAbort> {
        let desc = find_basic(self.host().layout(), index, sub)?;
        let len = desc.data_type.size().unwrap_or(4) as usize;
        let v = match desc.value {
            Value::Const(v) => v,
            Value::NodeId(base) => base + u32::from(self.host().node_id()),
            Value::Stored => self.state.stored(index, sub).ok_or(SdoAbort::NoData)?,
            Value::Live => self.live(index, sub)?,
        };
        Ok((v.to_le_bytes(), len))
    }

    /// The value of a [`Value::Live`] object.
    fn live(&self, index: u16, sub: u8) -> Result<u32, SdoAbort> {
        let policy = self.host().active_policy().unwrap_or_default();
        match (index, sub) {
            (0x1001, 0) => Ok(u32::from(self.host().error_register())),
            (0x1003, s) if s >= 1 => self
                .state
                .errors()
                .nth(usize::from(s) - 1)
                .ok_or(SdoAbort::NoData),
            (0x2000, 1) => Ok(policy.layout_hash),
            (0x2000, 2) => Ok(u32::from(policy.format_version)),
            (0x2000, 3) => Ok(self.program.slots.active_crc()),
            (0x2000, 4) => Ok(u32::from(policy.task)),
            (0x2000, 5) => Ok(self.program.slots.active().map_or(0, |f| f.generation)),
            (0x2001, 0) => Ok(u32::from(self.host().envelope_status())),
            (0x2002, 1) => Ok(u32::from(self.host().controller_state())),
            (0x2002, 2) => Ok(u32::from(self.host().fault_code())),
            (pdo::OBSERVATION_VALUES, s) if s >= 1 => Ok(u32::from(
                self.host().observation_raw(usize::from(s) - 1) as u16,
            )),
            (pdo::ACTION_VALUES, s) if s >= 1 => {
                Ok(u32::from(self.host().action_raw(usize::from(s) - 1) as u16))
            }
            (pdo::OBSERVATION_E2E, s) if s >= 1 => Ok(u32::from(
                self.host().observation_header(usize::from(s) - 1),
            )),
            (pdo::TPDO_E2E, s) if s >= 1 => {
                Ok(u32::from(self.host().tpdo_header(usize::from(s) - 1)))
            }
            _ => Err(SdoAbort::NoData),
        }
    }
}

impl<H: DeviceHost + ProgramHost> ObjectDictionary for DeviceObjects<'_, '_, H> {
    fn entry(&self, index: u16, sub: u8) -> Result<Entry, SdoAbort> {
        if is_program_object(index) {
            return self.program.entry(index, sub);
        }
        // An empty slot of the error history exists too (it reads as "no data").
        Ok(basic_entry(find_basic(self.host().layout(), index, sub)?))
    }

    fn read(
        &mut self,
        index: u16,
        sub: u8,
        offset: u32,
        buf: &mut [u8],
    ) -> Result<usize, SdoAbort> {
        if is_program_object(index) {
            return self.program.read(index, sub, offset, buf);
        }
        let (bytes, len) = self.value(index, sub)?;
        Ok(read_value(&bytes[..len], offset, buf))
    }

    fn begin_write(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort> {
        if is_program_object(index) {
            return self.program.begin_write(index, sub, size);
        }
        self.pending = [0; 2];
        Ok(())
    }

    fn write(&mut self, index: u16, sub: u8, offset: u32, data: &[u8]) -> Result<(), SdoAbort> {
        if is_program_object(index) {
            return self.program.write(index, sub, offset, data);
        }
        for (k, b) in data.iter().enumerate() {
            if let Some(slot) = self.pending.get_mut(offset as usize + k) {
                *slot = *b;
            }
        }
        Ok(())
    }

    fn end_write(&mut self, index: u16, sub: u8, total: u32) -> Result<(), SdoAbort> {
        if is_program_object(index) {
            return self.program.end_write(index, sub, total);
        }
        match (index, sub) {
            (0x1003, 0) if self.pending[0] == 0 => {
                self.state.history.clear();
                Ok(())
            }
            (0x1003, 0) => Err(SdoAbort::InvalidValue),
            (0x1017, 0) => {
                self.state.heartbeat_ms = u16::from_le_bytes(self.pending);
                Ok(())
            }
            (0x1029, 1) if self.pending[0] <= 2 => {
                self.state.error_behaviour = self.pending[0];
                Ok(())
            }
            (0x1029, 1) => Err(SdoAbort::ValueTooHigh),
            _ => Err(SdoAbort::ReadOnly),
        }
    }

    fn abort_write(&mut self, index: u16, sub: u8) {
        if is_program_object(index) {
            self.program.abort_write(index, sub);
        }
    }
}
