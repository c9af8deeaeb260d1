//! The controller's states and fault codes.

#[cfg(doc)]
use crate::envelope::EnvelopeConfig;

/// Controller states, in CANopen's spirit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// Just powered or reset; becomes pre-operational at the first poll.
    Boot,
    /// Configured, not controlling: policies may be loaded; sends the safe action.
    PreOperational,
    /// Evaluating the policy on every complete observation.
    Operational,
    /// Stopped by command or by a fault: sends the safe action; NMT start resumes.
    SafeStop,
    /// Unrecoverable without NMT reset: sends the safe action.
    Fault,
}

impl State {
    /// Code in the status TPDO and object 0x2002:1.
    pub const fn code(self) -> u8 {
        match self {
            State::Boot => 0,
            State::PreOperational => 1,
            State::Operational => 2,
            State::SafeStop => 3,
            State::Fault => 4,
        }
    }

    /// CANopen NMT state byte (the heartbeat's one byte).
    pub const fn canopen(self) -> u8 {
        match self {
            State::Boot => 0x00,
            State::PreOperational => 0x7F,
            State::Operational => 0x05,
            State::SafeStop | State::Fault => 0x04,
        }
    }
}

/// Why the controller left operational (reported in the status TPDO, object 0x2002:2 and
/// emergency frames).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultCode {
    /// No fault.
    None,
    /// No complete observation for longer than the watchdog allows.
    ObservationTimeout,
    /// An observation value was not finite.
    ObservationNonFinite,
    /// An observation value was out of its plausible range.
    ObservationOutOfRange,
    /// The network produced a non-finite output.
    ActionNonFinite,
    /// Start was commanded with no policy loaded.
    NoPolicy,
    /// The CAN controller went bus-off (reported with emergency 0x8140 once the bus is back).
    BusOff,
    /// A newly activated policy's first evaluation failed: the previous slot is active again.
    PolicyRolledBack,
    /// The safety envelope limited the policy's action for more than
    /// [`EnvelopeConfig::sustained_cycles`] consecutive cycles. A warning in emergency frames
    /// only (0xFF10 when the run starts, 0x0000 with this fault code when it ends): never
    /// latched, the controller stays operational and keeps limiting.
    EnvelopeSustained,
    /// NMT start refused: the envelope's configuration is invalid ([`EnvelopeConfig::validate`]).
    EnvelopeConfig,
}

impl FaultCode {
    /// Code in the status TPDO, object 0x2002:2 and emergency frames (byte 3).
    pub const fn code(self) -> u8 {
        match self {
            FaultCode::None => 0,
            FaultCode::ObservationTimeout => 1,
            FaultCode::ObservationNonFinite => 2,
            FaultCode::ObservationOutOfRange => 3,
            FaultCode::ActionNonFinite => 4,
            FaultCode::NoPolicy => 5,
            FaultCode::BusOff => 6,
            FaultCode::PolicyRolledBack => 7,
            FaultCode::EnvelopeSustained => 16,
            FaultCode::EnvelopeConfig => 17,
        }
    }

    /// CANopen-style emergency error code (0x8250 is CANopen's RPDO timeout, 0x8140 its
    /// "recovered from bus-off"; 0xFFxx are manufacturer-specific; 0x0000 is "error reset").
    pub const fn emcy_code(self) -> u16 {
        match self {
            FaultCode::None => 0x0000,
            FaultCode::ObservationTimeout => 0x8250,
            FaultCode::ObservationNonFinite => 0xFF02,
            FaultCode::ObservationOutOfRange => 0xFF03,
            FaultCode::ActionNonFinite => 0xFF04,
            FaultCode::NoPolicy => 0xFF05,
            FaultCode::BusOff => 0x8140,
            FaultCode::PolicyRolledBack => 0xFF07,
            FaultCode::EnvelopeSustained => 0xFF10,
            FaultCode::EnvelopeConfig => 0xFF11,
        }
    }
}
