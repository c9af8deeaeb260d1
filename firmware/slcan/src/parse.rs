//! Parsing one line.

use core::fmt;

use embedded_can::{ExtendedId, Id, StandardId};

/// A frame read from a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlcanFrame {
    /// Identifier.
    pub id: Id,
    /// Remote request (no data).
    pub remote: bool,
    /// Data length (0..=8).
    pub len: u8,
    /// Data (the first `len` bytes).
    pub data: [u8; 8],
    /// Lawicel time stamp in milliseconds, when the line carries one.
    pub timestamp_ms: Option<u16>,
}

impl SlcanFrame {
    /// The data bytes.
    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }
}

/// One parsed line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// A frame to send (`t`, `T`, `r`, `R`).
    Frame(SlcanFrame),
    /// `O`: open the channel.
    Open,
    /// `C`: close the channel.
    Close,
    /// `S0`..`S8`: a bit-rate index (10k .. 1M).
    Bitrate(u8),
    /// `V`: version request.
    Version,
    /// `N`: serial-number request.
    Serial,
    /// `F`: status-flags request.
    Status,
    /// `Z0`/`Z1`: time stamps off/on.
    Timestamps(bool),
    /// `z` or `Z` alone: a device's acknowledgement of a sent frame (seen by a host).
    Ack,
    /// An empty line (a lone `\r`; python-can sends some to flush).
    Empty,
}

/// Why a line is not a valid SLCAN line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SlcanError {
    /// The first character names no command.
    UnknownCommand(u8),
    /// A character that should be a hex digit is not.
    NotHex,
    /// The line is shorter or longer than its command needs.
    BadLength,
    /// An identifier above 0x7FF (standard) or 0x1FFF_FFFF (extended).
    BadId,
    /// A data length above 8.
    BadDlc,
    /// A command argument out of range (`S9`, `Z2`, a time stamp of 60,000 ms or more).
    BadArgument,
}

impl fmt::Display for SlcanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SlcanError::UnknownCommand(c) => write!(f, "unknown SLCAN command 0x{c:02x}"),
            SlcanError::NotHex => f.write_str("not a hex digit"),
            SlcanError::BadLength => f.write_str("line length does not fit its command"),
            SlcanError::BadId => f.write_str("identifier out of range"),
            SlcanError::BadDlc => f.write_str("data length above 8"),
            SlcanError::BadArgument => f.write_str("argument out of range"),
        }
    }
}

impl core::error::Error for SlcanError {}

fn hex(c: u8) -> Result<u8, SlcanError> {
    match c {
        b'0'..=b'9' => Ok(c - b'0'),
        b'a'..=b'f' => Ok(c - b'a' + 10),
        b'A'..=b'F' => Ok(c - b'A' + 10),
        _ => Err(SlcanError::NotHex),
    }
}

fn hex_u32(digits: &[u8]) -> Result<u32, SlcanError> {
    digits
        .iter()
        .try_fold(0u32, |acc, &c| Ok((acc << 4) | u32::from(hex(c)?)))
}

/// Parses one line (without its `\r`).
pub fn parse_line(line: &[u8]) -> Result<Command, SlcanError> {
    let Some((&first, rest)) = line.split_first() else {
        return Ok(Command::Empty);
    };
    match first {
        b't' | b'T' | b'r' | b'R' => frame(first, rest).map(Command::Frame),
        b'O' | b'C' | b'V' | b'N' | b'F' if !rest.is_empty() => Err(SlcanError::BadLength),
        b'O' => Ok(Command::Open),
        b'C' => Ok(Command::Close),
        b'V' => Ok(Command::Version),
        b'N' => Ok(Command::Serial),
        b'F' => Ok(Command::Status),
        b'z' if rest.is_empty() => Ok(Command::Ack),
        b'Z' if rest.is_empty() => Ok(Command::Ack),
        b'S' | b'Z' => {
            let [arg] = rest else {
                return Err(SlcanError::BadLength);
            };
            let v = hex(*arg)?;
            match (first, v) {
                (b'S', 0..=8) => Ok(Command::Bitrate(v)),
                (b'Z', 0 | 1) => Ok(Command::Timestamps(v == 1)),
                _ => Err(SlcanError::BadArgument),
            }
        }
        c => Err(SlcanError::UnknownCommand(c)),
    }
}

fn frame(kind: u8, rest: &[u8]) -> Result<SlcanFrame, SlcanError> {
    let extended = kind.is_ascii_uppercase();
    let remote = kind == b'r' || kind == b'R';
    let id_digits = if extended { 8 } else { 3 };
    if rest.len() < id_digits + 1 {
        return Err(SlcanError::BadLength);
    }
    let raw = hex_u32(&rest[..id_digits])?;
    let id = if extended {
        Id::Extended(ExtendedId::new(raw).ok_or(SlcanError::BadId)?)
    } else {
        let raw = u16::try_from(raw).map_err(|_| SlcanError::BadId)?;
        Id::Standard(StandardId::new(raw).ok_or(SlcanError::BadId)?)
    };
    let len = hex(rest[id_digits])?;
    if len > 8 {
        return Err(SlcanError::BadDlc);
    }
    let body = &rest[id_digits + 1..];
    let data_digits = if remote { 0 } else { 2 * usize::from(len) };
    let timestamp_ms = match body.len().checked_sub(data_digits) {
        Some(0) => None,
        Some(4) => {
            let ms = hex_u32(&body[data_digits..])?;
            if ms >= crate::TIMESTAMP_WRAP_MS {
                return Err(SlcanError::BadArgument);
            }
            Some(u16::try_from(ms).map_err(|_| SlcanError::BadArgument)?)
        }
        _ => return Err(SlcanError::BadLength),
    };
    let mut data = [0u8; 8];
    for (k, pair) in body[..data_digits].chunks_exact(2).enumerate() {
        data[k] = (hex(pair[0])? << 4) | hex(pair[1])?;
    }
    Ok(SlcanFrame {
        id,
        remote,
        len,
        data,
        timestamp_ms,
    })
}
