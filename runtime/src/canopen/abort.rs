//! SDO abort codes (CiA 301, the table of SDO abort codes): the one answer to every refusal.

/// Why an SDO transfer was refused or ended, as its 4-byte abort code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum SdoAbort {
    /// 0x0503_0000: toggle bit not alternated.
    ToggleBit,
    /// 0x0504_0000: SDO protocol timed out.
    Timeout,
    /// 0x0504_0001: client/server command specifier not valid or unknown.
    UnknownCommand,
    /// 0x0504_0002: invalid block size (block mode only).
    InvalidBlockSize,
    /// 0x0504_0003: invalid sequence number (block mode only).
    InvalidSequence,
    /// 0x0504_0004: CRC error (block mode only).
    Crc,
    /// 0x0504_0005: out of memory.
    OutOfMemory,
    /// 0x0601_0000: unsupported access to an object.
    UnsupportedAccess,
    /// 0x0601_0001: attempt to read a write-only object.
    WriteOnly,
    /// 0x0601_0002: attempt to write a read-only object.
    ReadOnly,
    /// 0x0602_0000: object does not exist in the object dictionary.
    NoObject,
    /// 0x0606_0000: access failed due to a hardware error (a slot region that cannot be written).
    Hardware,
    /// 0x0607_0010: data type does not match, length of service parameter does not match.
    LengthMismatch,
    /// 0x0607_0012: data type does not match, length of service parameter too high.
    TooLong,
    /// 0x0607_0013: data type does not match, length of service parameter too low.
    TooShort,
    /// 0x0609_0011: sub-index does not exist.
    NoSubIndex,
    /// 0x0609_0030: invalid value for parameter (download only).
    InvalidValue,
    /// 0x0609_0031: value of parameter written too high.
    ValueTooHigh,
    /// 0x0609_0032: value of parameter written too low.
    ValueTooLow,
    /// 0x0800_0000: general error.
    General,
    /// 0x0800_0020: data cannot be transferred or stored to the application (a program that
    /// fails verification).
    CannotStore,
    /// 0x0800_0021: ... because of local control.
    LocalControl,
    /// 0x0800_0022: ... because of the present device state (e.g. a program download while
    /// operational).
    DeviceState,
    /// 0x0800_0024: no data available (start with no staged program, roll-back with no previous).
    NoData,
}

impl SdoAbort {
    /// The abort code on the wire.
    pub const fn code(self) -> u32 {
        match self {
            SdoAbort::ToggleBit => 0x0503_0000,
            SdoAbort::Timeout => 0x0504_0000,
            SdoAbort::UnknownCommand => 0x0504_0001,
            SdoAbort::InvalidBlockSize => 0x0504_0002,
            SdoAbort::InvalidSequence => 0x0504_0003,
            SdoAbort::Crc => 0x0504_0004,
            SdoAbort::OutOfMemory => 0x0504_0005,
            SdoAbort::UnsupportedAccess => 0x0601_0000,
            SdoAbort::WriteOnly => 0x0601_0001,
            SdoAbort::ReadOnly => 0x0601_0002,
            SdoAbort::NoObject => 0x0602_0000,
            SdoAbort::Hardware => 0x0606_0000,
            SdoAbort::LengthMismatch => 0x0607_0010,
            SdoAbort::TooLong => 0x0607_0012,
            SdoAbort::TooShort => 0x0607_0013,
            SdoAbort::NoSubIndex => 0x0609_0011,
            SdoAbort::InvalidValue => 0x0609_0030,
            SdoAbort::ValueTooHigh => 0x0609_0031,
            SdoAbort::ValueTooLow => 0x0609_0032,
            SdoAbort::General => 0x0800_0000,
            SdoAbort::CannotStore => 0x0800_0020,
            SdoAbort::LocalControl => 0x0800_0021,
            SdoAbort::DeviceState => 0x0800_0022,
            SdoAbort::NoData => 0x0800_0024,
        }
    }

    /// What the code means (the wording of CiA 301's table, shortened).
    pub const fn description(self) -> &'static str {
        match self {
            SdoAbort::ToggleBit => "toggle bit not alternated",
            SdoAbort::Timeout => "SDO protocol timed out",
            SdoAbort::UnknownCommand => "client/server command specifier not valid or unknown",
            SdoAbort::InvalidBlockSize => "invalid block size",
            SdoAbort::InvalidSequence => "invalid sequence number",
            SdoAbort::Crc => "CRC error",
            SdoAbort::OutOfMemory => "out of memory",
            SdoAbort::UnsupportedAccess => "unsupported access to an object",
            SdoAbort::WriteOnly => "attempt to read a write-only object",
            SdoAbort::ReadOnly => "attempt to write a read-only object",
            SdoAbort::NoObject => "object does not exist in the object dictionary",
            SdoAbort::Hardware => "access failed due to a hardware error",
            SdoAbort::LengthMismatch => "length of service parameter does not match",
            SdoAbort::TooLong => "length of service parameter too high",
            SdoAbort::TooShort => "length of service parameter too low",
            SdoAbort::NoSubIndex => "sub-index does not exist",
            SdoAbort::InvalidValue => "invalid value for parameter",
            SdoAbort::ValueTooHigh => "value of parameter written too high",
            SdoAbort::ValueTooLow => "value of parameter written too low",
            SdoAbort::General => "general error",
            SdoAbort::CannotStore => "data cannot be transferred or stored to the application",
            SdoAbort::LocalControl => {
                "data cannot be transferred or stored to the application because of local control"
            }
            SdoAbort::DeviceState => {
                "data cannot be transferred or stored to the application because of the present \
                 device state"
            }
            SdoAbort::NoData => "no data available",
        }
    }

    /// The abort with wire code `code`, if it is one of these.
    pub fn from_code(code: u32) -> Option<SdoAbort> {
        ALL.into_iter().find(|a| a.code() == code)
    }
}

/// Every abort, for [`SdoAbort::from_code`].
const ALL: [SdoAbort; 24] = [
    SdoAbort::ToggleBit,
    SdoAbort::Timeout,
    SdoAbort::UnknownCommand,
    SdoAbort::InvalidBlockSize,
    SdoAbort::InvalidSequence,
    SdoAbort::Crc,
    SdoAbort::OutOfMemory,
    SdoAbort::UnsupportedAccess,
    SdoAbort::WriteOnly,
    SdoAbort::ReadOnly,
    SdoAbort::NoObject,
    SdoAbort::Hardware,
    SdoAbort::LengthMismatch,
    SdoAbort::TooLong,
    SdoAbort::TooShort,
    SdoAbort::NoSubIndex,
    SdoAbort::InvalidValue,
    SdoAbort::ValueTooHigh,
    SdoAbort::ValueTooLow,
    SdoAbort::General,
    SdoAbort::CannotStore,
    SdoAbort::LocalControl,
    SdoAbort::DeviceState,
    SdoAbort::NoData,
];
