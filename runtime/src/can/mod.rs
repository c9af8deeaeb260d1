//! The CAN side of the controller: frames, end-to-end protection and the cell's messages.

pub mod e2e;
pub mod frame;
pub mod messages;

pub use e2e::{E2eReceiver, E2eSender, E2eStatus};
pub use frame::CanFrame;
