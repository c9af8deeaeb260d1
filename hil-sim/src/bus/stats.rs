//! The bus counters.

/// Counters of the bus.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BusStats {
    /// Frames received from clients.
    pub frames_in: u64,
    /// Frames put on the bus (after faults; each counted once, however many clients got it).
    pub frames_on_bus: u64,
    /// Frame copies queued to clients.
    pub deliveries: u64,
    /// Frame copies dropped because a client's queue was full.
    pub queue_drops: u64,
    /// Frames dropped by a drop fault.
    pub fault_dropped: u64,
    /// Frames corrupted by a corrupt fault.
    pub fault_corrupted: u64,
    /// Frames delayed by a delay fault.
    pub fault_delayed: u64,
    /// Frames lost while the bus was off.
    pub busoff_dropped: u64,
    /// Messages that were not understood (ignored).
    pub unknown_messages: u64,
    /// Clients connected now.
    pub clients: u64,
    /// Clients connected since start.
    pub connections: u64,
    /// Frames that waited for the wire (offered while it was busy or lost arbitration).
    pub wire_waited: u64,
    /// Most frames waiting for the wire at once.
    pub wire_queue_peak: u64,
}
