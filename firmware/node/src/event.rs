//! What the receive interrupt hands to the control task, through a bounded queue.

use dex_runtime::can::CanFrame;

/// One received item.
#[derive(Debug, Clone, Copy)]
pub enum Event {
    /// A data frame, with the bus's time stamp (milliseconds) when the line carried one.
    Frame(CanFrame, Option<u16>),
}
