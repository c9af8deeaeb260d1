//! What the inputs reached, counted when `DEX_FUZZ_STATS` is set (replay a corpus with
//! `-runs=0` to see that the sequences get past the E2E check to the policy and the faults).

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};

use dex_runtime::State;
use dex_runtime::interface::ACT_DIM;

use super::model::Out;

pub const NAMES: [&str; 10] = [
    "policy actions",
    "observation timeouts",
    "non-finite observations",
    "out-of-range observations",
    "non-finite outputs (Fault)",
    "bus-off recoveries",
    "loads taken",
    "loads refused",
    "corrupted (resealed) files activated",
    "NMT starts into operational",
];
pub static COUNTS: [AtomicU64; 10] = [const { AtomicU64::new(0) }; 10];

pub fn on() -> bool {
    static ON: OnceLock<bool> = OnceLock::new();
    *ON.get_or_init(|| std::env::var_os("DEX_FUZZ_STATS").is_some())
}

pub fn count(i: usize) {
    if on() {
        COUNTS[i].fetch_add(1, Ordering::Relaxed);
    }
}

pub fn print() {
    if on() {
        let line: Vec<String> = NAMES
            .iter()
            .zip(&COUNTS)
            .map(|(n, c)| format!("{n}: {}", c.load(Ordering::Relaxed)))
            .collect();
        eprintln!("stats | {}", line.join(" | "));
    }
}

/// Counts what one step reached.
pub fn count_step(before: State, after: State, parsed: &[Out]) {
    for o in parsed {
        match o {
            Out::Action { raw, .. } if raw != &[0; ACT_DIM] => count(0),
            Out::Emcy { code: 0x8250, .. } => count(1),
            Out::Emcy { code: 0xFF02, .. } => count(2),
            Out::Emcy { code: 0xFF03, .. } => count(3),
            Out::Emcy { code: 0xFF04, .. } => count(4),
            Out::Emcy { code: 0x8140, .. } => count(5),
            _ => {}
        }
    }
    if before != State::Operational && after == State::Operational {
        count(9);
    }
}
