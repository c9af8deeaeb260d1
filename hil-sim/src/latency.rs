//! Observation to action in bus time, from the frame trace (candump log) of a timed bus: for every
//! observation of a controller, from when the plant queued it to the end of frame of its last
//! action frame, split into the two groups' own time on the wire, the controller's compute, and
//! queuing (the rest: the time the loop waited for other frames on the wire, such as the lockstep
//! SYNC ahead of the observation, an emergency that won arbitration over the actions, or other
//! nodes' traffic).
//!
//! A cycle starts at the start of frame of the first frame of its observation, or of the SYNC
//! (0x080) right before it when nothing came between (the plant queues them together). Start of
//! frame is end of frame less the frame's time on the wire ([`WireConfig`]), so the trace must
//! come from a bus with the same wire settings; the compute is given (the lockstep node's
//! [`crate::compute::StepCompute`]), and a trace whose loop is shorter than its wire time and that
//! compute is refused. A CAN FD bus's trace ([`analyse_any`]) in the FD layout: the observation's
//! two FD frames and the one FD action frame, each timed over the two bit rates ([`BusWire`]).

use dex_runtime::can::fd_messages::{fd_action_frame_index, fd_observation_frame_index};
use dex_runtime::can::messages::{action_frame_index, observation_frame_index};
use dex_runtime::can::{AnyFrame, CanFrame, FrameLayout};

use crate::bench::Percentiles;
use crate::node::SYNC_ID;
use crate::wire::WireConfig;
use crate::wire_fd::BusWire;

/// Rounding allowed between the trace's microsecond timestamps and the nanosecond wire model.
const TOLERANCE_NS: u64 = 3_000;

/// Errors of the analysis.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LatencyError {
    /// A line of the trace is not a candump frame line.
    #[error("trace line {line}: not a candump frame line: {text}")]
    Parse {
        /// 1-based line number.
        line: usize,
        /// The line.
        text: String,
    },
    /// A cycle took less than its frames' wire time and the compute: the trace comes from another
    /// bit rate, stuffing or compute than the analysis was given.
    #[error(
        "cycle {cycle}: {total_ns} ns from observation to action, less than its wire time \
         {wire_ns} ns + compute {compute_ns} ns (another bit rate, stuffing or compute?)"
    )]
    Inconsistent {
        /// Index of the cycle.
        cycle: usize,
        /// Its observation-to-action time.
        total_ns: u64,
        /// Its frames' wire time.
        wire_ns: u64,
        /// The compute given.
        compute_ns: u64,
    },
    /// No observation in the trace was answered.
    #[error("no answered observation of node {0} in the trace")]
    Empty(u8),
}

/// One observation and its answer, in nanoseconds of bus time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CycleLatency {
    /// From the observation's queuing to the end of its last action frame.
    pub total_ns: u64,
    /// The observation's frames' own time on the wire.
    pub observation_wire_ns: u64,
    /// The action frames' own time on the wire.
    pub action_wire_ns: u64,
    /// The controller's compute.
    pub compute_ns: u64,
    /// The rest: waiting for other frames on the wire.
    pub queuing_ns: u64,
}

impl CycleLatency {
    /// Both groups' time on the wire.
    pub fn wire_ns(&self) -> u64 {
        self.observation_wire_ns + self.action_wire_ns
    }
}

/// Every answered observation of a trace, and the observations that got no complete answer.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LatencyReport {
    /// Answered observations, in trace order.
    pub cycles: Vec<CycleLatency>,
    /// Complete observations with no complete answer before the next observation.
    pub unanswered: usize,
}

/// p50/p99/max in microseconds of one part of every cycle.
fn percentiles_us(cycles: &[CycleLatency], part: impl Fn(&CycleLatency) -> u64) -> Percentiles {
    let mut v: Vec<f64> = cycles.iter().map(|c| part(c) as f64 / 1e3).collect();
    Percentiles::of(&mut v)
}

impl LatencyReport {
    /// Percentiles (us) of observation to action.
    pub fn total_us(&self) -> Percentiles {
        percentiles_us(&self.cycles, |c| c.total_ns)
    }
    /// Percentiles (us) of the wire time.
    pub fn wire_us(&self) -> Percentiles {
        percentiles_us(&self.cycles, CycleLatency::wire_ns)
    }
    /// Percentiles (us) of the observation's wire time.
    pub fn observation_wire_us(&self) -> Percentiles {
        percentiles_us(&self.cycles, |c| c.observation_wire_ns)
    }
    /// Percentiles (us) of the actions' wire time.
    pub fn action_wire_us(&self) -> Percentiles {
        percentiles_us(&self.cycles, |c| c.action_wire_ns)
    }
    /// Percentiles (us) of the compute.
    pub fn compute_us(&self) -> Percentiles {
        percentiles_us(&self.cycles, |c| c.compute_ns)
    }
    /// Percentiles (us) of the queuing.
    pub fn queuing_us(&self) -> Percentiles {
        percentiles_us(&self.cycles, |c| c.queuing_ns)
    }
}

/// Reads a candump log (as the bus writes it with `--log`).
pub fn parse_trace(text: &str) -> Result<Vec<(u64, CanFrame)>, LatencyError> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            crate::protocol::parse_candump_line(l).ok_or_else(|| LatencyError::Parse {
                line: i + 1,
                text: l.to_string(),
            })
        })
        .collect()
}

/// Reads a candump log with classic and FD frames (as a `--fd` bus writes it with `--log`).
pub fn parse_trace_any(text: &str) -> Result<Vec<(u64, AnyFrame)>, LatencyError> {
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            crate::protocol::parse_candump_any(l).ok_or_else(|| LatencyError::Parse {
                line: i + 1,
                text: l.to_string(),
            })
        })
        .collect()
}

/// The observation being assembled, and its answer.
#[derive(Debug, Default)]
struct Cycle {
    start_ns: u64,
    obs_mask: u32,
    obs_wire_ns: u64,
    act_mask: u32,
    act_wire_ns: u64,
}

/// The cycles of controller `node` in `trace` (bus time in microseconds and frame, in bus
/// order), on a wire `wire`, with `compute_ns` of controller compute per answer.
pub fn analyse(
    trace: &[(u64, CanFrame)],
    node: u8,
    wire: WireConfig,
    compute_ns: u64,
) -> Result<LatencyReport, LatencyError> {
    let trace: Vec<(u64, AnyFrame)> = trace
        .iter()
        .map(|(ts, f)| (*ts, AnyFrame::Classic(*f)))
        .collect();
    analyse_any(&trace, node, FrameLayout::Classic, wire.into(), compute_ns)
}

/// [`analyse`] for a trace of classic and FD frames whose controller speaks `layout`, on the wire
/// `wire` (an FD frame's time over its two bit rates).
pub fn analyse_any(
    trace: &[(u64, AnyFrame)],
    node: u8,
    layout: FrameLayout,
    wire: BusWire,
    compute_ns: u64,
) -> Result<LatencyReport, LatencyError> {
    let all_obs = (1u32 << layout.observation_frames()) - 1;
    let all_act = (1u32 << layout.action_frames()) - 1;
    // A frame of the layout's kind on one of its identifiers.
    let observation = |frame: &AnyFrame, id: u16| match (layout, frame) {
        (FrameLayout::Classic, AnyFrame::Classic(_)) => observation_frame_index(node, id),
        (FrameLayout::Fd, AnyFrame::Fd(_)) => fd_observation_frame_index(node, id),
        _ => None,
    };
    let action = |frame: &AnyFrame, id: u16| match (layout, frame) {
        (FrameLayout::Classic, AnyFrame::Classic(_)) => action_frame_index(node, id),
        (FrameLayout::Fd, AnyFrame::Fd(_)) => fd_action_frame_index(node, id),
        _ => None,
    };
    let mut report = LatencyReport::default();
    let mut cycle: Option<Cycle> = None;
    // Start of frame of the SYNC that ended just now, and its end.
    let mut sync: Option<(u64, u64)> = None;
    for (ts_us, frame) in trace {
        let end_ns = ts_us * 1000;
        let start_ns = end_ns.saturating_sub(wire.frame_ns(frame));
        let id = frame.standard_id();
        if id == Some(SYNC_ID) {
            sync = Some((start_ns, end_ns));
            continue;
        }
        if let Some(k) = id.and_then(|id| observation(frame, id)) {
            let fresh = cycle.as_ref().is_none_or(|c| c.obs_mask == all_obs);
            if fresh {
                if cycle.as_ref().is_some_and(|c| c.act_mask != all_act) {
                    report.unanswered += 1;
                }
                let start_ns = match sync {
                    Some((s, e)) if start_ns.abs_diff(e) <= TOLERANCE_NS => s,
                    _ => start_ns,
                };
                cycle = Some(Cycle {
                    start_ns,
                    ..Cycle::default()
                });
            }
            if let Some(c) = cycle.as_mut() {
                c.obs_mask |= 1 << k;
                c.obs_wire_ns += wire.frame_ns(frame);
            }
        } else if let Some(k) = id.and_then(|id| action(frame, id))
            && let Some(c) = cycle.as_mut()
            && c.obs_mask == all_obs
            && c.act_mask != all_act
        {
            c.act_mask |= 1 << k;
            c.act_wire_ns += wire.frame_ns(frame);
            if c.act_mask == all_act {
                let total_ns = end_ns.saturating_sub(c.start_ns);
                let wire_ns = c.obs_wire_ns + c.act_wire_ns;
                if total_ns + TOLERANCE_NS < wire_ns + compute_ns {
                    return Err(LatencyError::Inconsistent {
                        cycle: report.cycles.len(),
                        total_ns,
                        wire_ns,
                        compute_ns,
                    });
                }
                report.cycles.push(CycleLatency {
                    total_ns,
                    observation_wire_ns: c.obs_wire_ns,
                    action_wire_ns: c.act_wire_ns,
                    compute_ns,
                    queuing_ns: total_ns.saturating_sub(wire_ns + compute_ns),
                });
            }
        }
        sync = None;
    }
    if cycle.as_ref().is_some_and(|c| c.act_mask != all_act) {
        report.unanswered += 1;
    }
    if report.cycles.is_empty() {
        return Err(LatencyError::Empty(node));
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arbitration::Arbiter;
    use crate::wire::Stuffing;
    use dex_runtime::can::messages::{ACTION_FRAMES, OBS_FRAMES, rpdo_cob_id, tpdo_cob_id};

    const NODE: u8 = 0x10;
    const WIRE: WireConfig = WireConfig {
        bitrate: 500_000,
        stuffing: Stuffing::WorstCase,
    };

    fn frame(id: u16) -> CanFrame {
        CanFrame::standard(id, &[0x5A; 8]).expect("valid test frame")
    }

    /// One cycle through the arbiter: SYNC and observation at `t`, then `extra` frames offered
    /// with the actions after `compute`.
    fn cycle(
        a: &mut Arbiter<CanFrame>,
        t: u64,
        compute: u64,
        extra: &[u16],
    ) -> Vec<(u64, CanFrame)> {
        let mut out = Vec::new();
        let sync = CanFrame::standard(SYNC_ID, &[]).expect("sync");
        a.offer(t, &sync, sync);
        for k in 0..OBS_FRAMES {
            let f = frame(rpdo_cob_id(NODE, k));
            a.offer(t, &f, f);
        }
        let on = a.commit_until(u64::MAX);
        let obs_end = on.last().map_or(t, |o| o.end_ns);
        out.extend(on.into_iter().map(|o| (o.end_ns / 1000, o.item)));
        for id in (0..ACTION_FRAMES)
            .map(|k| tpdo_cob_id(NODE, k))
            .chain(extra.iter().copied())
        {
            let f = frame(id);
            a.offer(obs_end + compute, &f, f);
        }
        out.extend(
            a.commit_until(u64::MAX)
                .into_iter()
                .map(|o| (o.end_ns / 1000, o.item)),
        );
        out
    }

    #[test]
    fn a_cycle_splits_into_wire_compute_and_queuing() {
        let mut a = Arbiter::new(WIRE);
        let mut trace = cycle(&mut a, 50_000_000, 3_000_000, &[]);
        // An emergency (0x090) offered with the actions wins arbitration: it is queuing.
        trace.extend(cycle(&mut a, 100_000_000, 3_000_000, &[0x090]));
        let r = analyse(&trace, NODE, WIRE, 3_000_000).expect("consistent trace");
        assert_eq!(r.cycles.len(), 2);
        assert_eq!(r.unanswered, 0);
        let frame_ns = 270_000;
        let sync_ns = crate::wire::bits_ns(crate::wire::worst_case_bits(0), 500_000);
        for c in &r.cycles {
            assert_eq!(c.observation_wire_ns, OBS_FRAMES as u64 * frame_ns);
            assert_eq!(c.action_wire_ns, ACTION_FRAMES as u64 * frame_ns);
            assert_eq!(c.compute_ns, 3_000_000);
        }
        assert!(
            r.cycles[0].queuing_ns.abs_diff(sync_ns) < 2_000,
            "{:?}",
            r.cycles[0]
        );
        assert!(
            r.cycles[1].queuing_ns.abs_diff(sync_ns + frame_ns) < 2_000,
            "{:?}",
            r.cycles[1]
        );
        // The wrong compute does not fit the trace.
        assert!(matches!(
            analyse(&trace, NODE, WIRE, 4_000_000),
            Err(LatencyError::Inconsistent { .. })
        ));
        // Another node's frames are not this node's cycles.
        assert_eq!(
            analyse(&trace, 0x11, WIRE, 0),
            Err(LatencyError::Empty(0x11))
        );
    }

    #[test]
    fn an_unanswered_observation_is_counted() {
        let mut a = Arbiter::new(WIRE);
        let mut trace = cycle(&mut a, 0, 1_000, &[]);
        let unanswered: Vec<_> = cycle(&mut a, 50_000_000, 1_000, &[])
            .into_iter()
            .filter(|(_, f)| {
                f.standard_id()
                    .is_some_and(|id| action_frame_index(NODE, id).is_none())
            })
            .collect();
        trace.extend(unanswered);
        trace.extend(cycle(&mut a, 100_000_000, 1_000, &[]));
        let r = analyse(&trace, NODE, WIRE, 1_000).expect("consistent trace");
        assert_eq!((r.cycles.len(), r.unanswered), (2, 1));
        let text: String = trace
            .iter()
            .map(|(ts, f)| crate::protocol::candump_line("vcan0", f, *ts) + "\n")
            .collect();
        assert_eq!(parse_trace(&text), Ok(trace));
        assert!(matches!(
            parse_trace("(0.1) vcan0 123#00\nnot a frame\n"),
            Err(LatencyError::Parse { line: 2, .. })
        ));
    }
}
