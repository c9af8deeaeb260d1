//! The controller's diagnostic counters and the identity of its policy.

#[cfg(doc)]
use super::Controller;

/// Counters for diagnosis; they saturate instead of wrapping.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Diagnostics {
    /// Control cycles run.
    pub cycles: u64,
    /// Cycles skipped because `poll` came late.
    pub missed_cycles: u64,
    /// Policy evaluations.
    pub evaluations: u64,
    /// Cycles with more than one evaluation.
    pub overruns: u64,
    /// Frames dropped for a wrong CRC, a bad counter or a wrong length.
    pub e2e_errors: u64,
    /// Frames dropped as repetitions.
    pub repeated: u64,
    /// Frames dropped for a counter jump.
    pub wrong_sequence: u64,
    /// Observations abandoned incomplete.
    pub incomplete_observations: u64,
    /// Cycles in which no observation frame arrived.
    pub no_new_data: u64,
    /// Frames with identifiers this controller does not use.
    pub ignored_frames: u64,
    /// Times the CAN controller went bus-off ([`Controller::on_bus_off`]).
    pub bus_off_events: u64,
}

/// Identity of the loaded policy, reported in the policy-info TPDO.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PolicyInfo {
    /// Layout hash from the file header.
    pub layout_hash: u32,
    /// Format version of the file.
    pub format_version: u16,
    /// Task code (order of [`dex_policy::Task`]).
    pub task: u8,
}
