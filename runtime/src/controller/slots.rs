//! Policy loading, the A/B policy slots and the SDO server the slot path serves.

use dex_policy::PolicyView;

use super::hosts::{policy_info_of, sdo_ms};
use super::{
    Controller, ControllerConfig, FaultCode, Outbox, Policy, PolicyInfo, SDO_REQUEST_BASE,
    SDO_RESPONSE_BASE, State,
};
use crate::can::fd_frame::TxFrame;
use crate::can::frame::CanFrame;
use crate::can::messages::{NMT_ID, NmtCommand};
use crate::canopen::device::{DeviceObjects, DeviceState, Identity};
use crate::canopen::program::{ProgramObjects, ProgramState};
use crate::canopen::{SdoFrame, SdoServer};
use crate::clock::Clock;
use crate::error::LoadError;
use crate::mlp::{Mlp, Network};
use crate::slots::{PolicySlots, SlotError};

/// The controller's SDO side: the server and what its object dictionary keeps between requests.
#[derive(Debug, Clone)]
pub(super) struct SdoSide {
    server: SdoServer,
    pub(super) device: DeviceState,
    pub(super) program: ProgramState,
}

impl SdoSide {
    pub(super) fn new(cfg: &ControllerConfig) -> Self {
        let heartbeat_ms = u64::from(cfg.heartbeat_cycles) * u64::from(cfg.period_us) / 1000;
        SdoSide {
            server: SdoServer::default(),
            device: DeviceState::new(
                Identity::default(),
                u16::try_from(heartbeat_ms).unwrap_or(u16::MAX),
            ),
            program: ProgramState::default(),
        }
    }
}

impl<'p, const WIDTH: usize, F: TxFrame> Controller<'p, WIDTH, F> {
    /// Loads or swaps the policy. Refused while operational; refused (leaving the current policy
    /// active) when the file does not fit this controller's capacity, layout or period.
    pub fn load_policy(&mut self, view: &PolicyView<'p>) -> Result<(), LoadError> {
        if self.state == State::Operational {
            return Err(LoadError::Operational);
        }
        self.check_policy(view)?;
        self.policy = Some(Policy::File(Mlp::new(view)?));
        self.info = Some(policy_info_of(view));
        self.announce = true;
        Ok(())
    }

    /// This controller's checks of a policy file: layout against [`crate::interface`], control
    /// period; capacity is checked when the evaluator is built.
    pub fn check_policy(&self, view: &PolicyView<'_>) -> Result<(), LoadError> {
        crate::features::check_layout(view)?;
        let period = view.body().control_period_us;
        if period != self.cfg.period_us {
            return Err(LoadError::ControlPeriod {
                policy_us: period,
                controller_us: self.cfg.period_us,
            });
        }
        Ok(())
    }

    /// The slot evaluator of `file` (decoded as `view`), after this controller's checks.
    pub(super) fn bind_slot(
        &self,
        view: &PolicyView<'_>,
        file: &[u8],
    ) -> Result<Network<WIDTH>, LoadError> {
        self.check_policy(view)?;
        Ok(Network::new(view, file)?)
    }

    /// Takes the active slot of `slots` as the policy (at start-up, after [`PolicySlots::mount`]).
    /// Refused while operational; refused, leaving the current policy, when the slot is empty or
    /// the controller refuses its file. Frames then go through [`Controller::on_frame_slots`].
    pub fn attach_slots(&mut self, slots: &PolicySlots<'_>) -> Result<(), SlotError> {
        if self.state == State::Operational {
            return Err(SlotError::Operational);
        }
        let (net, info) = slots
            .bind_active(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))?;
        self.set_slot_policy(net, info);
        Ok(())
    }

    /// Activates the verified file in the inactive slot of `slots`: refused while operational,
    /// and (leaving the active policy) when the controller refuses the file. Takes effect at
    /// once, between two control cycles; the policy-info frame goes out at the next cycle. The
    /// policy is on trial until its first evaluation: if that fails, the controller rolls it back.
    pub fn activate_slot(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        if self.state == State::Operational {
            return Err(SlotError::Operational);
        }
        let (net, info) =
            slots.activate(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))?;
        self.set_slot_policy(net, info);
        Ok(())
    }

    /// Makes the previous policy of `slots` active again (explicit roll-back, program control
    /// 0x1F51 = 0x80); refused while operational or when no previous policy is kept.
    pub fn roll_back_slot(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        if self.state == State::Operational {
            return Err(SlotError::Operational);
        }
        let (net, info) = slots
            .roll_back(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))?;
        self.set_slot_policy(net, info);
        Ok(())
    }

    #[inline(always)]
    fn set_slot_policy(&mut self, net: Network<WIDTH>, info: PolicyInfo) {
        self.policy = Some(Policy::Slot(net));
        self.info = Some(info);
        self.announce = true;
    }

    /// [`Controller::on_frame`] for a controller whose policy lives in `slots`: SDO requests
    /// (`0x600 + node`) go to the SDO server over the controller's object dictionary
    /// ([`crate::canopen::device`], program download onto `slots` included) and are answered on
    /// `0x580 + node` (every refusal an abort with its CiA 301 code); every other frame is
    /// handled as by `on_frame`, evaluating the active slot. A fault in the first evaluation of a
    /// newly activated policy rolls it back (previous slot active again), goes to safe-stop and
    /// sends emergency 0xFF07 (fault `PolicyRolledBack`); NMT start then runs the previous policy.
    /// NMT reset (node or communication) drops a running SDO transfer without an answer.
    pub fn on_frame_slots(
        &mut self,
        frame: &impl embedded_can::Frame,
        clock: &impl Clock,
        slots: &mut PolicySlots<'_>,
    ) -> Outbox<F> {
        let request = SDO_REQUEST_BASE + u16::from(self.cfg.node_id);
        match frame.id() {
            embedded_can::Id::Standard(s) if !frame.is_remote_frame() && s.as_raw() == request => {
                let now_ms = sdo_ms(clock);
                let mut out = Outbox::new();
                let response = self.with_sdo(slots, |server, od| {
                    server.on_request(frame.data(), now_ms, od)
                });
                self.push_sdo(response, &mut out);
                out
            }
            embedded_can::Id::Standard(s) if !frame.is_remote_frame() && s.as_raw() == NMT_ID => {
                let reset = matches!(
                    (frame.data().first().copied().and_then(NmtCommand::from_code), frame.data().get(1)),
                    (Some(NmtCommand::ResetNode | NmtCommand::ResetCommunication), Some(&n))
                        if n == 0 || n == self.cfg.node_id
                );
                if reset && self.sdo.server.busy() {
                    let _ = self.with_sdo(slots, |server, od| {
                        server.abort(od, crate::canopen::SdoAbort::General)
                    });
                }
                self.frame_in(frame, clock, Some(slots))
            }
            _ => self.frame_in(frame, clock, Some(slots)),
        }
    }

    /// [`Controller::poll`] for a controller whose policy lives in `slots`: also aborts an SDO
    /// transfer that has seen no request for the server's timeout (abort 0x0504_0000 on
    /// `0x580 + node`; a cut program download leaves the active policy as it was).
    pub fn poll_slots(&mut self, clock: &impl Clock, slots: &mut PolicySlots<'_>) -> Outbox<F> {
        let mut out = self.poll(clock);
        if self.sdo.server.busy() {
            let now_ms = sdo_ms(clock);
            let response = self.with_sdo(slots, |server, od| server.poll(now_ms, od));
            self.push_sdo(response, &mut out);
        }
        out
    }

    /// Runs `f` with the SDO server and the controller's dictionary over `slots`.
    fn with_sdo<T>(
        &mut self,
        slots: &mut PolicySlots<'_>,
        f: impl FnOnce(&mut SdoServer, &mut DeviceObjects<'_, '_, Self>) -> T,
    ) -> T {
        // The dictionary borrows the controller as its host: the SDO side is moved out meanwhile.
        let mut side = core::mem::replace(&mut self.sdo, SdoSide::new(&self.cfg));
        let result = {
            let program = ProgramObjects {
                slots,
                host: self,
                state: &mut side.program,
            };
            let mut od = DeviceObjects::new(&mut side.device, program);
            f(&mut side.server, &mut od)
        };
        self.sdo = side;
        result
    }

    fn push_sdo(&self, response: Option<SdoFrame>, out: &mut Outbox<F>) {
        let id = SDO_RESPONSE_BASE + u16::from(self.cfg.node_id);
        if let Some(f) = response.and_then(|r| CanFrame::standard(id, &r)) {
            let _ = out.push(F::classic(f));
        }
    }

    /// The first evaluation of a newly activated slot failed: safe-stop, the previous slot back,
    /// emergency 0xFF07. Without a previous policy to go back to, the usual fault.
    pub(super) fn roll_back_on_fault(&mut self, slots: &mut PolicySlots<'_>, out: &mut Outbox<F>) {
        match slots
            .roll_back_trial(|view, file| Ok((self.bind_slot(view, file)?, policy_info_of(view))))
        {
            Ok((net, info)) => {
                self.set_slot_policy(net, info);
                self.safe_stop(FaultCode::PolicyRolledBack, out);
            }
            Err(_) => {
                self.fault = FaultCode::ActionNonFinite;
                self.enter(State::Fault, out);
                self.push_emcy(out);
                self.send_safe_action(out);
            }
        }
    }
}
