//! Time for the controller: the bus's time when frames carry Lawicel time stamps (lockstep runs,
//! where the bridge stamps every frame with the virtual bus's simulated time), otherwise the
//! hardware timer's control periods.

use core::cell::Cell;

use dex_runtime::Clock;
use dex_slcan::TIMESTAMP_WRAP_MS;

/// A clock the node sets: from unwrapped 16-bit millisecond time stamps, or from timer ticks.
#[derive(Debug, Default)]
pub struct NodeClock {
    now_us: Cell<u64>,
    last_stamp: Cell<Option<u16>>,
    bus_time: Cell<bool>,
}

impl NodeClock {
    /// A clock at 0 in timer mode.
    pub const fn new() -> Self {
        NodeClock {
            now_us: Cell::new(0),
            last_stamp: Cell::new(None),
            bus_time: Cell::new(false),
        }
    }

    /// Whether time comes from the bus's time stamps (set by the first stamped frame, for good).
    pub fn is_bus_time(&self) -> bool {
        self.bus_time.get()
    }

    /// A frame's time stamp. The first one switches the clock to bus time and sets it to the
    /// stamp (returns `true` then); later ones advance it by the (wrapped) difference to the
    /// previous one. Stamps wrap every 60 s; successive frames are never a wrap apart on a live
    /// bus.
    pub fn on_stamp(&self, ms: u16) -> bool {
        let first = !self.bus_time.replace(true);
        match self.last_stamp.replace(Some(ms)) {
            Some(prev) if !first => {
                let step =
                    (u32::from(ms) + TIMESTAMP_WRAP_MS - u32::from(prev)) % TIMESTAMP_WRAP_MS;
                self.now_us
                    .set(self.now_us.get().saturating_add(u64::from(step) * 1_000));
            }
            _ => self.now_us.set(u64::from(ms) * 1_000),
        }
        first
    }

    /// `periods` control periods of `period_us` from the hardware timer (ignored once on bus
    /// time).
    pub fn on_ticks(&self, periods: u32, period_us: u32) {
        if !self.bus_time.get() {
            let step = u64::from(periods) * u64::from(period_us);
            self.now_us.set(self.now_us.get().saturating_add(step));
        }
    }
}

impl Clock for NodeClock {
    fn now_us(&self) -> u64 {
        self.now_us.get()
    }
}
