//! Assembling one observation from its frames, never mixing two cycles, and checking it; the
//! same code for the classic and the FD layout ([`FrameLayout`]): only the number and length of
//! the frames differ.

use crate::can::e2e::{E2eReceiver, E2eStatus};
use crate::can::fd_messages::raw_value;
use crate::can::layout::FrameLayout;
use crate::can::messages::{OBS_FRAMES, from_raw, observation_frame_index, rpdo_cob_id};
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
    pub fn layout(&self) -> FrameLayout {
        self.layout
    }

    /// Index of the observation frame with CAN id `id`, if it is one of this node's.
    pub fn frame_index(&self, id: u16) -> Option<usize> {
        observation_frame_index(self.node, id).filter(|&k| k < self.layout.observation_frames())
    }

    /// Takes observation frame `k`. Frames of a new sample abandon an incomplete older one.
    /// A frame of the wrong length for the layout is [`FrameOutcome::Malformed`].
    pub fn push(&mut self, k: usize, data: &[u8]) -> FrameOutcome {
        let layout = self.layout;
        let Some(receiver) = self
            .receivers
            .get_mut(k)
            .filter(|_| k < layout.observation_frames())
        else {
            return FrameOutcome::Malformed;
        };
        if data.len() != layout.observation_len() {
            return FrameOutcome::Malformed;
        }
        let status = receiver.check(rpdo_cob_id(self.node, k), data);
        if status != E2eStatus::Ok {
            return FrameOutcome::Rejected(status);
        }
        let sample = data[1] >> 4;
        self.headers[k] = u16::from_le_bytes([data[0], data[1]]);
        if self.sample != Some(sample) {
            if self.received != 0 && self.received != (1u32 << layout.observation_frames()) - 1 {
                self.abandoned = self.abandoned.saturating_add(1);
            }
            self.sample = Some(sample);
            self.received = 0;
        }
        let per_frame = layout.observation_values_per_frame();
        for s in 0..per_frame {
            let index = k * per_frame + s;
            if let (Some(slot), Some(q), Some(r)) = (
                self.values.get_mut(index),
                quantity_of(index),
                raw_value(data, s),
            ) {
                *slot = from_raw(r, q.lsb());
            }
        }
        let all = (1u32 << layout.observation_frames()) - 1;
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
