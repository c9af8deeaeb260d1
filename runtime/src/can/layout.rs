//! Which frames carry the observation and the action: the classic layout (8-byte frames, three
//! values each: 15 observation frames, 3 action frames; [`crate::can::messages`]) or the CAN FD
//! layout (two 48-byte observation frames, one 20-byte action frame; [`crate::can::fd_messages`]).
//! Both put the same E2E header (CRC, alive counter and sample nibble, bytes 0-1) before the same
//! 2-byte raw values, on the first RPDOs and TPDOs of the node.

use crate::can::fd_messages::{
    FD_ACTION_FRAMES, FD_ACTION_LEN, FD_OBS_FRAMES, FD_OBS_LEN, FD_VALUES_PER_OBS_FRAME,
};
use crate::can::messages::{ACTION_FRAMES, OBS_FRAMES, SIGNALS_PER_FRAME};

/// The frame layout of a controller and its plant.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrameLayout {
    /// Classic CAN frames (the default).
    #[default]
    Classic,
    /// CAN FD frames.
    Fd,
}

impl FrameLayout {
    /// Observation frames per cycle (RPDOs 0..n).
    pub const fn observation_frames(self) -> usize {
        match self {
            FrameLayout::Classic => OBS_FRAMES,
            FrameLayout::Fd => FD_OBS_FRAMES,
        }
    }

    /// Bytes of each observation frame.
    pub const fn observation_len(self) -> usize {
        match self {
            FrameLayout::Classic => 8,
            FrameLayout::Fd => FD_OBS_LEN,
        }
    }

    /// Observation values per frame (frame `k` carries values `k*n .. k*n + n`).
    pub const fn observation_values_per_frame(self) -> usize {
        match self {
            FrameLayout::Classic => SIGNALS_PER_FRAME,
            FrameLayout::Fd => FD_VALUES_PER_OBS_FRAME,
        }
    }

    /// Action frames per cycle (TPDOs 0..n).
    pub const fn action_frames(self) -> usize {
        match self {
            FrameLayout::Classic => ACTION_FRAMES,
            FrameLayout::Fd => FD_ACTION_FRAMES,
        }
    }

    /// Bytes of each action frame.
    pub const fn action_len(self) -> usize {
        match self {
            FrameLayout::Classic => 8,
            FrameLayout::Fd => FD_ACTION_LEN,
        }
    }
}
