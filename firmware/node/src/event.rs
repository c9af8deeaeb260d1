//! What the receive interrupt hands to the control task, through a bounded queue.

use dex_runtime::can::CanFrame;

/// One received item.
#[derive(Debug, Clone, Copy)]
pub enum Event {
    /// A data frame, with the bus's time stamp (milliseconds) when the line carried one.
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
