//! The CAN side of the controller: frames (classic and FD), end-to-end protection and the cell's
//! messages in the classic and the FD layout.

pub mod e2e;
pub mod fd_frame;
pub mod fd_messages;
pub mod frame;
pub mod layout;
pub mod messages;

pub use e2e::{E2eReceiver, E2eSender, E2eStatus};
pub use fd_frame::{AnyFrame, FdFrame, TxFrame};
pub use frame::CanFrame;
pub use layout::FrameLayout;
