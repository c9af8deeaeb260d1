//! The object dictionary as the SDO server sees it: objects addressed by index and sub-index,
//! read in chunks and written as a stream, so that a 300 kB program (object 0x1F50) goes straight
//! into a policy slot without a buffer of its size.

use super::abort::SdoAbort;

/// What an SDO client may do with an object.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Read only (`ro`, or `const`).
    ReadOnly,
    /// Write only (`wo`): program data, program control.
    WriteOnly,
    /// Read and write (`rw`).
    ReadWrite,
}

impl Access {
    /// Whether an upload (read) is allowed.
    pub const fn readable(self) -> bool {
        matches!(self, Access::ReadOnly | Access::ReadWrite)
    }

    /// Whether a download (write) is allowed.
    pub const fn writable(self) -> bool {
        matches!(self, Access::WriteOnly | Access::ReadWrite)
    }
}

/// One object (index, sub-index) as the server needs to know it before a transfer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Entry {
    /// Access.
    pub access: Access,
    /// Bytes of the value: fixed for basic types, the current length for a visible string, and
    /// the most a domain may take (`None`: no fixed size, e.g. a domain written by streaming).
    pub size: Option<u32>,
    /// Whether a write must have exactly `size` bytes (basic types) rather than at most.
    pub exact: bool,
}

/// The device's objects. The SDO server ([`super::sdo::SdoServer`]) calls these in order: for a
/// download `entry`, `begin_write`, `write` for each chunk (offsets increasing, no gaps), then
/// `end_write` or `abort_write`; for an upload `entry`, then `read` at increasing offsets.
pub trait ObjectDictionary {
    /// The object's access and size, or why it cannot be reached
    /// ([`SdoAbort::NoObject`], [`SdoAbort::NoSubIndex`]).
    fn entry(&self, index: u16, sub: u8) -> Result<Entry, SdoAbort>;

    /// Copies up to `buf.len()` bytes of the value from byte `offset` into `buf`; returns how many
    /// (0 at the end).
    fn read(&mut self, index: u16, sub: u8, offset: u32, buf: &mut [u8])
    -> Result<usize, SdoAbort>;

    /// A download of `size` bytes (when the client said) begins.
    fn begin_write(&mut self, index: u16, sub: u8, size: Option<u32>) -> Result<(), SdoAbort>;

    /// Bytes `offset..offset + data.len()` of the value being written.
    fn write(&mut self, index: u16, sub: u8, offset: u32, data: &[u8]) -> Result<(), SdoAbort>;

    /// The download ended after `total` bytes: check and commit the value.
    fn end_write(&mut self, index: u16, sub: u8, total: u32) -> Result<(), SdoAbort>;

    /// The download was aborted (by either side, or timed out): drop what was written.
    fn abort_write(&mut self, index: u16, sub: u8);
}

/// Copies the part of `value` from byte `offset` on into `buf` (as much as fits); returns how many
/// bytes: the [`ObjectDictionary::read`] of an object whose whole value is at hand.
pub fn read_value(value: &[u8], offset: u32, buf: &mut [u8]) -> usize {
    let rest = value.get(offset as usize..).unwrap_or(&[]);
    let n = rest.len().min(buf.len());
    buf[..n].copy_from_slice(&rest[..n]);
    n
}

/// CiA 301 data type of an object, as the dictionary serves it and the EDS lists it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataType {
    /// INTEGER16 (0x0003): a raw signal value.
    Integer16,
    /// UNSIGNED8 (0x0005).
    Unsigned8,
    /// UNSIGNED16 (0x0006).
    Unsigned16,
    /// UNSIGNED32 (0x0007).
    Unsigned32,
    /// DOMAIN (0x000F): bytes of any length, streamed.
    Domain,
}

impl DataType {
    /// The CiA 301 data type index (the EDS's `DataType`).
    pub const fn code(self) -> u16 {
        match self {
            DataType::Integer16 => 0x0003,
            DataType::Unsigned8 => 0x0005,
            DataType::Unsigned16 => 0x0006,
            DataType::Unsigned32 => 0x0007,
            DataType::Domain => 0x000F,
        }
    }

    /// Bytes of a value (`None` for a domain).
    pub const fn size(self) -> Option<u32> {
        match self {
            DataType::Unsigned8 => Some(1),
            DataType::Integer16 => Some(2),
            DataType::Unsigned16 => Some(2),
            DataType::Unsigned32 => Some(4),
            DataType::Domain => None,
        }
    }
}

/// Where a sub-object's value comes from, for a description of the dictionary (an EDS).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Value {
    /// Always this value (a sub-index 0 count, the device type).
    Const(u32),
    /// Kept by the dictionary, starting from the device's configuration (identity, heartbeat
    /// time): the EDS default is the value after boot of the default configuration.
    Stored,
    /// Read from the controller or the slots at the time of the request (no static default).
    Live,
    /// This value plus the node id (a COB-ID): `$NODEID+value` in the EDS.
    NodeId(u32),
}

/// How the sub-objects of an object are organised (CiA 301 object code).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjectKind {
    /// A single value at sub-index 0 (VAR, object code 0x7).
    Var,
    /// Sub-index 0 the count, the others of one type (ARRAY, 0x8).
    Array,
    /// Sub-index 0 the count, the others of any type (RECORD, 0x9).
    Record,
}

impl ObjectKind {
    /// The CiA 301 object code (the EDS's `ObjectType`).
    pub const fn code(self) -> u8 {
        match self {
            ObjectKind::Var => 0x7,
            ObjectKind::Array => 0x8,
            ObjectKind::Record => 0x9,
        }
    }
}

/// One sub-object of the dictionary's static description.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SubObject {
    /// Sub-index.
    pub sub: u8,
    /// Name (the EDS's `ParameterName`).
    pub name: &'static str,
    /// Data type.
    pub data_type: DataType,
    /// Access.
    pub access: Access,
    /// Where the value comes from.
    pub value: Value,
}

/// One object of the dictionary's static description: what the SDO server serves (its
/// [`ObjectDictionary::entry`] reads access and size here) and what the EDS lists.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Object {
    /// Index.
    pub index: u16,
    /// Name (the EDS's `ParameterName`).
    pub name: &'static str,
    /// Object code.
    pub kind: ObjectKind,
    /// Sub-objects in sub-index order (a VAR has one, at sub-index 0).
    pub subs: &'static [SubObject],
}

/// A sub-object of `objects`: [`SdoAbort::NoObject`] when no object has `index`,
/// [`SdoAbort::NoSubIndex`] when it has no `sub`.
pub fn find(objects: &[Object], index: u16, sub: u8) -> Result<&SubObject, SdoAbort> {
    let object = objects
        .iter()
        .find(|o| o.index == index)
        .ok_or(SdoAbort::NoObject)?;
    object
        .subs
        .iter()
        .find(|s| s.sub == sub)
        .ok_or(SdoAbort::NoSubIndex)
}

/// The [`Entry`] of a described sub-object of a basic type (exact size).
pub const fn basic_entry(sub: &SubObject) -> Entry {
    Entry {
        access: sub.access,
        size: sub.data_type.size(),
        exact: true,
    }
}
