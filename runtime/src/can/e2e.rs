//! End-to-end protection in the style of AUTOSAR E2E profile 11 (CAN).
//!
//! Byte 0 of a protected frame is a CRC-8/SAE-J1850 (polynomial 0x1D, initial 0xFF, final XOR 0xFF)
//! over the data id (low byte, then high byte; the data id is the 11-bit CAN id) followed by bytes
//! 1..len of the frame. The low nibble of byte 1 is the alive counter, 0 to 14, wrapping to 0 (15 is
//! never sent and is an error). The high nibble of byte 1 belongs to the message.

use crc::{CRC_8_SAE_J1850, Crc};

const CRC8: Crc<u8> = Crc::<u8>::new(&CRC_8_SAE_J1850);

/// Largest alive-counter value; the counter wraps from 14 to 0.
pub const COUNTER_MAX: u8 = 14;

/// CRC-8/SAE-J1850 of a protected frame `frame` (byte 0 is skipped) under `data_id`.
pub fn crc8(data_id: u16, frame: &[u8]) -> u8 {
    let mut digest = CRC8.digest();
    digest.update(&data_id.to_le_bytes());
    digest.update(frame.get(1..).unwrap_or(&[]));
    digest.finalize()
}

/// Fills in the alive counter and the CRC of `frame` (at least 2 bytes).
pub fn protect(data_id: u16, counter: u8, frame: &mut [u8]) {
    if frame.len() < 2 {
        return;
    }
    frame[1] = (frame[1] & 0xF0) | (counter & 0x0F);
    frame[0] = crc8(data_id, frame);
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
    /// Protects `frame` with the current counter, then advances it.
    pub fn protect(&mut self, data_id: u16, frame: &mut [u8]) {
        protect(data_id, self.counter, frame);
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

    /// Checks one received frame. On `Ok`, and on `WrongSequence` (to resynchronise), the counter
    /// is remembered; on `Error` and `Repeated` it is not.
    pub fn check(&mut self, data_id: u16, frame: &[u8]) -> E2eStatus {
        if frame.len() < 2 || crc8(data_id, frame) != frame[0] {
            return E2eStatus::Error;
        }
        let counter = frame[1] & 0x0F;
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
}
