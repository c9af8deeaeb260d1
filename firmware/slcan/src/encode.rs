//! Writing a frame line.

use embedded_can::Id;

/// Longest encoded frame line, `\r` included.
const CAP: usize = crate::MAX_LINE + 1;

/// One encoded line in a fixed buffer.
#[derive(Debug, Clone, Copy)]
pub struct EncodedLine {
    buf: [u8; CAP],
    len: usize,
}

impl EncodedLine {
    /// The line's bytes, `\r` included.
    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    fn push(&mut self, b: u8) {
        if self.len < CAP {
            self.buf[self.len] = b;
            self.len += 1;
        }
    }

    fn push_hex(&mut self, value: u32, digits: u32) {
        for k in (0..digits).rev() {
            let nibble = ((value >> (4 * k)) & 0xF) as usize;
            self.push(b"0123456789ABCDEF"[nibble]);
        }
    }
}

/// Encodes a data frame (`data` past 8 bytes is cut), with a Lawicel time stamp (milliseconds,
/// taken modulo [`crate::TIMESTAMP_WRAP_MS`]) when `timestamp_ms` is given.
pub fn encode_frame(id: Id, data: &[u8], timestamp_ms: Option<u32>) -> EncodedLine {
    let mut line = EncodedLine {
        buf: [0; CAP],
        len: 0,
    };
    let data = &data[..data.len().min(8)];
    match id {
        Id::Standard(s) => {
            line.push(b't');
            line.push_hex(u32::from(s.as_raw()), 3);
        }
        Id::Extended(e) => {
            line.push(b'T');
            line.push_hex(e.as_raw(), 8);
        }
    }
    line.push_hex(data.len() as u32, 1);
    for &b in data {
        line.push_hex(u32::from(b), 2);
    }
    if let Some(ms) = timestamp_ms {
        line.push_hex(ms % crate::TIMESTAMP_WRAP_MS, 4);
    }
    line.push(crate::CR);
    line
}
