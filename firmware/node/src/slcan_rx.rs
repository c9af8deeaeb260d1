//! The receive side of the SLCAN link: bytes from the USART to [`Event`]s, counting everything
//! it drops.

use dex_runtime::can::CanFrame;
use dex_slcan::{Command, LineReader, Push, parse_line};
use embedded_can::Frame;

use crate::counters::Counters;

/// What a completed line asks for.
#[derive(Debug, Clone, Copy)]
pub enum RxItem {
    /// A data frame, with its Lawicel time stamp when the line had one.
    Frame(CanFrame, Option<u16>),
    /// An SLCAN command to answer.
    Reply(Reply),
}

/// The answer an SLCAN command gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply {
    /// `\r`.
    Ok,
    /// `\x07` (BEL): the line was refused.
    Error,
    /// `V` -> `V0101\r`.
    Version,
    /// `N` -> `NDEX1\r`.
    Serial,
    /// `F` -> `Fxx\r`, the status flags.
    Status,
}

/// Line assembly and parsing, one byte at a time (from the USART interrupt).
#[derive(Debug, Default)]
pub struct SlcanRx {
    reader: LineReader,
}

impl SlcanRx {
    /// A receiver at the start of a line.
    pub const fn new() -> Self {
        SlcanRx {
            reader: LineReader::new(),
        }
    }

    /// A receive error (overrun, framing): the partial line is unusable and is dropped.
    pub fn on_line_error(&mut self) {
        self.reader.reset();
    }

    /// Feeds one byte; returns what a completed line asks for. Remote frames and extended ids
    /// are answered (the controller uses neither) but not passed on.
    pub fn push(&mut self, byte: u8, counters: &Counters) -> Option<RxItem> {
        counters.rx_bytes.bump();
        match self.reader.push(byte) {
            Push::Pending => None,
            Push::Dropped => {
                counters.long_lines.bump();
                Some(RxItem::Reply(Reply::Error))
            }
            Push::Line => match parse_line(self.reader.line()) {
                Ok(Command::Frame(f)) => {
                    if f.remote {
                        return Some(RxItem::Reply(Reply::Ok));
                    }
                    match CanFrame::new(f.id, f.data()) {
                        Some(frame) => Some(RxItem::Frame(frame, f.timestamp_ms)),
                        None => {
                            counters.bad_lines.bump();
                            Some(RxItem::Reply(Reply::Error))
                        }
                    }
                }
                Ok(Command::Version) => Some(RxItem::Reply(Reply::Version)),
                Ok(Command::Serial) => Some(RxItem::Reply(Reply::Serial)),
                Ok(Command::Status) => Some(RxItem::Reply(Reply::Status)),
                Ok(Command::Empty | Command::Ack) => None,
                Ok(
                    Command::Open | Command::Close | Command::Bitrate(_) | Command::Timestamps(_),
                ) => Some(RxItem::Reply(Reply::Ok)),
                Err(_) => {
                    counters.bad_lines.bump();
                    Some(RxItem::Reply(Reply::Error))
                }
            },
        }
    }
}
