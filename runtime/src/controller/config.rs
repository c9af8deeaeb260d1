//! The controller's settings.

use crate::can::messages::{NodeIdError, check_node_id};
use crate::envelope::EnvelopeConfig;
use crate::interface::CONTROL_PERIOD_US;

/// Controller settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControllerConfig {
    /// CANopen node id (1..=31, [`ControllerConfig::check`]): every node-specific identifier
    /// derives from it ([`crate::can::messages`]).
    pub node_id: u8,
    /// Control period in microseconds.
    pub period_us: u32,
    /// Safe-stop when the newest complete observation is older than this many periods.
    pub watchdog_cycles: u32,
    /// The producer heartbeat time (0x1017) after boot, in periods (0: no heartbeat but the
    /// boot-up message); an SDO write to 0x1017 changes it, in ms. The heartbeat also goes out
    /// on every state change while it is on.
    pub heartbeat_cycles: u32,
    /// Largest accepted alive-counter jump on observation frames (1: no frame may be lost).
    pub e2e_max_delta: u8,
    /// The safety envelope applied to every policy action ([`crate::envelope`]); on by default.
    pub envelope: EnvelopeConfig,
}

impl Default for ControllerConfig {
    fn default() -> Self {
        ControllerConfig {
            node_id: 0x10,
            period_us: CONTROL_PERIOD_US,
            watchdog_cycles: 3,
            heartbeat_cycles: 10,
            e2e_max_delta: 1,
            envelope: EnvelopeConfig::jaco(),
        }
    }
}

impl ControllerConfig {
    /// Whether the configuration can run on a shared bus: the node id must lie in 1..=31
    /// ([`check_node_id`]). Check it when the configuration is made; a controller built from a
    /// configuration that fails it sends frames on identifiers of other nodes.
    pub const fn check(&self) -> Result<(), NodeIdError> {
        match check_node_id(self.node_id) {
            Ok(_) => Ok(()),
            Err(e) => Err(e),
        }
    }
}
