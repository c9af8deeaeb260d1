//! Time on the wire of classic CAN frames: each frame's length in bits (worst-case or exact bit
//! stuffing) and a bus that sends one frame at a time, the lowest identifier first among those
//! waiting (arbitration). The model behind the wire-time figures of docs/benchmarks.md, and behind
//! the virtual bus's timestamps ([`crate::arbitration`], `hil-sim bus --bitrate`).
//!
//! A classic data frame with an 11-bit identifier and `n` data bytes has `34 + 8n` bits from the
//! start of frame to the end of the CRC, the part bit stuffing applies to (a complementary bit after
//! five equal ones), then 13 fixed bits: CRC delimiter, ACK slot and delimiter, 7 bits of end of
//! frame, 3 of intermission. Worst-case stuffing adds `floor((34 + 8n - 1) / 4)` bits: 135 bits
//! for 8 data bytes, 270 us at 500 kbit/s.

use embedded_can::{Frame, Id};

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
    push_bits(&mut bits, u32::from(id), 11);
    bits.extend([false, false, false]); // RTR (data frame), IDE (standard), r0
    push_bits(&mut bits, data.len() as u32, 4);
    for byte in data {
        push_bits(&mut bits, u32::from(*byte), 8);
    }
    unstuffed_bits(data.len()) + stuff_bits_with_crc(bits)
}

/// Appends the low `n` bits of `value`, most significant first.
pub(crate) fn push_bits(bits: &mut Vec<bool>, value: u32, n: u32) {
    for k in (0..n).rev() {
        bits.push((value >> k) & 1 == 1);
    }
}

/// The positions in `bits` after which a transmitter inserts a stuff bit (after five equal
/// bits; the stuff bit is their complement and starts the next run). Classic and FD frames
/// count their dynamic stuff bits with it.
pub(crate) fn stuff_positions(bits: &[bool]) -> impl Iterator<Item = usize> + '_ {
    let (mut run, mut last) = (0, None);
    bits.iter().enumerate().filter_map(move |(i, &b)| {
        if Some(b) == last {
            run += 1;
        } else {
            run = 1;
            last = Some(b);
        }
        (run == 5).then(|| {
            last = Some(!b);
            run = 1;
            i
        })
    })
}

/// Appends the CRC-15 of `bits` and counts the stuff bits of the whole run.
fn stuff_bits_with_crc(mut bits: Vec<bool>) -> u32 {
    let mut crc: u16 = 0;
    for &b in &bits {
        let top = (crc >> 14) & 1 == 1;
        crc = (crc << 1) & 0x7FFF;
        if b ^ top {
            crc ^= 0x4599;
        }
    }
    push_bits(&mut bits, u32::from(crc), 15);
    stuff_positions(&bits).count() as u32
}

/// How the bus counts a frame's stuff bits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Stuffing {
    /// The frame's own stuff bits (its bit stream built and counted): what the wire really
    /// carries for this identifier and data, as a bus analyser would time it.
    #[default]
    Exact,
    /// The most stuff bits a frame of its length can carry: the bound a schedulability analysis
    /// uses.
    WorstCase,
}

/// The wire of a classic CAN bus: bit rate and how stuff bits are counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WireConfig {
    /// Bits per second (classic CAN: at most 1,000,000).
    pub bitrate: u32,
    /// Stuff bits of each frame.
    pub stuffing: Stuffing,
}

impl Default for WireConfig {
    /// The classic 500 kbit/s of issue #30, each frame's exact stuffing.
    fn default() -> Self {
        WireConfig {
            bitrate: 500_000,
            stuffing: Stuffing::Exact,
        }
    }
}

impl WireConfig {
    /// This frame's bits on this wire.
    pub fn bits(&self, frame: &impl Frame) -> u32 {
        frame_bits(frame, self.stuffing)
    }

    /// This frame's time on this wire, start of frame to the end of its intermission (ns).
    pub fn frame_ns(&self, frame: &impl Frame) -> u64 {
        bits_ns(self.bits(frame), self.bitrate)
    }
}

/// Unstuffed bits from the start of frame to the end of the CRC (where stuffing applies) of a
/// classic frame: 34 + 8n with an 11-bit identifier, 54 + 8n with a 29-bit one (n data bytes;
/// none for a remote frame).
const fn stuffable_bits(extended: bool, data_len: usize) -> u32 {
    (if extended { 54 } else { 34 }) + 8 * data_len as u32
}

/// The bits of a classic frame (standard or extended identifier, data or remote) with the given
/// stuffing, intermission included: the stuffable part, 13 fixed bits (CRC delimiter, ACK slot
/// and delimiter, end of frame, intermission), and its stuff bits.
pub fn frame_bits(frame: &impl Frame, stuffing: Stuffing) -> u32 {
    let remote = frame.is_remote_frame();
    let data: &[u8] = if remote { &[] } else { frame.data() };
    let data = &data[..data.len().min(8)];
    let (extended, raw) = match frame.id() {
        Id::Standard(s) => (false, u32::from(s.as_raw())),
        Id::Extended(e) => (true, e.as_raw()),
    };
    let stuffable = stuffable_bits(extended, data.len());
    let stuff = match stuffing {
        Stuffing::WorstCase => (stuffable - 1) / 4,
        Stuffing::Exact => {
            let mut bits: Vec<bool> = Vec::with_capacity(stuffable as usize);
            bits.push(false); // start of frame
            if extended {
                push_bits(&mut bits, raw >> 18, 11);
                bits.extend([true, true]); // SRR, IDE
                push_bits(&mut bits, raw & 0x3_FFFF, 18);
                bits.extend([remote, false, false]); // RTR, r1, r0
            } else {
                push_bits(&mut bits, raw, 11);
                bits.extend([remote, false, false]); // RTR, IDE (standard), r0
            }
            push_bits(&mut bits, frame.dlc().min(15) as u32, 4);
            for byte in data {
                push_bits(&mut bits, u32::from(*byte), 8);
            }
            stuff_bits_with_crc(bits)
        }
    };
    stuffable + 13 + stuff
}

/// The frame's place in arbitration, lower wins: the arbitration field's bits as a number
/// (11-bit base identifier, then RTR or SRR, IDE, the 18 identifier extension bits and the
/// extended frame's RTR). A standard data frame beats a remote frame and an extended frame of
/// the same base identifier, as on the wire (a dominant bit is 0).
pub fn arbitration_key(frame: &impl Frame) -> u32 {
    let remote = u32::from(frame.is_remote_frame());
    match frame.id() {
        Id::Standard(s) => (u32::from(s.as_raw()) << 21) | (remote << 20),
        Id::Extended(e) => {
            let raw = e.as_raw();
            ((raw >> 18) << 21) | (1 << 20) | (1 << 19) | ((raw & 0x3_FFFF) << 1) | remote
        }
    }
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
    fn frame_bits_cover_standard_and_extended_frames() {
        use dex_runtime::can::CanFrame;
        use embedded_can::ExtendedId;
        for (id, fill) in [
            (0x000u16, 0x00u8),
            (0x123, 0xA5),
            (0x7FF, 0xFF),
            (0x210, 0x3C),
        ] {
            let f = CanFrame::standard(id, &[fill; 8]).expect("valid");
            assert_eq!(frame_bits(&f, Stuffing::Exact), exact_bits(id, &[fill; 8]));
            assert_eq!(frame_bits(&f, Stuffing::WorstCase), worst_case_bits(8));
        }
        // 29-bit identifiers: 20 more bits (SRR, IDE, 18 extension bits), 67 + 8n unstuffed.
        let e = CanFrame::new(ExtendedId::new(0x1ABC_DEF0).expect("29 bits"), &[0x55; 4])
            .expect("valid");
        assert_eq!(
            frame_bits(&e, Stuffing::WorstCase),
            67 + 32 + (54 + 32 - 1) / 4
        );
        let exact = frame_bits(&e, Stuffing::Exact);
        assert!(
            (67 + 32..=67 + 32 + (54 + 32 - 1) / 4).contains(&exact),
            "{exact}"
        );
    }

    #[test]
    fn arbitration_follows_the_arbitration_field() {
        use dex_runtime::can::CanFrame;
        use embedded_can::ExtendedId;
        let std = |id| CanFrame::standard(id, &[]).expect("valid");
        let ext = |id| CanFrame::new(ExtendedId::new(id).expect("29 bits"), &[]).expect("valid");
        assert!(arbitration_key(&std(0x100)) < arbitration_key(&std(0x101)));
        // Same 11-bit base: the standard frame wins (SRR and IDE recessive in the extended one).
        assert!(arbitration_key(&std(0x100)) < arbitration_key(&ext(0x100 << 18)));
        // A lower base wins whatever follows.
        assert!(arbitration_key(&ext(0x0FF << 18 | 0x3_FFFF)) < arbitration_key(&std(0x100)));
        assert!(arbitration_key(&ext(1)) < arbitration_key(&ext(2)));
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
