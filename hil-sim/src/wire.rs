//! Time on the wire of classic CAN frames: each frame's length in bits (worst-case or exact bit
//! stuffing) and a bus that sends one frame at a time, the lowest identifier first among those
//! waiting (arbitration). The model behind the wire-time figures of docs/benchmarks.md; the virtual
//! bus itself does not use it yet (issue #30).
//!
//! A classic data frame with an 11-bit identifier and `n` data bytes has `34 + 8n` bits from the
//! start of frame to the end of the CRC, the part bit stuffing applies to (a complementary bit after
//! five equal ones), then 13 fixed bits: CRC delimiter, ACK slot and delimiter, 7 bits of end of
//! frame, 3 of intermission. Worst-case stuffing adds `floor((34 + 8n - 1) / 4)` bits: 135 bits
//! for 8 data bytes, 270 us at 500 kbit/s.

/// Bits of a classic frame with an 11-bit identifier and `data_len` bytes (at most 8), without
/// stuffing (intermission included).
pub const fn unstuffed_bits(data_len: usize) -> u32 {
    47 + 8 * data_len as u32
}

/// The most stuff bits such a frame can carry.
pub const fn worst_case_stuff_bits(data_len: usize) -> u32 {
    (34 + 8 * data_len as u32 - 1) / 4
}

/// Worst-case length in bits (stuffing included) of a classic frame with `data_len` bytes.
pub const fn worst_case_bits(data_len: usize) -> u32 {
    unstuffed_bits(data_len) + worst_case_stuff_bits(data_len)
}

/// The stuffed bits of this very frame: the bit stream from the start of frame to the end of the
/// CRC-15 (polynomial 0x4599) is built and a complementary bit counted after every five equal
/// bits (stuff bits count towards the next run, as on the wire). `id` is the 11-bit identifier.
pub fn exact_bits(id: u16, data: &[u8]) -> u32 {
    let data = &data[..data.len().min(8)];
    let mut bits: Vec<bool> = Vec::with_capacity(34 + 64);
    bits.push(false); // start of frame
    for k in (0..11).rev() {
        bits.push((id >> k) & 1 == 1);
    }
    bits.extend([false, false, false]); // RTR (data frame), IDE (standard), r0
    for k in (0..4).rev() {
        bits.push((data.len() >> k) & 1 == 1);
    }
    for byte in data {
        for k in (0..8).rev() {
            bits.push((byte >> k) & 1 == 1);
        }
    }
    let mut crc: u16 = 0;
    for &b in &bits {
        let top = (crc >> 14) & 1 == 1;
        crc = (crc << 1) & 0x7FFF;
        if b ^ top {
            crc ^= 0x4599;
        }
    }
    for k in (0..15).rev() {
        bits.push((crc >> k) & 1 == 1);
    }
    let mut stuffed = 0;
    let (mut run, mut last) = (0, None);
    for b in bits {
        if Some(b) == last {
            run += 1;
        } else {
            run = 1;
            last = Some(b);
        }
        if run == 5 {
            stuffed += 1;
            // The stuff bit is the complement, and starts the next run.
            last = Some(!b);
            run = 1;
        }
    }
    unstuffed_bits(data.len()) + stuffed
}

/// Nanoseconds `bits` take at `bitrate` bits per second (rounded up).
pub fn bits_ns(bits: u32, bitrate: u32) -> u64 {
    (u64::from(bits) * 1_000_000_000).div_ceil(u64::from(bitrate.max(1)))
}

/// A frame offered to the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Offer {
    /// When the sender queued it (ns).
    pub ready_ns: u64,
    /// Identifier (lower wins arbitration).
    pub id: u16,
    /// Its length in bits.
    pub bits: u32,
}

/// When a frame was on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    /// Start of frame (ns).
    pub start_ns: u64,
    /// End of its intermission (ns): the time it is received, and the earliest the next starts.
    pub end_ns: u64,
}

/// Puts `offers` on a bus of `bitrate` that is idle from `idle_from_ns`: whenever the bus is free,
/// the frame with the lowest identifier among those ready goes next (ties: the earlier offer).
/// Returns each offer's slot, in the order of `offers`.
pub fn schedule(offers: &[Offer], bitrate: u32, idle_from_ns: u64) -> Vec<Slot> {
    let mut slots = vec![None; offers.len()];
    let mut t = idle_from_ns;
    for _ in 0..offers.len() {
        let pending = || (0..offers.len()).filter(|&i| slots[i].is_none());
        let earliest = pending().map(|i| offers[i].ready_ns).min().unwrap_or(t);
        t = t.max(earliest);
        let Some(next) = pending()
            .filter(|&i| offers[i].ready_ns <= t)
            .min_by_key(|&i| (offers[i].id, offers[i].ready_ns, i))
        else {
            break;
        };
        let end = t + bits_ns(offers[next].bits, bitrate);
        slots[next] = Some(Slot {
            start_ns: t,
            end_ns: end,
        });
        t = end;
    }
    slots
        .into_iter()
        .map(|s| {
            s.unwrap_or(Slot {
                start_ns: t,
                end_ns: t,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worst_case_lengths_match_the_standard_figures() {
        assert_eq!(worst_case_bits(8), 135);
        assert_eq!(worst_case_bits(0), 55);
        assert_eq!(bits_ns(135, 500_000), 270_000);
        // An exact length is never above the worst case, and all-zero data stuffs a lot.
        for id in [0x000, 0x123, 0x7FF] {
            for len in 0..=8 {
                for fill in [0x00u8, 0xFF, 0xA5, 0x3C] {
                    let b = exact_bits(id, &vec![fill; len]);
                    assert!(
                        b >= unstuffed_bits(len) && b <= worst_case_bits(len),
                        "{id} {len} {fill}"
                    );
                }
            }
        }
        assert!(exact_bits(0x000, &[0; 8]) > exact_bits(0x2AA, &[0x55; 8]));
    }

    #[test]
    fn a_frames_time_is_its_bits_over_the_bitrate() {
        for bitrate in [125_000u32, 500_000, 1_000_000] {
            let bit_ns = 1_000_000_000 / u64::from(bitrate);
            let s = schedule(
                &[Offer {
                    ready_ns: 1_000,
                    id: 0x210,
                    bits: 111,
                }],
                bitrate,
                0,
            );
            let took = s[0].end_ns - s[0].start_ns;
            assert!(took.abs_diff(111 * bit_ns) < bit_ns, "{bitrate}: {took}");
            assert_eq!(s[0].start_ns, 1_000);
        }
    }

    #[test]
    fn the_lower_identifier_goes_first_and_frames_do_not_overlap() {
        let offers = [
            Offer {
                ready_ns: 0,
                id: 0x290,
                bits: 135,
            },
            Offer {
                ready_ns: 0,
                id: 0x180,
                bits: 135,
            },
            Offer {
                ready_ns: 0,
                id: 0x200,
                bits: 100,
            },
        ];
        let s = schedule(&offers, 500_000, 0);
        assert_eq!(s[1].start_ns, 0, "0x180 wins");
        assert_eq!(s[2].start_ns, s[1].end_ns, "then 0x200");
        assert_eq!(s[0].start_ns, s[2].end_ns, "0x290 last");
        // A frame queued while the bus is busy waits; timestamps are a frame apart at least.
        let late = [
            Offer {
                ready_ns: 0,
                id: 0x300,
                bits: 135,
            },
            Offer {
                ready_ns: 10_000,
                id: 0x001,
                bits: 135,
            },
        ];
        let s = schedule(&late, 500_000, 0);
        assert_eq!(
            s[1].start_ns, s[0].end_ns,
            "no pre-emption of a frame on the wire"
        );
        assert!(s[1].end_ns - s[0].end_ns >= bits_ns(55, 500_000));
    }
}
