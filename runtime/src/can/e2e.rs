//! End-to-end protection in the style of AUTOSAR E2E profile 11 (CAN).
//!
//! Byte 0 of a protected frame is a CRC-8/SAE-J1850 (polynomial 0x1D, initial 0xFF, final XOR 0xFF)
//! over the data id (low byte, then high byte; the data id is the 11-bit CAN id) followed by bytes
//! 1..len of the frame. The low nibble of byte 1 is the alive counter, 0 to 14, wrapping to 0 (15 is
//! never sent and is an error). The high nibble of byte 1 belongs to the message.
//!
//! That is the [`E2eLayout::Head`] layout, used by the PDOs (observation, action, policy
//! information, status). The emergency frame keeps CiA 301's bytes 0-2 (error code and error
//! register) and carries the same protection at its end instead, [`E2eLayout::Tail`]: the CRC in
//! the last byte and the alive counter in the low nibble of the byte before it. In every layout
//! the CRC covers the data id followed by every byte of the frame but the CRC byte, in order.

use crc::{CRC_8_SAE_J1850, Crc};

const CRC8: Crc<u8> = Crc::<u8>::new(&CRC_8_SAE_J1850);

/// Largest alive-counter value; the counter wraps from 14 to 0.
pub const COUNTER_MAX: u8 = 14;

/// Where the CRC and the alive counter sit in a protected frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum E2eLayout {
    /// CRC in byte 0, alive counter in the low nibble of byte 1 (the PDOs).
    Head,
    /// CRC in the last byte, alive counter in the low nibble of the byte before it (the
    /// emergency frame, whose bytes 0-2 CiA 301 defines).
    Tail,
}

impl E2eLayout {
    /// The (CRC, counter) byte positions in a frame of `len` bytes (`None` under 2 bytes).
    pub const fn positions(self, len: usize) -> Option<(usize, usize)> {
        if len < 2 {
            return None;
        }
        Some(match self {
            E2eLayout::Head => (0, 1),
            E2eLayout::Tail => (len - 1, len - 2),
        })
    }
}

/// CRC-8/SAE-J1850 of a protected frame `frame` in the [`E2eLayout::Head`] layout (byte 0 is
/// skipped) under `data_id`.
pub fn crc8(data_id: u16, frame: &[u8]) -> u8 {
    crc8_in(E2eLayout::Head, data_id, frame)
}

/// CRC-8/SAE-J1850 of `frame` under `data_id`, skipping the CRC byte of `layout`.
pub fn crc8_in(layout: E2eLayout, data_id: u16, frame: &[u8]) -> u8 {
    let mut digest = CRC8.digest();
    digest.update(&data_id.to_le_bytes());
    match layout.positions(frame.len()) {
        Some((crc, _)) => {
            digest.update(&frame[..crc]);
            digest.update(&frame[crc + 1..]);
        }
        None => digest.update(frame.get(1..).unwrap_or(&[])),
    }
    digest.finalize()
}

/// Fills in the alive counter and the CRC of `frame` (at least 2 bytes) in the
/// [`E2eLayout::Head`] layout.
pub fn protect(data_id: u16, counter: u8, frame: &mut [u8]) {
    protect_in(E2eLayout::Head, data_id, counter, frame);
}

/// Fills in the alive counter and the CRC of `frame` (at least 2 bytes) in `layout`.
pub fn protect_in(layout: E2eLayout, data_id: u16, counter: u8, frame: &mut [u8]) {
    let Some((crc, count)) = layout.positions(frame.len()) else {
        return;
    };
    frame[count] = (frame[count] & 0xF0) | (counter & 0x0F);
    frame[crc] = crc8_in(layout, data_id, frame);
}

/// Result of checking one data id in one cycle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum E2eStatus {
    /// CRC correct and counter advanced by 1 to `max_delta`.
    Ok,
    /// No frame since the last check.
    NoNewData,
    /// CRC wrong, frame too short or counter 15.
    Error,
    /// Counter equal to the previous one: the same frame again.
    Repeated,
    /// Counter jumped by more than `max_delta`: frames were lost or reordered.
    WrongSequence,
}

/// The next alive counter after `c`.
pub const fn next_counter(c: u8) -> u8 {
    if c >= COUNTER_MAX { 0 } else { c + 1 }
}

/// Sender side: one alive counter per data id.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct E2eSender {
    counter: u8,
}

impl E2eSender {
    /// Protects `frame` with the current counter ([`E2eLayout::Head`]), then advances it.
    pub fn protect(&mut self, data_id: u16, frame: &mut [u8]) {
        self.protect_in(E2eLayout::Head, data_id, frame);
    }

    /// Protects `frame` with the current counter in `layout`, then advances it.
    pub fn protect_in(&mut self, layout: E2eLayout, data_id: u16, frame: &mut [u8]) {
        protect_in(layout, data_id, self.counter, frame);
        self.counter = next_counter(self.counter);
    }
}

/// Receiver side for one data id.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct E2eReceiver {
    last: Option<u8>,
    max_delta: u8,
}

impl E2eReceiver {
    /// A receiver accepting counter jumps up to `max_delta` (1 = no frame may be lost).
    pub const fn new(max_delta: u8) -> Self {
        E2eReceiver {
            last: None,
            max_delta,
        }
    }

    /// Forgets the last counter: the next correct frame is accepted whatever its counter.
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// Checks one received frame ([`E2eLayout::Head`]). On `Ok`, and on `WrongSequence` (to
    /// resynchronise), the counter is remembered; on `Error` and `Repeated` it is not.
    pub fn check(&mut self, data_id: u16, frame: &[u8]) -> E2eStatus {
        self.check_in(E2eLayout::Head, data_id, frame)
    }

    /// Checks one received frame protected in `layout` (as [`E2eReceiver::check`]).
    pub fn check_in(&mut self, layout: E2eLayout, data_id: u16, frame: &[u8]) -> E2eStatus {
        let Some((crc, count)) = layout.positions(frame.len()) else {
            return E2eStatus::Error;
        };
        if crc8_in(layout, data_id, frame) != frame[crc] {
            return E2eStatus::Error;
        }
        let counter = frame[count] & 0x0F;
        if counter > COUNTER_MAX {
            return E2eStatus::Error;
        }
        let status = match self.last {
            None => E2eStatus::Ok,
            Some(last) => {
                let delta = (counter + COUNTER_MAX + 1 - last) % (COUNTER_MAX + 1);
                if delta == 0 {
                    E2eStatus::Repeated
                } else if delta <= self.max_delta {
                    E2eStatus::Ok
                } else {
                    E2eStatus::WrongSequence
                }
            }
        };
        if status != E2eStatus::Repeated {
            self.last = Some(counter);
        }
        status
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_catalogue_check_value() {
        // CRC-8/SAE-J1850 of "123456789" is 0x4B; with data id bytes '1','2' in front of a frame
        // whose byte 0 is skipped, the covered bytes are exactly "123456789".
        let data_id = u16::from_le_bytes([b'1', b'2']);
        let frame = [0u8, b'3', b'4', b'5', b'6', b'7', b'8', b'9'];
        assert_eq!(crc8(data_id, &frame), 0x4B);
    }

    #[test]
    fn receiver_classifies_every_case() {
        let id = 0x200;
        let mut tx = E2eSender::default();
        let mut rx = E2eReceiver::new(2);
        let mut frames = [[0u8; 8]; 20];
        for f in frames.iter_mut() {
            f[2] = 0xAB;
            tx.protect(id, f);
        }
        assert_eq!(rx.check(id, &frames[0]), E2eStatus::Ok);
        assert_eq!(rx.check(id, &frames[0]), E2eStatus::Repeated);
        assert_eq!(rx.check(id, &frames[1]), E2eStatus::Ok);
        assert_eq!(rx.check(id, &frames[3]), E2eStatus::Ok); // one lost, within max_delta 2
        assert_eq!(rx.check(id, &frames[7]), E2eStatus::WrongSequence);
        assert_eq!(rx.check(id, &frames[8]), E2eStatus::Ok); // resynchronised
        let mut bad = frames[9];
        bad[5] ^= 0x10;
        assert_eq!(rx.check(id, &bad), E2eStatus::Error);
        assert_eq!(rx.check(id, &frames[9]), E2eStatus::Ok);
        assert_eq!(rx.check(0x201, &frames[10]), E2eStatus::Error); // wrong data id
        // Counters wrap from 14 to 0 (frames 14 and 15 carry counters 14 and 0).
        let mut rx = E2eReceiver::new(1);
        assert_eq!(rx.check(id, &frames[14]), E2eStatus::Ok);
        assert_eq!(rx.check(id, &frames[15]), E2eStatus::Ok);
        assert_eq!(frames[15][1] & 0x0F, 0);
        let mut fifteen = frames[16];
        protect(id, 15, &mut fifteen);
        assert_eq!(rx.check(id, &fifteen), E2eStatus::Error);
        assert_eq!(rx.check(id, &[0u8]), E2eStatus::Error);
    }

    #[test]
    fn tail_layout_protects_the_same_bytes_from_the_end() {
        // The catalogue value again, the CRC byte now last.
        let data_id = u16::from_le_bytes([b'1', b'2']);
        let frame = [b'3', b'4', b'5', b'6', b'7', b'8', b'9', 0u8];
        assert_eq!(crc8_in(E2eLayout::Tail, data_id, &frame), 0x4B);
        let id = 0x090;
        let mut tx = E2eSender::default();
        let mut rx = E2eReceiver::new(1);
        let mut a = [0x50, 0x82, 0x11, 1, 3, 0, 0xA0, 0];
        let mut b = a;
        tx.protect_in(E2eLayout::Tail, id, &mut a);
        tx.protect_in(E2eLayout::Tail, id, &mut b);
        assert_eq!((a[6], b[6]), (0xA0, 0xA1)); // the high nibble is the message's
        assert_eq!(rx.check_in(E2eLayout::Tail, id, &a), E2eStatus::Ok);
        assert_eq!(rx.check_in(E2eLayout::Tail, id, &b), E2eStatus::Ok);
        assert_eq!(rx.check(id, &b), E2eStatus::Error); // not a head-protected frame
        b[0] ^= 1;
        assert_eq!(rx.check_in(E2eLayout::Tail, id, &b), E2eStatus::Error);
    }
}
