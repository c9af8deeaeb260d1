//! The controller as the host of program download and of the communication objects.

use dex_policy::PolicyView;

use super::{Controller, FaultCode, PolicyInfo, State};
use crate::can::fd_frame::TxFrame;
use crate::can::layout::FrameLayout;
use crate::can::messages::{ACTION_QUANTITY, to_raw};
use crate::clock::Clock;
use crate::error::LoadError;
use crate::interface::{Quantity, quantity_of};
use crate::slots::{PolicySlots, SlotError};

/// The controller's clock in milliseconds, as the SDO server's timeout reads it (wrapping).
pub(super) fn sdo_ms(clock: &impl Clock) -> u32 {
    (clock.now_us() / 1000) as u32
}

/// The policy-info fields of a file.
pub(super) fn policy_info_of(view: &PolicyView<'_>) -> PolicyInfo {
    PolicyInfo {
        layout_hash: view.header().layout_hash,
        format_version: view.header().version,
        task: view.body().task as u8,
    }
}

/// The controller as the application of CiA 302-3 program download ([`crate::canopen::program`]).
impl<const WIDTH: usize, F: TxFrame> crate::canopen::program::ProgramHost
    for Controller<'_, WIDTH, F>
{
    fn may_change_program(&self) -> bool {
        self.state != State::Operational
    }

    fn accept(&self, view: &PolicyView<'_>, file: &[u8]) -> Result<(), LoadError> {
        self.bind_slot(view, file).map(|_| ())
    }

    fn activate(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        self.activate_slot(slots)
    }

    fn roll_back(&mut self, slots: &mut PolicySlots<'_>) -> Result<(), SlotError> {
        self.roll_back_slot(slots)
    }

    fn stop(&mut self) {
        self.stop_requested = true;
    }

    fn running(&self) -> bool {
        self.state == State::Operational
    }
}

/// The controller as the application behind the communication objects
/// ([`crate::canopen::device`]).
impl<const WIDTH: usize, F: TxFrame> crate::canopen::device::DeviceHost
    for Controller<'_, WIDTH, F>
{
    /// Bit 0 (generic) while a fault is latched, bit 4 (communication) for a watchdog timeout or
    /// bus-off, bit 7 (manufacturer-specific) for the other faults.
    fn error_register(&self) -> u8 {
        match self.fault {
            FaultCode::None | FaultCode::EnvelopeSustained => 0,
            FaultCode::ObservationTimeout | FaultCode::BusOff => 0x01 | 0x10,
            _ => 0x01 | 0x80,
        }
    }

    fn active_policy(&self) -> Option<crate::canopen::device::ActivePolicy> {
        self.info.map(|i| crate::canopen::device::ActivePolicy {
            layout_hash: i.layout_hash,
            format_version: i.format_version,
            task: i.task,
        })
    }

    fn envelope_status(&self) -> u8 {
        self.envelope.status()
    }

    fn controller_state(&self) -> u8 {
        self.state.code()
    }

    fn fault_code(&self) -> u8 {
        self.fault.code()
    }

    fn node_id(&self) -> u8 {
        self.cfg.node_id
    }

    fn layout(&self) -> FrameLayout {
        Controller::layout(self)
    }

    fn observation_raw(&self, index: usize) -> i16 {
        let lsb = quantity_of(index).map_or(1.0, Quantity::lsb);
        self.obs.get(index).map_or(0, |&v| to_raw(v, lsb))
    }

    fn action_raw(&self, index: usize) -> i16 {
        self.action
            .get(index)
            .map_or(0, |&v| to_raw(v, ACTION_QUANTITY.lsb()))
    }

    fn observation_header(&self, k: usize) -> u16 {
        self.assembler.header(k)
    }

    fn tpdo_header(&self, k: usize) -> u16 {
        self.tpdo_headers.get(k).copied().unwrap_or(0)
    }
}
