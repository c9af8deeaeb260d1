//! What the node dropped or refused, counted from interrupt and task context alike (32-bit
//! atomics: the Cortex-M4 has no 64-bit ones), and the status line that reports them.

use core::fmt;
use core::sync::atomic::{AtomicU32, Ordering};

/// One counter.
#[derive(Debug)]
pub struct Counter(AtomicU32);

impl Counter {
    /// Zero.
    pub const fn new() -> Self {
        Counter(AtomicU32::new(0))
    }

    /// Adds one (wrapping after 2^32 events).
    pub fn bump(&self) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }

    /// The count.
    pub fn get(&self) -> u32 {
        self.0.load(Ordering::Relaxed)
    }
}

impl Default for Counter {
    fn default() -> Self {
        Self::new()
    }
}

/// Every count of the node's link layer (the controller's own counters are its `Diagnostics`).
#[derive(Debug)]
pub struct Counters {
    /// Bytes received on the serial line (SLCAN) or frames from the CAN peripheral.
    pub rx_bytes: Counter,
    /// Frames handed to the controller.
    pub frames_in: Counter,
    /// Frames the node transmitted.
    pub frames_out: Counter,
    /// SLCAN lines that parse to no command (garbage, half lines).
    pub bad_lines: Counter,
    /// SLCAN lines longer than any valid line (dropped whole).
    pub long_lines: Counter,
    /// Receive overruns reported by the USART (ORE) or the CAN peripheral's FIFO.
    pub overruns: Counter,
    /// Framing, noise and parity errors on the serial line.
    pub line_errors: Counter,
    /// Frames dropped because the receive queue to the controller task was full.
    pub queue_full: Counter,
    /// Control periods from the hardware timer.
    pub ticks: Counter,
    /// Writes of a slot region to the NorFlash that failed.
    pub flash_errors: Counter,
    /// Slot regions written to the NorFlash.
    pub flash_writes: Counter,
}

impl Counters {
    /// All zero.
    pub const fn new() -> Self {
        Counters {
            rx_bytes: Counter::new(),
            frames_in: Counter::new(),
            frames_out: Counter::new(),
            bad_lines: Counter::new(),
            long_lines: Counter::new(),
            overruns: Counter::new(),
            line_errors: Counter::new(),
            queue_full: Counter::new(),
            ticks: Counter::new(),
            flash_errors: Counter::new(),
            flash_writes: Counter::new(),
        }
    }

    /// Everything dropped or refused so far: a status line changes when this does.
    pub fn dropped(&self) -> u32 {
        self.bad_lines
            .get()
            .wrapping_add(self.long_lines.get())
            .wrapping_add(self.overruns.get())
            .wrapping_add(self.line_errors.get())
            .wrapping_add(self.queue_full.get())
            .wrapping_add(self.flash_errors.get())
    }

    /// The Lawicel `F` status byte: bit 0 receive queue full, bit 3 data overrun (either seen
    /// since boot).
    pub fn slcan_flags(&self) -> u8 {
        let mut f = 0;
        if self.queue_full.get() > 0 {
            f |= 0x01;
        }
        if self.overruns.get() > 0 {
            f |= 0x08;
        }
        f
    }
}

impl Default for Counters {
    fn default() -> Self {
        Self::new()
    }
}

impl fmt::Display for Counters {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "rx_bytes={} frames_in={} frames_out={} bad_lines={} long_lines={} overruns={} \
             line_errors={} queue_full={} ticks={} flash_writes={} flash_errors={}",
            self.rx_bytes.get(),
            self.frames_in.get(),
            self.frames_out.get(),
            self.bad_lines.get(),
            self.long_lines.get(),
            self.overruns.get(),
            self.line_errors.get(),
            self.queue_full.get(),
            self.ticks.get(),
            self.flash_writes.get(),
            self.flash_errors.get(),
        )
    }
}

/// The node's counters (read by the status line, bumped by the interrupt handlers).
pub static COUNTERS: Counters = Counters::new();
