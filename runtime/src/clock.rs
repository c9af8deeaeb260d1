//! Time enters the controller only through [`Clock`], so tests drive a mock clock.

use core::cell::Cell;

/// A monotonic microsecond clock.
pub trait Clock {
    /// Microseconds since an arbitrary fixed origin; never decreases.
    fn now_us(&self) -> u64;
}

/// A clock that moves only when told to: for tests and lockstep simulation.
#[derive(Debug, Default)]
pub struct MockClock {
    now: Cell<u64>,
}

impl MockClock {
    /// A clock reading `start_us`.
    pub fn new(start_us: u64) -> Self {
        MockClock {
            now: Cell::new(start_us),
        }
    }

    /// Moves the clock forward by `us`.
    pub fn advance(&self, us: u64) {
        self.now.set(self.now.get().saturating_add(us));
    }

    /// Sets the clock to `us` (ignored if earlier than now: the clock is monotonic).
    pub fn set(&self, us: u64) {
        if us > self.now.get() {
            self.now.set(us);
        }
    }
}

impl Clock for MockClock {
    fn now_us(&self) -> u64 {
        self.now.get()
    }
}
