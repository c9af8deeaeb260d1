//! Policy flashing over CAN: a segmented transfer (CANopen SDO-block style) into an inactive slot,
//! verification, and activation only outside operational.
//!
//! Frames: requests on `0x600 + node` (tool to controller), responses on `0x580 + node`; byte 0 is
//! the command, responses set bit 7 (`0x80 | command`) and carry a [`FlashStatus`] in byte 1.
//!
//! | request | bytes | response |
//! |---|---|---|
//! | `0x01` init | size u32 LE | `0x81 status` |
//! | `0x02` data | sequence u8, 1..6 data bytes | every [`BLOCK_SEGMENTS`] segments and at the last: `0x82 status seq` |
//! | `0x03` end | CRC-32/ISO-HDLC of the whole file u32 LE | `0x83 status` (after verification) |
//! | `0x04` activate | - | `0x84 status` (after the controller loaded the file, or refused it) |
//! | `0x05` abort | - | `0x85 status` |
//! | `0x06` status | - | `0x86 transfer-state active-crc u32 LE` |
//!
//! Verification before a slot may be activated: the length and the transfer CRC, then the policy
//! file's own checks (`PolicyView::decode`: magic, version, file CRC, layout hash) and the
//! controller's (layout, capacity, control period) on a scratch controller. Activation is refused in
//! operational. Anything that goes wrong (sequence gap, abort, a new init, a bad CRC, a refused
//! file) discards the inactive slot only: the active policy is never touched before activation.
//!
//! Host-side slot storage: the runtime's `Controller<'p>` borrows its policy for `'p`, so an
//! activated slot is moved into a leaked, 8-byte-aligned buffer (`'static`). One leak per
//! activation is fine for simulation; the firmware needs the runtime change described in
//! `docs/sil.md` (evaluation over the active slot's bytes passed in per call).

use crc::{CRC_32_ISO_HDLC, Crc};
use dex_policy::PolicyView;
use dex_runtime::can::CanFrame;
use dex_runtime::testkit::{AlignedBytes, aligned_copy};
use dex_runtime::{Controller, ControllerConfig, State};
use embedded_can::Frame;

const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// Request identifier base (`+ node`).
pub const FLASH_REQUEST_BASE: u16 = 0x600;
/// Response identifier base (`+ node`).
pub const FLASH_RESPONSE_BASE: u16 = 0x580;
/// Segments per acknowledged block.
pub const BLOCK_SEGMENTS: u32 = 32;
/// Largest policy file accepted into a slot.
pub const SLOT_CAPACITY: usize = 512 * 1024;

/// Result codes of flash responses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlashStatus {
    /// Accepted.
    Ok = 0,
    /// A data segment arrived out of sequence: the transfer is aborted.
    Sequence = 1,
    /// The announced size exceeds the slot or more data came than announced.
    TooLarge = 2,
    /// Length or transfer CRC did not match.
    Crc = 3,
    /// The file is not a valid policy file.
    Format = 4,
    /// The controller refuses the file (layout, capacity, period).
    Refused = 5,
    /// Activation refused: the controller is operational.
    Operational = 6,
    /// Nothing verified to activate.
    NoImage = 7,
    /// Data or end without an init.
    NoTransfer = 8,
    /// Unknown command.
    Unknown = 9,
}

#[derive(Debug)]
enum Slot {
    Empty,
    Receiving {
        size: usize,
        next_seq: u8,
        segments: u32,
        data: Vec<u8>,
    },
    Verified(AlignedBytes),
}

/// The flash server inside the controller node: the inactive slot and the transfer state.
#[derive(Debug)]
pub struct FlashServer {
    node: u8,
    slot: Slot,
    active_crc: u32,
    activation_failures: u64,
}

/// What the node must do after a flash request.
#[derive(Debug)]
pub struct FlashOutcome {
    /// Response frame to send, if any (none for an activation: see [`FlashServer::activated`]).
    pub response: Option<CanFrame>,
    /// A verified file to load into the controller now (activation).
    pub activate: Option<Activation>,
}

/// A verified file handed out for activation. The node loads it into the controller and reports
/// the result with [`FlashServer::activated`], which answers the request: status 0 and the file's
/// CRC as the active one when the controller took it, status 5 (refused) and the old CRC when not.
#[derive(Debug)]
pub struct Activation {
    bytes: &'static [u8],
    crc: u32,
}

impl Activation {
    /// The policy file (8-byte aligned, living for the rest of the process).
    pub fn bytes(&self) -> &'static [u8] {
        self.bytes
    }
}

impl FlashServer {
    /// A server for `node` whose active policy file is `active` (for the status CRC).
    pub fn new(node: u8, active: Option<&[u8]>) -> Self {
        FlashServer {
            node,
            slot: Slot::Empty,
            active_crc: active.map_or(0, |b| CRC32.checksum(b)),
            activation_failures: 0,
        }
    }

    /// Verified files the controller refused when they were activated (see
    /// [`FlashServer::activated`]); reported in the node's `< diag >` line.
    pub fn activation_failures(&self) -> u64 {
        self.activation_failures
    }

    /// Whether `id` is this server's request identifier.
    pub fn is_request(&self, frame: &CanFrame) -> bool {
        frame.standard_id() == Some(FLASH_REQUEST_BASE + u16::from(self.node))
    }

    fn respond(&self, bytes: &[u8]) -> Option<CanFrame> {
        CanFrame::standard(FLASH_RESPONSE_BASE + u16::from(self.node), bytes)
    }

    /// Handles one request; `state` is the controller's current state.
    pub fn handle(&mut self, frame: &CanFrame, state: State) -> FlashOutcome {
        let data = frame.data();
        let cmd = data.first().copied().unwrap_or(0);
        let status: Option<FlashStatus> = match cmd {
            0x01 => Some(self.init(data)),
            0x02 => self.segment(data),
            0x03 => Some(self.end(data)),
            0x04 => match self.activate(state) {
                Ok(a) => {
                    // Answered by `activated` once the controller has loaded the file.
                    return FlashOutcome {
                        response: None,
                        activate: Some(a),
                    };
                }
                Err(s) => Some(s),
            },
            0x05 => {
                self.slot = Slot::Empty;
                Some(FlashStatus::Ok)
            }
            0x06 => {
                let st = match self.slot {
                    Slot::Empty => 0u8,
                    Slot::Receiving { .. } => 1,
                    Slot::Verified(_) => 2,
                };
                let c = self.active_crc.to_le_bytes();
                return FlashOutcome {
                    response: self.respond(&[0x86, st, c[0], c[1], c[2], c[3]]),
                    activate: None,
                };
            }
            _ => Some(FlashStatus::Unknown),
        };
        let response = status.and_then(|s| {
            if cmd == 0x02 {
                let seq = data.get(1).copied().unwrap_or(0);
                self.respond(&[0x82, s as u8, seq])
            } else {
                self.respond(&[0x80 | cmd, s as u8])
            }
        });
        FlashOutcome {
            response,
            activate: None,
        }
    }

    /// Completes an activation: `loaded` says whether the controller took the file. Returns the
    /// `0x84` response (status 0, or 5 when refused; a refused file is gone from the slot and the
    /// active policy and its CRC stay as they were).
    pub fn activated(&mut self, activation: Activation, loaded: bool) -> Option<CanFrame> {
        let status = if loaded {
            self.active_crc = activation.crc;
            FlashStatus::Ok
        } else {
            self.activation_failures = self.activation_failures.saturating_add(1);
            FlashStatus::Refused
        };
        self.respond(&[0x84, status as u8])
    }

    fn init(&mut self, data: &[u8]) -> FlashStatus {
        let Some(size) = data.get(1..5) else {
            self.slot = Slot::Empty;
            return FlashStatus::Format;
        };
        let size = u32::from_le_bytes([size[0], size[1], size[2], size[3]]) as usize;
        if size == 0 || size > SLOT_CAPACITY {
            self.slot = Slot::Empty;
            return FlashStatus::TooLarge;
        }
        self.slot = Slot::Receiving {
            size,
            next_seq: 0,
            segments: 0,
            data: Vec::with_capacity(size),
        };
        FlashStatus::Ok
    }

    /// `None`: segment accepted inside a block (no response).
    fn segment(&mut self, data: &[u8]) -> Option<FlashStatus> {
        let Slot::Receiving {
            size,
            next_seq,
            segments,
            data: buf,
        } = &mut self.slot
        else {
            return Some(FlashStatus::NoTransfer);
        };
        let (Some(&seq), Some(payload)) = (data.get(1), data.get(2..)) else {
            self.slot = Slot::Empty;
            return Some(FlashStatus::Format);
        };
        if seq != *next_seq || payload.is_empty() {
            self.slot = Slot::Empty;
            return Some(FlashStatus::Sequence);
        }
        if buf.len() + payload.len() > *size {
            self.slot = Slot::Empty;
            return Some(FlashStatus::TooLarge);
        }
        buf.extend_from_slice(payload);
        *next_seq = next_seq.wrapping_add(1);
        *segments += 1;
        if *segments % BLOCK_SEGMENTS == 0 || buf.len() == *size {
            Some(FlashStatus::Ok)
        } else {
            None
        }
    }

    fn end(&mut self, data: &[u8]) -> FlashStatus {
        let slot = std::mem::replace(&mut self.slot, Slot::Empty);
        let Slot::Receiving {
            size, data: buf, ..
        } = slot
        else {
            return FlashStatus::NoTransfer;
        };
        let Some(c) = data.get(1..5) else {
            return FlashStatus::Format;
        };
        let crc = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        if buf.len() != size || CRC32.checksum(&buf) != crc {
            return FlashStatus::Crc;
        }
        let aligned = aligned_copy(&buf);
        let status = match PolicyView::decode(aligned.as_bytes()) {
            Err(_) => FlashStatus::Format,
            Ok(view) => {
                // The controller's own checks, on a scratch controller (layout, capacity, period).
                let mut scratch =
                    Controller::<{ crate::node::NODE_WIDTH }>::new(ControllerConfig {
                        node_id: self.node,
                        ..ControllerConfig::default()
                    });
                if scratch.load_policy(&view).is_err() {
                    FlashStatus::Refused
                } else {
                    FlashStatus::Ok
                }
            }
        };
        if status == FlashStatus::Ok {
            self.slot = Slot::Verified(aligned);
        }
        status
    }

    fn activate(&mut self, state: State) -> Result<Activation, FlashStatus> {
        if state == State::Operational {
            return Err(FlashStatus::Operational);
        }
        match std::mem::replace(&mut self.slot, Slot::Empty) {
            Slot::Verified(bytes) => {
                let crc = CRC32.checksum(bytes.as_bytes());
                let leaked: &'static AlignedBytes = Box::leak(Box::new(bytes));
                Ok(Activation {
                    bytes: leaked.as_bytes(),
                    crc,
                })
            }
            other => {
                self.slot = other;
                Err(FlashStatus::NoImage)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn req(data: &[u8]) -> CanFrame {
        CanFrame::standard(FLASH_REQUEST_BASE + 0x10, data).unwrap()
    }

    /// Sends `image` (cut after `cut` segments if given); returns the end status.
    fn transfer(s: &mut FlashServer, image: &[u8], crc: u32, cut: Option<usize>) -> Option<u8> {
        let size = (image.len() as u32).to_le_bytes();
        let r = s.handle(
            &req(&[1, size[0], size[1], size[2], size[3]]),
            State::PreOperational,
        );
        assert_eq!(r.response.unwrap().data(), &[0x81, 0]);
        for (n, chunk) in image.chunks(6).enumerate() {
            if cut == Some(n) {
                return None;
            }
            let mut d = vec![2, n as u8];
            d.extend_from_slice(chunk);
            let r = s.handle(&req(&d), State::PreOperational);
            if let Some(f) = r.response {
                assert_eq!(f.data()[1], 0);
            }
        }
        let c = crc.to_le_bytes();
        let r = s.handle(&req(&[3, c[0], c[1], c[2], c[3]]), State::PreOperational);
        Some(r.response.unwrap().data()[1])
    }

    #[test]
    fn an_activation_the_controller_refuses_is_reported_and_keeps_the_old_crc() {
        let old = dex_runtime::testkit::jaco_policy(&[16], 1).unwrap();
        let new = dex_runtime::testkit::jaco_policy(&[8, 8], 2).unwrap();
        let mut s = FlashServer::new(0x10, Some(&old));
        assert_eq!(transfer(&mut s, &new, CRC32.checksum(&new), None), Some(0));
        let activation = s
            .handle(&req(&[4]), State::PreOperational)
            .activate
            .unwrap();
        let response = s.activated(activation, false).unwrap();
        assert_eq!(response.data(), &[0x84, FlashStatus::Refused as u8]);
        assert_eq!(s.activation_failures(), 1);
        let f = s
            .handle(&req(&[6]), State::PreOperational)
            .response
            .unwrap();
        assert_eq!(f.data()[1], 0, "slot emptied");
        assert_eq!(
            u32::from_le_bytes([f.data()[2], f.data()[3], f.data()[4], f.data()[5]]),
            CRC32.checksum(&old),
            "the old file is still reported active"
        );
    }

    #[test]
    fn transfer_verify_activate_and_every_refusal() {
        let old = dex_runtime::testkit::jaco_policy(&[16], 1).unwrap();
        let new = dex_runtime::testkit::jaco_policy(&[8, 8], 2).unwrap();
        let mut s = FlashServer::new(0x10, Some(&old));
        let old_crc = CRC32.checksum(&old);
        let status = |s: &mut FlashServer| {
            let f = s
                .handle(&req(&[6]), State::PreOperational)
                .response
                .unwrap();
            (
                f.data()[1],
                u32::from_le_bytes([f.data()[2], f.data()[3], f.data()[4], f.data()[5]]),
            )
        };
        // Interrupted: nothing to activate, old one still reported active.
        assert_eq!(transfer(&mut s, &new, CRC32.checksum(&new), Some(10)), None);
        assert_eq!(status(&mut s), (1, old_crc));
        let r = s.handle(&req(&[4]), State::PreOperational);
        assert_eq!(
            r.response.unwrap().data(),
            &[0x84, FlashStatus::NoImage as u8]
        );
        assert!(r.activate.is_none());
        // Wrong transfer CRC; corrupted file with a matching transfer CRC.
        assert_eq!(
            transfer(&mut s, &new, 0xDEAD_BEEF, None),
            Some(FlashStatus::Crc as u8)
        );
        let mut bad = new.clone();
        let mid = bad.len() / 2;
        bad[mid] ^= 0x40;
        assert_eq!(
            transfer(&mut s, &bad, CRC32.checksum(&bad), None),
            Some(FlashStatus::Format as u8)
        );
        // Verified, then refused while operational, then activated.
        assert_eq!(transfer(&mut s, &new, CRC32.checksum(&new), None), Some(0));
        let r = s.handle(&req(&[4]), State::Operational);
        assert_eq!(
            r.response.unwrap().data(),
            &[0x84, FlashStatus::Operational as u8]
        );
        assert_eq!(status(&mut s), (2, old_crc));
        let r = s.handle(&req(&[4]), State::SafeStop);
        assert!(r.response.is_none(), "answered after the controller's load");
        let activation = r.activate.unwrap();
        assert_eq!(activation.bytes(), &new[..]);
        let response = s.activated(activation, true).unwrap();
        assert_eq!(response.data(), &[0x84, 0]);
        assert_eq!(status(&mut s), (0, CRC32.checksum(&new)));
        // Out-of-sequence segment and data without init.
        let r = s.handle(&req(&[2, 0, 1, 2]), State::PreOperational);
        assert_eq!(
            r.response.unwrap().data(),
            &[0x82, FlashStatus::NoTransfer as u8, 0]
        );
        let size = 100u32.to_le_bytes();
        s.handle(
            &req(&[1, size[0], size[1], size[2], size[3]]),
            State::PreOperational,
        );
        let r = s.handle(&req(&[2, 5, 1, 2]), State::PreOperational);
        assert_eq!(
            r.response.unwrap().data(),
            &[0x82, FlashStatus::Sequence as u8, 5]
        );
        let too_big = (SLOT_CAPACITY as u32 + 1).to_le_bytes();
        let r = s.handle(
            &req(&[1, too_big[0], too_big[1], too_big[2], too_big[3]]),
            State::PreOperational,
        );
        assert_eq!(
            r.response.unwrap().data(),
            &[0x81, FlashStatus::TooLarge as u8]
        );
    }
}
