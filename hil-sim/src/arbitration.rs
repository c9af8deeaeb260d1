//! The wire as the bus thread sees it: frames offered to it wait until it is idle, then the one
//! that wins arbitration (lowest [`wire::arbitration_key`], ties: the earlier offer) goes next and
//! takes its bits over the bit rate ([`WireConfig`]; an FD frame on a CAN FD wire its bits over
//! the two bit rates, [`BusWire`] of [`crate::wire_fd`]). Each frame's timestamp is its end of
//! frame (end of the intermission after it): when a receiver has it.
//!
//! The arbiter commits frames to the wire up to a horizon: the bus thread commits every frame that
//! has started by the wall clock (real time), or everything offered so far (lockstep: bus time is
//! virtual, and the virtual bus never waits for a client). A committed frame keeps its slot; the
//! frames still waiting are arbitrated afresh at every idle.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BTreeSet, BinaryHeap};

use dex_runtime::can::{AnyFrame, FdFrame};

use crate::wire;
#[cfg(doc)]
use crate::wire::WireConfig;
use crate::wire_fd::BusWire;

/// A frame given its slot on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OnWire<T> {
    /// When it was offered (ns of bus time).
    pub offered_ns: u64,
    /// Start of frame (ns).
    pub start_ns: u64,
    /// End of its intermission (ns): its timestamp, and the earliest the next frame starts.
    pub end_ns: u64,
    /// What was offered.
    pub item: T,
}

/// A frame waiting for the wire.
#[derive(Debug)]
struct Waiting<T> {
    offered_ns: u64,
    key: u32,
    /// Its time on the wire.
    ns: u64,
    item: T,
}

/// Frames waiting for one wire, and when it is next idle.
#[derive(Debug)]
pub struct Arbiter<T> {
    wire: BusWire,
    /// Offers not yet in arbitration, by offer time.
    future: BinaryHeap<Reverse<(u64, u64)>>,
    /// Offers in arbitration (offered by the wire's next idle), by (key, offer time, order).
    ready: BTreeSet<(u32, u64, u64)>,
    /// Every waiting offer, by its order number.
    waiting: BTreeMap<u64, Waiting<T>>,
    seq: u64,
    idle_from_ns: u64,
}

impl<T> Arbiter<T> {
    /// An idle wire: classic ([`WireConfig`]) or CAN FD ([`BusWire`]).
    pub fn new(wire: impl Into<BusWire>) -> Self {
        let wire = wire.into();
        Arbiter {
            wire,
            future: BinaryHeap::new(),
            ready: BTreeSet::new(),
            waiting: BTreeMap::new(),
            seq: 0,
            idle_from_ns: 0,
        }
    }

    /// The wire's settings.
    pub fn wire(&self) -> BusWire {
        self.wire
    }

    /// When the last committed frame ends (ns): the wire is idle from then on, if nothing waits.
    pub fn idle_from_ns(&self) -> u64 {
        self.idle_from_ns
    }

    /// Frames waiting for the wire.
    pub fn waiting(&self) -> usize {
        self.waiting.len()
    }

    /// Offers the classic frame `frame` (carried as `item`) to the wire at `offered_ns`.
    pub fn offer(&mut self, offered_ns: u64, frame: &impl embedded_can::Frame, item: T) {
        let ns = self.wire.nominal.frame_ns(frame);
        self.offer_timed(offered_ns, wire::arbitration_key(frame), ns, item);
    }

    /// Offers the FD frame `frame` at `offered_ns`: it arbitrates on its identifier as a classic
    /// data frame does (RRS dominant) and takes its bits over the two bit rates.
    pub fn offer_fd(&mut self, offered_ns: u64, frame: &FdFrame, item: T) {
        let ns = self.wire.fd_frame_ns(frame);
        self.offer_timed(offered_ns, wire::arbitration_key(frame), ns, item);
    }

    /// Offers a classic or an FD frame ([`Arbiter::offer`], [`Arbiter::offer_fd`]).
    pub fn offer_any(&mut self, offered_ns: u64, frame: &AnyFrame, item: T) {
        match frame {
            AnyFrame::Classic(f) => self.offer(offered_ns, f, item),
            AnyFrame::Fd(f) => self.offer_fd(offered_ns, f, item),
        }
    }

    fn offer_timed(&mut self, offered_ns: u64, key: u32, ns: u64, item: T) {
        self.seq += 1;
        self.waiting.insert(
            self.seq,
            Waiting {
                offered_ns,
                key,
                ns,
                item,
            },
        );
        self.future.push(Reverse((offered_ns, self.seq)));
    }

    /// When the next frame would start, if any waits.
    pub fn next_start_ns(&self) -> Option<u64> {
        if !self.ready.is_empty() {
            return Some(self.idle_from_ns);
        }
        self.future
            .peek()
            .map(|Reverse((t, _))| (*t).max(self.idle_from_ns))
    }

    /// Commits the next frame if it starts at or before `horizon_ns`: at the wire's next idle (or
    /// the first offer after it), the lowest key among the frames offered by then wins.
    pub fn commit_next(&mut self, horizon_ns: u64) -> Option<OnWire<T>> {
        let start = self.next_start_ns()?;
        if start > horizon_ns {
            return None;
        }
        while let Some(&Reverse((t, seq))) = self.future.peek() {
            if t > start {
                break;
            }
            self.future.pop();
            if let Some(w) = self.waiting.get(&seq) {
                self.ready.insert((w.key, w.offered_ns, seq));
            }
        }
        let (_, _, seq) = self.ready.pop_first()?;
        let w = self.waiting.remove(&seq)?;
        let end = start + w.ns;
        self.idle_from_ns = end;
        Some(OnWire {
            offered_ns: w.offered_ns,
            start_ns: start,
            end_ns: end,
            item: w.item,
        })
    }

    /// Commits every frame that starts at or before `horizon_ns`, in wire order.
    pub fn commit_until(&mut self, horizon_ns: u64) -> Vec<OnWire<T>> {
        std::iter::from_fn(|| self.commit_next(horizon_ns)).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::WireConfig;
    use dex_runtime::can::CanFrame;

    fn frame(id: u16, data: &[u8]) -> CanFrame {
        CanFrame::standard(id, data).expect("valid test frame")
    }

    const WIRE: WireConfig = WireConfig {
        bitrate: 500_000,
        stuffing: wire::Stuffing::WorstCase,
    };

    #[test]
    fn frames_offered_together_go_lowest_identifier_first_back_to_back() {
        let mut a = Arbiter::new(WIRE);
        for id in [0x290u16, 0x180, 0x200] {
            a.offer(1_000, &frame(id, &[0; 8]), id);
        }
        let on = a.commit_until(u64::MAX);
        assert_eq!(
            on.iter().map(|o| o.item).collect::<Vec<_>>(),
            [0x180, 0x200, 0x290]
        );
        assert_eq!(on[0].start_ns, 1_000);
        assert_eq!(on[1].start_ns, on[0].end_ns);
        assert_eq!(on[2].start_ns, on[1].end_ns);
        assert_eq!(
            on[0].end_ns - on[0].start_ns,
            270_000,
            "135 bits at 500 kbit/s"
        );
    }

    #[test]
    fn a_frame_offered_while_the_wire_is_busy_waits_and_the_lowest_wins_the_next_idle() {
        let mut a = Arbiter::new(WIRE);
        a.offer(0, &frame(0x300, &[0; 8]), "first");
        a.offer(0, &frame(0x400, &[0; 8]), "queued");
        // Real time: the first frame is committed when it starts; the second still waits.
        let first = a.commit_until(0);
        assert_eq!(first.len(), 1);
        // A lower identifier offered while the first is on the wire overtakes the waiting one.
        a.offer(100_000, &frame(0x100, &[0; 8]), "late, lower");
        let rest = a.commit_until(u64::MAX);
        assert_eq!(
            rest.iter().map(|o| o.item).collect::<Vec<_>>(),
            ["late, lower", "queued"]
        );
        assert_eq!(rest[0].start_ns, first[0].end_ns, "no pre-emption");
        assert_eq!(rest[1].start_ns, rest[0].end_ns);
    }

    #[test]
    fn fd_frames_take_their_bits_over_two_rates_and_arbitrate_with_classic_ones() {
        let fd = BusWire {
            nominal: WireConfig {
                bitrate: 1_000_000,
                stuffing: wire::Stuffing::WorstCase,
            },
            data_bitrate: Some(5_000_000),
        };
        let mut a = Arbiter::new(fd);
        let obs = FdFrame::standard(0x310, &[0; 48]).expect("48 bytes");
        let act = FdFrame::standard(0x190, &[0; 20]).expect("20 bytes");
        a.offer_fd(0, &obs, "observation");
        a.offer(0, &frame(0x700, &[5]), "heartbeat");
        a.offer_fd(0, &act, "action");
        let on = a.commit_until(u64::MAX);
        assert_eq!(
            on.iter().map(|o| o.item).collect::<Vec<_>>(),
            ["action", "observation", "heartbeat"]
        );
        let bits = crate::wire_fd::fd_bits(false, 48, true);
        assert_eq!(
            on[1].end_ns - on[1].start_ns,
            wire::bits_ns(bits.nominal, 1_000_000) + wire::bits_ns(bits.data, 5_000_000)
        );
        assert_eq!(on[1].start_ns, on[0].end_ns);
        assert_eq!(
            on[2].end_ns - on[2].start_ns,
            wire::bits_ns(wire::worst_case_bits(1), 1_000_000)
        );
    }

    #[test]
    fn an_idle_wire_starts_a_frame_when_it_is_offered() {
        let mut a = Arbiter::new(WIRE);
        a.offer(5_000, &frame(0x700, &[]), ());
        let on = a.commit_until(u64::MAX);
        assert_eq!((on[0].start_ns, on[0].offered_ns), (5_000, 5_000));
        a.offer(10_000_000, &frame(0x700, &[]), ());
        assert_eq!(a.next_start_ns(), Some(10_000_000));
        assert!(a.commit_until(9_999_999).is_empty(), "not started yet");
        assert_eq!(a.commit_until(10_000_000).len(), 1);
        assert_eq!(a.waiting(), 0);
    }
}
