//! Time on the wire of CAN FD frames (ISO 11898-1:2015, bit-rate switching on): the arbitration
//! phase and the frame's end at the nominal bit rate, the data phase at the data bit rate. A model
//! for budgets (`example wire_budget`); the virtual bus itself carries classic frames only.
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
//!   (a bound at most one bit above the exact worst case).

/// The data lengths an FD frame can have (DLC 0..=15).
pub const FD_LENGTHS: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

/// The shortest FD data length that holds `n` bytes, if any (at most 64).
pub fn fd_length(n: usize) -> Option<usize> {
    FD_LENGTHS.iter().copied().find(|&l| l >= n)
}

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
