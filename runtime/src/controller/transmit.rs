//! The outbox writers: the safe action, status, TPDOs, emergencies and the policy information.

use dex_policy::FORMAT_VERSION;

use super::{Controller, FaultCode, Outbox};
use crate::can::fd_frame::{FdFrame, TxFrame};
use crate::can::fd_messages::encode_action_fd;
use crate::can::frame::CanFrame;
use crate::can::layout::FrameLayout;
use crate::can::messages::{
    TPDOS, emcy_frame, encode_action, heartbeat_frame, policy_info_frame, status_frame, tpdo_cob_id,
};
use crate::interface::ACT_DIM;

impl<'p, const WIDTH: usize, F: TxFrame> Controller<'p, WIDTH, F> {
    pub(super) fn send_safe_action(&mut self, out: &mut Outbox<F>) {
        self.action = [0.0; ACT_DIM];
        self.own_sample = self.own_sample.wrapping_add(1) & 0x0F;
        self.push_action(self.own_sample, out);
    }

    /// The heartbeat (one NMT state byte; not while the heartbeat time is 0) and the status
    /// TPDO (controller state, fault code, envelope status; always).
    pub(super) fn push_status(&mut self, out: &mut Outbox<F>) {
        self.cycles_since_heartbeat = 0;
        self.status_sent = true;
        let node = self.cfg.node_id;
        if self.sdo.device.heartbeat_ms != 0 {
            let _ = out.push(F::classic(heartbeat_frame(node, self.state.canopen())));
        }
        let f = status_frame(
            node,
            self.state.code(),
            self.fault.code(),
            self.envelope.status(),
            &mut self.status_tx,
        );
        self.push_tpdo(f, out);
    }

    /// Sends a TPDO frame, remembering its E2E header for object 0x2201.
    fn push_tpdo(&mut self, f: CanFrame, out: &mut Outbox<F>) {
        let node = self.cfg.node_id;
        let id = f.standard_id();
        if let (Some(k), [a, b, ..]) = (
            (0..TPDOS).find(|&k| id == Some(tpdo_cob_id(node, k))),
            embedded_can::Frame::data(&f),
        ) {
            self.tpdo_headers[k] = u16::from_le_bytes([*a, *b]);
        }
        let _ = out.push(F::classic(f));
    }

    /// Sends the FD action frame (TPDO 0), remembering its E2E header for object 0x2201; a frame
    /// type without FD frames never gets here ([`Controller::new_fd`] is the FD layout's only way).
    fn push_tpdo_fd(&mut self, f: FdFrame, out: &mut Outbox<F>) {
        if let [a, b, ..] = embedded_can::Frame::data(&f) {
            self.tpdo_headers[0] = u16::from_le_bytes([*a, *b]);
        }
        if let Some(f) = F::fd(f) {
            let _ = out.push(f);
        }
    }

    /// The action frames of the current action, tagged `sample`, in the controller's layout.
    pub(super) fn push_action(&mut self, sample: u8, out: &mut Outbox<F>) {
        let node = self.cfg.node_id;
        match self.layout() {
            FrameLayout::Classic => {
                for f in encode_action(node, &self.action, sample, &mut self.action_tx) {
                    self.push_tpdo(f, out);
                }
            }
            FrameLayout::Fd => {
                let f = encode_action_fd(node, &self.action, sample, &mut self.action_tx[0]);
                self.push_tpdo_fd(f, out);
            }
        }
    }

    pub(super) fn push_emcy(&mut self, out: &mut Outbox<F>) {
        self.push_emcy_code(self.fault, out);
    }

    /// Emergency for `fault` (its error code and fault code) with the current state.
    pub(super) fn push_emcy_code(&mut self, fault: FaultCode, out: &mut Outbox<F>) {
        self.push_emcy_with(fault.emcy_code(), fault, out);
    }

    /// Emergency with `error_code`, the error register (0x1001) as it stands, `fault`'s fault
    /// code and the current state; an error (not the error reset 0x0000) is recorded in the
    /// pre-defined error field (0x1003) with the same code.
    pub(super) fn push_emcy_with(
        &mut self,
        error_code: u16,
        fault: FaultCode,
        out: &mut Outbox<F>,
    ) {
        if error_code != 0 {
            self.sdo.device.record_emergency(error_code, fault.code());
        }
        let register = crate::canopen::device::DeviceHost::error_register(self);
        let f = emcy_frame(
            self.cfg.node_id,
            error_code,
            register,
            fault.code(),
            self.state.code(),
            &mut self.emcy_tx,
        );
        let _ = out.push(F::classic(f));
    }

    pub(super) fn push_policy_info(&mut self, out: &mut Outbox<F>) {
        let (hash, version, task) = match self.info {
            Some(i) => (i.layout_hash, i.format_version as u8, i.task),
            None => (0, FORMAT_VERSION as u8, 0xFF),
        };
        let f = policy_info_frame(self.cfg.node_id, hash, version, task, &mut self.info_tx);
        self.push_tpdo(f, out);
    }
}
