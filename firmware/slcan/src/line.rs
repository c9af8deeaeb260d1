//! Line assembly from a byte stream.

/// Longest line kept: `T` + 8 id digits + length + 16 data digits + 4 time-stamp digits.
pub const MAX_LINE: usize = 30;

/// What one byte did to the reader.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Push {
    /// The byte was stored (or was a stray `\n`); no line yet.
    Pending,
    /// A `\r` ended a line: read it with [`LineReader::line`] before the next push.
    Line,
    /// A `\r` ended a line that had overflowed the buffer: the line was dropped.
    Dropped,
}

/// Assembles `\r`-terminated lines in a fixed buffer.
#[derive(Debug, Clone)]
pub struct LineReader {
    buf: [u8; MAX_LINE],
    len: usize,
    overflow: bool,
    ready: usize,
}

impl Default for LineReader {
    fn default() -> Self {
        Self::new()
    }
}

impl LineReader {
    /// An empty reader.
    pub const fn new() -> Self {
        LineReader {
            buf: [0; MAX_LINE],
            len: 0,
            overflow: false,
            ready: 0,
        }
    }

    /// Feeds one byte. `\n` is ignored (some hosts send `\r\n`).
    pub fn push(&mut self, byte: u8) -> Push {
        match byte {
            crate::CR => {
                let overflowed = self.overflow;
                self.ready = if overflowed { 0 } else { self.len };
                self.len = 0;
                self.overflow = false;
                if overflowed {
                    Push::Dropped
                } else {
                    Push::Line
                }
            }
            b'\n' => Push::Pending,
            _ => {
                if self.len < MAX_LINE {
                    self.buf[self.len] = byte;
                    self.len += 1;
                } else {
                    self.overflow = true;
                }
                Push::Pending
            }
        }
    }

    /// The line the last [`Push::Line`] completed (without the `\r`).
    pub fn line(&self) -> &[u8] {
        &self.buf[..self.ready]
    }

    /// Forgets a partial line (after a framing or overrun error on the serial line).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflow = true;
    }
}
