//! The checks after every step: the invariants below, then the comparison with the reference model
//! ([`super::model`]): every frame, the state, the latched fault, the bus-off flag, the diagnostic
//! counters, the policy identity and the last action. A violation or a difference panics.
//!
//! # Invariants
//!
//! Model-free, from `docs/runtime.md` and the controller's documentation:
//! 1. Safe action whenever not operational: outside `Operational`, `last_action()` is zero, and every
//!    action frame sent by a step that ends outside `Operational` carries zero velocity.
//! 2. No action from an incomplete or mismatched sample: a non-zero (policy) action leaves the
//!    controller only in answer to an observation frame, in `Operational`, tagged with that frame's
//!    sample nibble, and only when that frame completed a sample whose 15 frames all passed the E2E
//!    check with that nibble (the reference model below tracks the accepted frames).
//! 3. No non-finite action: no action signal is "not available" (raw -32768) and `last_action()` is
//!    finite.
//! 4. Watchdog: after every `poll` in `Operational`, the newest complete observation (or the NMT
//!    start) is less than `watchdog_cycles + 1` periods old; a cycle boundary that finds it older
//!    than `watchdog_cycles` periods leaves `Operational` for `SafeStop` with fault
//!    `ObservationTimeout` and emergency 0x8250.
//! 5. Legal transitions only (the state table of `docs/runtime.md`): poll: Boot -> PreOperational,
//!    Operational -> SafeStop; NMT start: PreOperational/SafeStop -> Operational; NMT stop:
//!    PreOperational/Operational -> SafeStop; NMT pre-op: Operational/SafeStop -> PreOperational;
//!    NMT reset node/communication: any -> Boot; observation frame: Operational -> SafeStop/Fault;
//!    bus-off: Operational -> PreOperational; recovery and policy loads change no state. `Fault` is
//!    left by NMT reset only; never `Operational` while bus-off, nor without a policy.
//! 6. Frames sent are well-formed: only the controller's identifiers (its TPDOs, emergency and
//!    heartbeat, all derived from its node id); E2E-protected ones (action, policy info and status
//!    TPDOs with the CRC in byte 0, the emergency with it in byte 7) have a correct CRC and an
//!    alive counter that advances by one per identifier (restarting at 0 after NMT reset
//!    communication); the three action frames go together with one sample nibble; a heartbeat is
//!    one byte (CiA 301); the emergency's error register is 0 exactly when no error is latched;
//!    at most 7 frames per call (the `Outbox` holds 10, and frames past it would be lost
//!    silently).
//! 7. Policy loads: refused while operational (`LoadError::Operational`), and a refused file leaves
//!    the active policy (its identity and its actions) in place; a transfer whose bytes differ from

use dex_runtime::can::e2e::{E2eLayout, crc8, crc8_in, next_counter};
use dex_runtime::can::messages::{
    ACTION_FRAMES, EMCY_BASE_ID, HEARTBEAT_BASE_ID, NmtCommand, POLICY_INFO_TPDO,
    RAW_NOT_AVAILABLE, SIGNALS_PER_FRAME, STATUS_LEN, STATUS_TPDO, tpdo_cob_id,
};
use dex_runtime::interface::ACT_DIM;
use dex_runtime::{Clock, Outbox, State};
use embedded_can::Frame;

use super::PERIOD;
use super::model::Out;
use super::run::Run;
use super::stats::count_step;

/// What happened to the controller in one step, for the transition check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Event {
    Poll,
    Nmt(Option<NmtCommand>),
    Observation,
    BusOff,
    BusRecovered,
    Load,
    Other,
}

impl<'p> Run<'p> {
    /// Parses an outbox, checking invariants 3 and 6 on the way.
    fn parse(&mut self, out: &Outbox) -> Vec<Out> {
        assert!(out.len() <= 7, "{} frames in one outbox", out.len());
        let node = self.model.cfg.node_id;
        let mut parsed = Vec::new();
        let mut i = 0;
        while i < out.len() {
            let f = &out[i];
            let id = f
                .standard_id()
                .expect("the controller sends standard frames");
            let data = f.data();
            let sealed = |id: u16, data: &[u8], next: &mut u8| {
                let len = if id == tpdo_cob_id(node, STATUS_TPDO) {
                    STATUS_LEN
                } else {
                    8
                };
                assert_eq!(
                    data.len(),
                    len,
                    "protected frame {id:#x} of {} bytes",
                    data.len()
                );
                let (crc, counter) = if id == EMCY_BASE_ID + u16::from(node) {
                    (crc8_in(E2eLayout::Tail, id, data), data[6] & 0x0F)
                } else {
                    (crc8(id, data), data[1] & 0x0F)
                };
                let at = if id == EMCY_BASE_ID + u16::from(node) { 7 } else { 0 };
                assert_eq!(crc, data[at], "wrong CRC on sent frame {id:#x}");
                assert_eq!(counter, *next, "alive counter of {id:#x}");
                *next = next_counter(*next);
            };
            if id == tpdo_cob_id(node, 0) {
                assert!(i + ACTION_FRAMES <= out.len(), "action frames split");
                let mut raw = [0i16; ACT_DIM];
                let sample = data[1] >> 4;
                for k in 0..ACTION_FRAMES {
                    let g = &out[i + k];
                    assert_eq!(g.standard_id(), Some(tpdo_cob_id(node, k)));
                    let d = g.data();
                    sealed(tpdo_cob_id(node, k), d, &mut self.tx_action[k]);
                    assert_eq!(d[1] >> 4, sample, "action frames of one action disagree");
                    for s in 0..SIGNALS_PER_FRAME {
                        let j = k * SIGNALS_PER_FRAME + s;
                        let r = i16::from_le_bytes([d[2 + 2 * s], d[3 + 2 * s]]);
                        assert_ne!(r, RAW_NOT_AVAILABLE, "non-finite action sent (joint {j})");
                        if j < ACT_DIM {
                            raw[j] = r;
                        }
                    }
                }
                parsed.push(Out::Action { sample, raw });
                i += ACTION_FRAMES;
                continue;
            }
            if id == EMCY_BASE_ID + u16::from(node) {
                sealed(id, data, &mut self.tx_emcy);
                assert_eq!(data[5], 0, "reserved emergency byte");
                assert_eq!(data[6] >> 4, 0, "emergency counter byte's high nibble");
                parsed.push(Out::Emcy {
                    code: u16::from_le_bytes([data[0], data[1]]),
                    register: data[2],
                    fault: data[3],
                    state: data[4],
                });
            } else if id == tpdo_cob_id(node, POLICY_INFO_TPDO) {
                sealed(id, data, &mut self.tx_info);
                parsed.push(Out::Info {
                    hash: u32::from_le_bytes([data[2], data[3], data[4], data[5]]),
                    version: data[6],
                    task: data[7],
                });
            } else if id == HEARTBEAT_BASE_ID + u16::from(node) {
                assert_eq!(data.len(), 1, "heartbeat length (CiA 301: the NMT state)");
                assert!(
                    matches!(data[0], 0x00 | 0x04 | 0x05 | 0x7F),
                    "heartbeat state {:#x}",
                    data[0]
                );
                parsed.push(Out::Heartbeat { canopen: data[0] });
            } else if id == tpdo_cob_id(node, STATUS_TPDO) {
                sealed(id, data, &mut self.tx_status);
                assert_eq!(data[4], 0, "envelope status byte with the envelope off");
                assert!(data[2] <= 4, "status state {}", data[2]);
                parsed.push(Out::Status {
                    state: data[2],
                    fault: data[3],
                });
            } else {
                panic!("the controller sent frame id {id:#x}");
            }
            i += 1;
        }
        parsed
    }

    /// Runs one step on both, then checks everything.
    pub(crate) fn step(
        &mut self,
        event: Event,
        before: State,
        obs_nibble: Option<u8>,
        out: Outbox,
    ) {
        let parsed = self.parse(&out);
        let expected = std::mem::take(&mut self.model.out);
        let c = &self.controller;
        let after = c.state();

        // 1. Safe action whenever not operational.
        if after != State::Operational {
            assert!(
                c.last_action().iter().all(|&a| a == 0.0),
                "non-zero last action in {after:?}"
            );
            for o in &parsed {
                if let Out::Action { raw, .. } = o {
                    assert_eq!(raw, &[0; ACT_DIM], "non-zero action sent in {after:?}");
                }
            }
        }
        // 2. A policy action only answers an observation frame in Operational, with its nibble.
        for o in &parsed {
            if let Out::Action { sample, raw } = o
                && raw != &[0; ACT_DIM]
            {
                assert_eq!(event, Event::Observation, "policy action outside a sample");
                assert_eq!(
                    before,
                    State::Operational,
                    "policy action outside operational"
                );
                assert_eq!(
                    Some(*sample),
                    obs_nibble,
                    "action tagged with another sample"
                );
            }
        }
        // 3. Finite actions.
        assert!(c.last_action().iter().all(|a| a.is_finite()));
        // 5. Legal transitions.
        if before != after {
            use State::*;
            let legal = match event {
                Event::Poll => matches!(
                    (before, after),
                    (Boot, PreOperational) | (Operational, SafeStop)
                ),
                Event::Nmt(Some(NmtCommand::Start)) => {
                    matches!(before, PreOperational | SafeStop) && after == Operational
                }
                Event::Nmt(Some(NmtCommand::Stop)) => {
                    matches!(before, PreOperational | Operational) && after == SafeStop
                }
                Event::Nmt(Some(NmtCommand::EnterPreOperational)) => {
                    matches!(before, Operational | SafeStop) && after == PreOperational
                }
                Event::Nmt(Some(NmtCommand::ResetNode | NmtCommand::ResetCommunication)) => {
                    after == Boot
                }
                Event::Observation => before == Operational && matches!(after, SafeStop | Fault),
                Event::BusOff => (before, after) == (Operational, PreOperational),
                _ => false,
            };
            assert!(
                legal,
                "illegal transition {before:?} -> {after:?} on {event:?}"
            );
            // A state change is announced by the status TPDO carrying the new state, and by a
            // heartbeat with its NMT state when the heartbeat is on (reset goes to Boot
            // silently: the boot-up heartbeat follows at the next cycle).
            if after != Boot {
                assert!(
                    parsed.iter().any(
                        |o| matches!(o, Out::Status { state, .. } if *state == after.code())
                    ),
                    "{before:?} -> {after:?} without a status"
                );
                if self.model.cfg.heartbeat_cycles != 0 {
                    assert!(
                        parsed.iter().any(|o| matches!(
                            o,
                            Out::Heartbeat { canopen } if *canopen == after.canopen()
                        )),
                        "{before:?} -> {after:?} without a heartbeat"
                    );
                }
            }
        }
        if c.is_bus_off() || c.policy_info().is_none() {
            assert_ne!(
                after,
                State::Operational,
                "operational while bus-off or without policy"
            );
        }
        // 4. Watchdog.
        if event == Event::Poll && after == State::Operational {
            let age = self.clock.now_us() - self.model.last_obs_us;
            let limit = (u64::from(self.model.cfg.watchdog_cycles) + 1) * PERIOD;
            assert!(age < limit, "operational with an observation {age} us old");
        }
        count_step(before, after, &parsed);
        // Reference model: every frame, the state, the fault and the counters.
        assert_eq!(
            parsed, expected,
            "frames differ from the model's on {event:?}"
        );
        assert_eq!(after, self.model.state, "state differs from the model's");
        assert_eq!(
            c.fault(),
            self.model.fault,
            "latched fault differs from the model's"
        );
        assert_eq!(c.is_bus_off(), self.model.bus_off);
        assert_eq!(
            c.diagnostics(),
            &self.model.diag,
            "diagnostics differ from the model's"
        );
        assert_eq!(
            c.policy_info(),
            self.model.policy.as_ref().map(|p| p.info),
            "policy identity differs from the model's"
        );
        assert!(
            c.last_action()
                .iter()
                .zip(&self.model.action)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "last action {:?} differs from the model's {:?}",
            c.last_action(),
            self.model.action
        );
    }
}
