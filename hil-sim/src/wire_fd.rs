//! Time on the wire of CAN FD frames (ISO 11898-1:2015, bit-rate switching on): the arbitration
//! phase and the frame's end at the nominal bit rate, the data phase at the data bit rate. The
//! bus's FD wire ([`BusWire`], `hil-sim bus --fd --data-bitrate D`: [`crate::arbitration`] times
//! every FD frame with it) and the budget model of `example wire_budget`.
//!
//! An FD data frame with an 11-bit identifier and `n` data bytes (`n` one of [`FD_LENGTHS`]):
//! - nominal rate: start of frame, identifier, RRS, IDE, FDF, res, BRS (17 bits; 36 with a 29-bit
//!   identifier), then ACK slot and delimiter, end of frame and intermission (12 bits);
//! - data rate: ESI and DLC (5 bits), the data, the stuff count and CRC (4 + 17 bits up to 16 data
//!   bytes, 4 + 21 above) with their fixed stuff bits (one before the stuff count and one after
//!   every fourth bit: 6, or 7), and the CRC delimiter (the switch back happens at its sample
//!   point);
//! - dynamic stuff bits from the start of frame to the end of the data: none at best, at worst
//!   one after the first five bits and then one every four, counted here per phase and rounded up
//!   (a bound at most one bit above the exact worst case); or exactly this frame's
//!   ([`fd_frame_bits`] with [`Stuffing::Exact`]: its bit stream from the start of frame to the
//!   end of the data built and counted, those up to BRS at the nominal rate, the rest at the data
//!   rate; the stuff count and CRC fields carry fixed stuff bits only, so their CRC need not be
//!   built).

use dex_runtime::can::{AnyFrame, FdFrame};
use embedded_can::{Frame, Id};

use crate::wire::{Stuffing, WireConfig, push_bits, stuff_positions};

/// The data lengths of an FD frame and the shortest that holds `n` bytes: the runtime's.
pub use dex_runtime::can::fd_frame::{FD_LENGTHS, fd_length};

/// An FD frame's bits in its two phases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FdBits {
    /// Bits at the nominal bit rate.
    pub nominal: u32,
    /// Bits at the data bit rate.
    pub data: u32,
}

/// Bits of an FD data frame of `data_len` bytes (rounded up to an FD length; at most 64) with an
/// 11-bit (`extended` false) or 29-bit identifier, with no dynamic stuff bits (`worst_case`
/// false) or the most it can carry.
pub fn fd_bits(extended: bool, data_len: usize, worst_case: bool) -> FdBits {
    let n = fd_length(data_len).unwrap_or(64) as u32;
    let arbitration = if extended { 36 } else { 17 };
    let control_data = 5 + 8 * n;
    let crc_field = if n <= 16 { 4 + 17 + 6 } else { 4 + 21 + 7 };
    let (stuff_nominal, stuff_data) = if worst_case {
        ((arbitration - 1) / 4, control_data.div_ceil(4))
    } else {
        (0, 0)
    };
    FdBits {
        nominal: arbitration + stuff_nominal + 12,
        data: control_data + stuff_data + crc_field + 1,
    }
}

/// The dynamic stuff bits of this FD frame's bit stream from the start of frame to the end of
/// its data: (up to and including BRS, after it).
fn exact_stuff_bits(frame: &FdFrame) -> (u32, u32) {
    let mut bits: Vec<bool> = Vec::with_capacity(48 + 8 * frame.data().len());
    bits.push(false); // start of frame
    match frame.id() {
        Id::Standard(s) => {
            push_bits(&mut bits, u32::from(s.as_raw()), 11);
            bits.extend([false, false]); // RRS, IDE
        }
        Id::Extended(e) => {
            push_bits(&mut bits, e.as_raw() >> 18, 11);
            bits.extend([true, true]); // SRR, IDE
            push_bits(&mut bits, e.as_raw() & 0x3_FFFF, 18);
            bits.push(false); // RRS
        }
    }
    bits.extend([true, false, frame.bit_rate_switch()]); // FDF, res, BRS
    let nominal_end = bits.len();
    bits.push(false); // ESI (error active)
    push_bits(&mut bits, u32::from(frame.dlc_code()), 4);
    for byte in frame.data() {
        push_bits(&mut bits, u32::from(*byte), 8);
    }
    let (mut nominal, mut data) = (0, 0);
    for i in stuff_positions(&bits) {
        // The stuff bit follows bit `i`: at the nominal rate while `i` is before BRS's end.
        if i + 1 < nominal_end {
            nominal += 1;
        } else {
            data += 1;
        }
    }
    (nominal, data)
}

/// Bits of this FD frame with `stuffing`: its own dynamic stuff bits ([`Stuffing::Exact`]) or
/// the most a frame of its length can carry ([`fd_bits`] worst case). A frame without bit-rate
/// switching runs at the nominal rate throughout: all its bits count as nominal.
pub fn fd_frame_bits(frame: &FdFrame, stuffing: Stuffing) -> FdBits {
    let extended = frame.is_extended();
    let len = frame.data().len();
    let bits = match stuffing {
        Stuffing::WorstCase => fd_bits(extended, len, true),
        Stuffing::Exact => {
            let unstuffed = fd_bits(extended, len, false);
            let (nominal, data) = exact_stuff_bits(frame);
            FdBits {
                nominal: unstuffed.nominal + nominal,
                data: unstuffed.data + data,
            }
        }
    };
    if frame.bit_rate_switch() {
        bits
    } else {
        FdBits {
            nominal: bits.nominal + bits.data,
            data: 0,
        }
    }
}

/// The wire of the virtual bus: classic frames at the nominal bit rate ([`WireConfig`]), and on
/// a CAN FD bus ([`BusWire::data_bitrate`]) FD frames over the two bit rates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BusWire {
    /// The nominal (arbitration) bit rate and the stuffing of every frame.
    pub nominal: WireConfig,
    /// CAN FD: the data-phase bit rate (at least the nominal one). `None`: a classic bus.
    pub data_bitrate: Option<u32>,
}

impl From<WireConfig> for BusWire {
    /// A classic bus.
    fn from(nominal: WireConfig) -> Self {
        BusWire {
            nominal,
            data_bitrate: None,
        }
    }
}

impl BusWire {
    /// Whether FD frames go on this wire.
    pub fn is_fd(&self) -> bool {
        self.data_bitrate.is_some()
    }

    /// The two bit rates of FD frames (the data rate the nominal one on a classic bus).
    pub fn fd_wire(&self) -> FdWire {
        FdWire {
            nominal_bitrate: self.nominal.bitrate,
            data_bitrate: self.data_bitrate.unwrap_or(self.nominal.bitrate),
        }
    }

    /// This FD frame's time on this wire, start of frame to the end of its intermission (ns).
    pub fn fd_frame_ns(&self, frame: &FdFrame) -> u64 {
        self.fd_wire()
            .frame_ns(fd_frame_bits(frame, self.nominal.stuffing))
    }

    /// Any frame's time on this wire (ns): a classic frame's bits over the nominal rate, an FD
    /// frame's over the two.
    pub fn frame_ns(&self, frame: &AnyFrame) -> u64 {
        match frame {
            AnyFrame::Classic(f) => self.nominal.frame_ns(f),
            AnyFrame::Fd(f) => self.fd_frame_ns(f),
        }
    }
}

/// The two bit rates of an FD bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FdWire {
    /// Arbitration-phase bit rate (bit/s).
    pub nominal_bitrate: u32,
    /// Data-phase bit rate (bit/s).
    pub data_bitrate: u32,
}

impl FdWire {
    /// Nanoseconds a frame of these bits takes, start of frame to the end of its intermission.
    pub fn frame_ns(&self, bits: FdBits) -> u64 {
        crate::wire::bits_ns(bits.nominal, self.nominal_bitrate)
            + crate::wire::bits_ns(bits.data, self.data_bitrate)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{bits_ns, unstuffed_bits, worst_case_bits};

    #[test]
    fn lengths_round_up_to_the_fd_steps() {
        assert_eq!(fd_length(8), Some(8));
        assert_eq!(fd_length(9), Some(12));
        assert_eq!(fd_length(46), Some(48));
        assert_eq!(fd_length(64), Some(64));
        assert_eq!(fd_length(65), None);
    }

    #[test]
    fn the_data_phase_alone_runs_at_the_data_rate() {
        for worst in [false, true] {
            let b = fd_bits(false, 64, worst);
            let same = FdWire {
                nominal_bitrate: 500_000,
                data_bitrate: 500_000,
            };
            let fast = FdWire {
                nominal_bitrate: 500_000,
                data_bitrate: 2_000_000,
            };
            assert_eq!(same.frame_ns(b), bits_ns(b.nominal + b.data, 500_000));
            assert_eq!(
                same.frame_ns(b) - fast.frame_ns(b),
                u64::from(b.data) * (2_000 - 500)
            );
        }
        // Worst-case stuffing adds bits, and more data more of them.
        assert!(fd_bits(false, 64, true).data > fd_bits(false, 64, false).data);
        assert!(fd_bits(true, 8, false).nominal == fd_bits(false, 8, false).nominal + 19);
    }

    #[test]
    fn exact_stuffing_lies_between_none_and_the_worst_case() {
        for data in [[0u8; 48], [0xFF; 48], [0x5A; 48], [0x0F; 48]] {
            let f = FdFrame::standard(0x210, &data).expect("48 bytes");
            let none = fd_bits(false, 48, false);
            let worst = fd_bits(false, 48, true);
            let exact = fd_frame_bits(&f, Stuffing::Exact);
            assert!(exact.nominal >= none.nominal && exact.nominal <= worst.nominal + 1);
            assert!(
                exact.data >= none.data && exact.data <= worst.data + 1,
                "{exact:?}"
            );
            assert_eq!(fd_frame_bits(&f, Stuffing::WorstCase), worst);
        }
        // All zeros: a stuff bit after every five (512 / 5 in the data).
        let zeros = FdFrame::standard(0x000, &[0; 64]).expect("64 bytes");
        let exact = fd_frame_bits(&zeros, Stuffing::Exact);
        assert_eq!(
            exact.data - fd_bits(false, 64, false).data,
            102,
            "{exact:?}"
        );
        // Alternating bits: no stuff bit in the data.
        let alt = FdFrame::standard(0x555, &[0x55; 64]).expect("64 bytes");
        assert_eq!(
            fd_frame_bits(&alt, Stuffing::Exact).data,
            fd_bits(false, 64, false).data
        );
        // Without BRS everything runs at the nominal rate.
        let slow = FdFrame::new_fd(
            embedded_can::StandardId::new(0x210).expect("11 bits"),
            &[0; 20],
            false,
        )
        .expect("20 bytes");
        assert_eq!(fd_frame_bits(&slow, Stuffing::WorstCase).data, 0);
    }

    #[test]
    fn an_fd_frame_at_one_rate_is_longer_than_the_classic_one() {
        // The same 8 bytes: the FD frame's longer CRC field and its FDF/BRS/ESI bits.
        let fd = fd_bits(false, 8, false);
        assert!(fd.nominal + fd.data > unstuffed_bits(8));
        let fd = fd_bits(false, 8, true);
        assert!(fd.nominal + fd.data > worst_case_bits(8));
        // And the CRC-21 above 16 bytes.
        assert_eq!(
            fd_bits(false, 20, false).data - fd_bits(false, 16, false).data,
            4 * 8 + 5
        );
    }
}
