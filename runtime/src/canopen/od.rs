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
