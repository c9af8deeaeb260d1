//! SLCAN (Lawicel ASCII) over a serial line: the line codec, `no_std`, no heap.
//!
//! Frames: `t<id:3 hex><len:1><data:2*len hex>` (standard), `T<id:8 hex><len><data>` (extended),
//! `r`/`R` the same without data (remote), each ended by `\r`. A received frame may carry the
//! Lawicel time stamp, 4 hex digits of milliseconds (0..=59,999, wrapping), after its data.
//! Commands: `O` open, `C` close, `S0`..`S8` bit rate, `V` version, `N` serial number, `F` status
//! flags, `Z0`/`Z1` time stamps off/on; the device answers `\r` (ok) or `\x07` (error), a sent
//! frame `z\r` / `Z\r`.
//!
//! [`LineReader`] assembles lines byte by byte with a fixed buffer: an over-long line is dropped
//! whole (counted), so a lost `\r` costs at most the line it was in plus the next one.
//! [`parse_line`] turns a line into a [`Command`]; [`encode_frame`] writes a frame line.
#![no_std]

mod encode;
mod line;
mod parse;

pub use encode::{EncodedLine, encode_frame};
pub use line::{LineReader, MAX_LINE, Push};
pub use parse::{Command, SlcanError, SlcanFrame, parse_line};

/// Line terminator.
pub const CR: u8 = b'\r';
/// The device's error answer (ASCII BEL).
pub const BELL: u8 = 0x07;
/// Milliseconds after which a Lawicel time stamp wraps.
pub const TIMESTAMP_WRAP_MS: u32 = 60_000;
