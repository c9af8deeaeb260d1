//! The fixed 24-byte header, the file CRC and the layout hash.

use crc::{CRC_32_ISCSI, CRC_32_ISO_HDLC, Crc};

use crate::error::FormatError;

/// First four bytes of every policy file.
pub const MAGIC: [u8; 4] = *b"DXPL";
/// Newest format version this crate reads and writes (version 2 adds int8 layers).
pub const FORMAT_VERSION: u16 = 2;
/// Oldest format version this crate reads. The encoder writes the oldest version that can carry a
/// policy: version 1 for all-f32 networks (byte for byte what a version 1 encoder wrote), version 2
/// when a layer is int8.
pub const MIN_FORMAT_VERSION: u16 = 1;
/// Size of the fixed header in bytes.
pub const HEADER_LEN: usize = 24;
/// Byte offset of the CRC-32 field inside the header.
pub const CRC_OFFSET: usize = 20;

/// CRC-32/ISO-HDLC (the zlib/Ethernet CRC): the workspace's one checksum. It protects the whole
/// policy file, and the trainer's demo files, learner checkpoints and MPI messages use it too.
pub const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);
/// CRC-32C hashes the layout, so that a layout hash never equals a file CRC by construction.
const LAYOUT_CRC: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// The decoded fixed header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Format version of the file.
    pub version: u16,
    /// Reserved flags (zero in versions 1 and 2).
    pub flags: u16,
    /// Hash of the observation and action layout (see [`layout_hash`]).
    pub layout_hash: u32,
    /// Length of the postcard body in bytes.
    pub body_len: u32,
    /// Number of stored 4-byte words: little-endian f32 values (and, in version 2, packed int8
    /// weights, four to a word).
    pub value_count: u32,
    /// CRC-32 over the header (without this field) and everything after it.
    pub crc: u32,
}

impl Header {
    /// Parses the header fields and checks magic, version and flags. Sizes and CRC are checked by
    /// [`crate::PolicyView::decode`].
    pub fn parse(bytes: &[u8]) -> Result<Header, FormatError> {
        let head: &[u8; HEADER_LEN] = bytes
            .get(..HEADER_LEN)
            .and_then(|h| h.try_into().ok())
            .ok_or(FormatError::Truncated {
                needed: HEADER_LEN,
                got: bytes.len(),
            })?;
        let magic = [head[0], head[1], head[2], head[3]];
        if magic != MAGIC {
            return Err(FormatError::BadMagic { found: magic });
        }
        let u16_at = |i: usize| u16::from_le_bytes([head[i], head[i + 1]]);
        let u32_at =
            |i: usize| u32::from_le_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]);
        let header = Header {
            version: u16_at(4),
            flags: u16_at(6),
            layout_hash: u32_at(8),
            body_len: u32_at(12),
            value_count: u32_at(16),
            crc: u32_at(CRC_OFFSET),
        };
        if !(MIN_FORMAT_VERSION..=FORMAT_VERSION).contains(&header.version) {
            return Err(FormatError::UnsupportedVersion {
                found: header.version,
                supported: FORMAT_VERSION,
            });
        }
        if header.flags != 0 {
            return Err(FormatError::UnknownFlags {
                flags: header.flags,
            });
        }
        Ok(header)
    }

    /// Writes the header (with its current `crc` field) into the first 24 bytes of `out`.
    pub(crate) fn write(&self, out: &mut [u8; HEADER_LEN]) {
        out[0..4].copy_from_slice(&MAGIC);
        out[4..6].copy_from_slice(&self.version.to_le_bytes());
        out[6..8].copy_from_slice(&self.flags.to_le_bytes());
        out[8..12].copy_from_slice(&self.layout_hash.to_le_bytes());
        out[12..16].copy_from_slice(&self.body_len.to_le_bytes());
        out[16..20].copy_from_slice(&self.value_count.to_le_bytes());
        out[20..24].copy_from_slice(&self.crc.to_le_bytes());
    }
}

/// Byte offset of the first stored value for a body of `body_len` bytes (4-byte aligned).
pub const fn values_offset(body_len: usize) -> usize {
    (HEADER_LEN + body_len).next_multiple_of(4)
}

/// CRC-32 of a whole file: header bytes 0..20, then everything from byte 24 on.
/// `file` must be at least [`HEADER_LEN`] bytes long.
pub fn file_crc(file: &[u8]) -> u32 {
    let mut digest = CRC32.digest();
    digest.update(file.get(..CRC_OFFSET).unwrap_or(&[]));
    digest.update(file.get(HEADER_LEN..).unwrap_or(&[]));
    digest.finalize()
}

/// Hash of an observation layout (names and sizes, in order) and an action layout (names, in order).
///
/// Canonical bytes: per observation field its name, a 0x00 byte and its size as u32 LE; then 0xFF;
/// then per action joint its name and a 0x00 byte. Hashed with CRC-32C. Scales and limits are
/// calibration, not layout, and are not part of the hash.
pub fn layout_hash<'n>(
    observation: impl IntoIterator<Item = (&'n str, usize)>,
    action: impl IntoIterator<Item = &'n str>,
) -> u32 {
    let mut digest = LAYOUT_CRC.digest();
    for (name, size) in observation {
        digest.update(name.as_bytes());
        digest.update(&[0]);
        digest.update(&(size as u32).to_le_bytes());
    }
    digest.update(&[0xFF]);
    for name in action {
        digest.update(name.as_bytes());
        digest.update(&[0]);
    }
    digest.finalize()
}
