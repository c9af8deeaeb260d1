//! Assembling one observation from its frames, never mixing two cycles, and checking it; the
//! same code for the classic and the FD layout ([`FrameLayout`]): only the number and length of
//! the frames differ.

use crate::can::e2e::{E2eReceiver, E2eStatus};
use crate::can::fd_messages::{FD_OBS_FRAMES, FD_OBS_LEN, FD_VALUES_PER_OBS_FRAME};
use crate::can::layout::FrameLayout;
use crate::can::messages::{
    OBS_FRAMES, SIGNALS_PER_FRAME, from_raw, observation_frame_index, rpdo_cob_id,
};
use crate::interface::{OBS_DIM, Quantity, quantity_of};

/// What one observation frame did to the assembly.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameOutcome {
    /// Stored; the observation is not complete yet.
    Stored,
    /// Stored and the observation of this sample is now complete.
    Complete {
        /// Sample nibble of the completed observation.
        sample: u8,
    },
    /// Dropped by the end-to-end check.
    Rejected(E2eStatus),
    /// Dropped: wrong length.
    Malformed,
}

/// Why a complete observation is unusable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObservationFault {
    /// A value was reported "not available" (non-finite at the plant).
    NonFinite {
        /// Index of the value.
        index: usize,
    },
    /// A value lies beyond its quantity's plausible range.
    OutOfRange {
        /// Index of the value.
        index: usize,
    },
}

/// Collects observation frames of one sample at a time.
#[derive(Debug, Clone)]
pub struct ObservationAssembler {
    node: u8,
    layout: FrameLayout,
    receivers: [E2eReceiver; OBS_FRAMES],
    sample: Option<u8>,
    received: u32,
    values: [f32; OBS_DIM],
    headers: [u16; OBS_FRAMES],
    /// Observations abandoned because frames of a newer sample arrived before they completed.
    pub abandoned: u32,
}

impl ObservationAssembler {
    /// An empty assembler for the classic observation frames (RPDOs) of controller `node`, whose
    /// end-to-end receivers accept counter jumps up to `max_delta`.
    pub fn new(node: u8, max_delta: u8) -> Self {
        Self::with_layout(node, max_delta, FrameLayout::Classic)
    }

    /// [`ObservationAssembler::new`] for the observation frames of `layout`.
    pub fn with_layout(node: u8, max_delta: u8, layout: FrameLayout) -> Self {
        ObservationAssembler {
            node,
            layout,
            receivers: [E2eReceiver::new(max_delta); OBS_FRAMES],
            sample: None,
            received: 0,
            values: [0.0; OBS_DIM],
            headers: [0; OBS_FRAMES],
            abandoned: 0,
        }
    }

    /// Forgets the partial observation and the end-to-end counters.
    pub fn reset(&mut self) {
        self.receivers.iter_mut().for_each(E2eReceiver::reset);
        self.sample = None;
        self.received = 0;
    }

    /// The frame layout it assembles.
    #[inline]
    pub fn layout(&self) -> FrameLayout {
        self.layout
    }

    /// Index of the observation frame with CAN id `id`, if it is one of this node's.
    pub fn frame_index(&self, id: u16) -> Option<usize> {
        self.frame_index_as(self.layout, id)
    }

    /// [`ObservationAssembler::frame_index`] for a caller that knows the assembler's layout
    /// (`layout` is [`ObservationAssembler::layout`]): a constant `layout` leaves no branch.
    #[inline(always)]
    pub(crate) fn frame_index_as(&self, layout: FrameLayout, id: u16) -> Option<usize> {
        debug_assert_eq!(layout, self.layout);
        let k = observation_frame_index(self.node, id)?;
        match layout {
            FrameLayout::Classic => Some(k),
            FrameLayout::Fd => (k < FD_OBS_FRAMES).then_some(k),
        }
    }

    /// Takes observation frame `k`. Frames of a new sample abandon an incomplete older one.
    /// A frame of the wrong length for the layout is [`FrameOutcome::Malformed`].
    pub fn push(&mut self, k: usize, data: &[u8]) -> FrameOutcome {
        self.push_as(self.layout, k, data)
    }

    /// [`ObservationAssembler::push`] for a caller that knows the assembler's layout (`layout` is
    /// [`ObservationAssembler::layout`]): a constant `layout` (a classic-only controller's) runs
    /// the classic frame's code alone, with the layout's sizes as constants.
    #[inline(always)]
    pub(crate) fn push_as(&mut self, layout: FrameLayout, k: usize, data: &[u8]) -> FrameOutcome {
        debug_assert_eq!(layout, self.layout);
        match layout {
            FrameLayout::Classic => self.push_frame::<OBS_FRAMES, 8, SIGNALS_PER_FRAME>(k, data),
            FrameLayout::Fd => {
                self.push_frame::<FD_OBS_FRAMES, FD_OBS_LEN, FD_VALUES_PER_OBS_FRAME>(k, data)
            }
        }
    }

    /// Takes frame `k` of a layout of `FRAMES` frames of `LEN` bytes, `PER_FRAME` values each.
    fn push_frame<const FRAMES: usize, const LEN: usize, const PER_FRAME: usize>(
        &mut self,
        k: usize,
        data: &[u8],
    ) -> FrameOutcome {
        const { assert!(2 + 2 * PER_FRAME <= LEN && FRAMES <= OBS_FRAMES) };
        let Some(receiver) = self.receivers.get_mut(k).filter(|_| k < FRAMES) else {
            return FrameOutcome::Malformed;
        };
        let Ok(data) = <&[u8; LEN]>::try_from(data) else {
            return FrameOutcome::Malformed;
        };
        let status = receiver.check(rpdo_cob_id(self.node, k), data);
        if status != E2eStatus::Ok {
            return FrameOutcome::Rejected(status);
        }
        let sample = data[1] >> 4;
        self.headers[k] = u16::from_le_bytes([data[0], data[1]]);
        let all = (1u32 << FRAMES) - 1;
        if self.sample != Some(sample) {
            if self.received != 0 && self.received != all {
                self.abandoned = self.abandoned.saturating_add(1);
            }
            self.sample = Some(sample);
            self.received = 0;
        }
        for s in 0..PER_FRAME {
            let index = k * PER_FRAME + s;
            let raw = i16::from_le_bytes([data[2 + 2 * s], data[3 + 2 * s]]);
            if let (Some(slot), Some(q)) = (self.values.get_mut(index), quantity_of(index)) {
                *slot = from_raw(raw, q.lsb());
            }
        }
        let before = self.received;
        self.received |= 1 << k;
        if self.received == all && before != all {
            FrameOutcome::Complete { sample }
        } else {
            FrameOutcome::Stored
        }
    }

    /// Bytes 0-1 (little-endian) of the last accepted observation frame `k` (0 before one, or
    /// for `k` out of range).
    pub fn header(&self, k: usize) -> u16 {
        self.headers.get(k).copied().unwrap_or(0)
    }

    /// The assembled values (complete after [`FrameOutcome::Complete`]).
    pub fn values(&self) -> &[f32; OBS_DIM] {
        &self.values
    }
}

/// Checks every value of an observation: finite and within its quantity's limit.
pub fn check_observation(obs: &[f32; OBS_DIM]) -> Result<(), ObservationFault> {
    for (index, v) in obs.iter().enumerate() {
        if !v.is_finite() {
            return Err(ObservationFault::NonFinite { index });
        }
        let limit = quantity_of(index).map_or(0.0, Quantity::limit);
        if v.abs() > limit {
            return Err(ObservationFault::OutOfRange { index });
        }
    }
    Ok(())
}
