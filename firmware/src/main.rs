//! Board entry point: paints the stack, runs [`dex_firmware::run`] with semihosting output and
//! SysTick instruction counts, reports the stack high-water mark and exits QEMU.
//!
//! Exit status: 0 after a complete run; 1 for the fault state (bad policy, bad trace, controller
//! fault), a panic (panic-semihosting's `exit` feature) or a HardFault. Never a hang: every path
//! ends in a semihosting exit.
#![no_std]
#![no_main]

use core::fmt::{self, Write};

use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::{ExceptionFrame, entry, exception};
use cortex_m_semihosting::debug::{self, EXIT_FAILURE, EXIT_SUCCESS};
use cortex_m_semihosting::hio::{self, HostStream};
use dex_firmware::{Platform, Summary};
use panic_semihosting as _;

/// SysTick's processor clock as QEMU models the board, in Hz (mps2: 25 MHz).
#[cfg(dex_board = "mps2-an386")]
const SYSTICK_HZ: u64 = 25_000_000;
/// SysTick's processor clock as QEMU models the board, in Hz (STM32F405 SYSCLK: 168 MHz; the
/// 24-bit counter then wraps after ~1.5M instructions at shift 6).
#[cfg(not(dex_board = "mps2-an386"))]
const SYSTICK_HZ: u64 = 168_000_000;

/// QEMU's `-icount shift` the instruction conversion assumes: one instruction = 2^shift ns.
const ICOUNT_SHIFT: u32 = 6;

/// Start of RAM on both boards (`.data`/`.bss` begin here).
const RAM_ORIGIN: usize = 0x2000_0000;

/// The SysTick counter is 24 bits wide.
const SYST_MASK: u32 = 0x00FF_FFFF;

/// Semihosting output and SysTick timing.
struct Board {
    out: Option<HostStream>,
    syst: SYST,
    painted: stack::Painted,
    /// Deepest stack use over all finished phases, in bytes.
    stack_peak: usize,
}

impl Board {
    /// SysTick ticks to guest instructions under `-icount shift=ICOUNT_SHIFT`.
    fn instructions(ticks: u32) -> Option<u32> {
        let ns = u64::from(ticks) * 1_000_000_000 / SYSTICK_HZ;
        u32::try_from(ns >> ICOUNT_SHIFT).ok()
    }
}

impl Platform for Board {
    fn line(&mut self, args: fmt::Arguments<'_>) {
        if let Some(out) = self.out.as_mut() {
            let _ = out.write_fmt(args);
            let _ = out.write_str("\n");
        }
    }

    fn measure<R>(&mut self, f: impl FnOnce() -> R) -> (R, Option<u32>) {
        self.syst.clear_current();
        let start = SYST::get_current();
        let r = f();
        let end = SYST::get_current();
        // SysTick counts down and wraps at 24 bits (after ~10M instructions at shift 6).
        let ticks = start.wrapping_sub(end) & SYST_MASK;
        (r, Self::instructions(ticks))
    }

    fn stack_checkpoint(&mut self, phase: &str) {
        let used = stack::high_water(self.painted);
        self.stack_peak = self.stack_peak.max(used);
        self.line(format_args!("S {phase} stack_used={used}"));
        self.painted = stack::paint();
    }
}

/// Stack painting: fill the free stack with a pattern before the run, find the deepest
/// overwritten word after it.
mod stack {
    /// The pattern painted into unused stack.
    const PAINT: u32 = 0xC5AC_CE55;
    /// Bytes below the current stack pointer left unpainted (this function's own frame).
    const MARGIN: usize = 256;

    unsafe extern "C" {
        /// End of `.bss` (and start of the unused heap region): the lowest address the stack
        /// may grow into (cortex-m-rt's linker script).
        static mut __sheap: u32;
        /// Initial stack pointer, the top of RAM (cortex-m-rt's linker script).
        static mut _stack_start: u32;
    }

    /// The painted region `[bottom, top)` and the stack's top.
    #[derive(Debug, Clone, Copy)]
    pub struct Painted {
        pub bottom: usize,
        pub painted_top: usize,
        pub stack_top: usize,
    }

    /// Paints from the end of `.bss` up to just below the current stack pointer.
    #[inline(never)]
    pub fn paint() -> Painted {
        let bottom = core::ptr::addr_of!(__sheap) as usize;
        let stack_top = core::ptr::addr_of!(_stack_start) as usize;
        let sp = cortex_m::register::msp::read() as usize;
        let painted_top = sp.saturating_sub(MARGIN) & !3;
        let mut p = bottom;
        while p < painted_top {
            // SAFETY: [bottom, sp - MARGIN) is RAM between .bss and the live stack: nothing
            // lives there (no heap), and the stack has not grown into it yet.
            unsafe { (p as *mut u32).write_volatile(PAINT) };
            p += 4;
        }
        Painted {
            bottom,
            painted_top,
            stack_top,
        }
    }

    /// Bytes of stack used at the deepest point since [`paint`] (from the top of RAM).
    pub fn high_water(painted: Painted) -> usize {
        let mut p = painted.bottom;
        // SAFETY: the same RAM range that `paint` wrote, read with volatile word loads.
        while p < painted.painted_top && unsafe { (p as *const u32).read_volatile() } == PAINT {
            p += 4;
        }
        painted.stack_top - p
    }
}

/// Reports and exits QEMU with `status`; spins only if no debugger answers semihosting.
fn finish(board: &mut Board, result: Result<Summary, dex_firmware::Fault>) -> ! {
    let used = stack::high_water(board.painted).max(board.stack_peak);
    let status = match result {
        Ok(s) => {
            for (name, st) in [
                ("mlp", s.mlp),
                ("controller", s.controller),
                ("slot_controller", s.slot_controller),
                ("flash_request", s.flash_request),
                ("envelope", s.envelope),
            ] {
                if st.count > 0 {
                    board.line(format_args!(
                        "I {name} steps={} min={} max={} mean={}",
                        st.count,
                        st.min,
                        st.max,
                        st.mean()
                    ));
                }
            }
            board.line(format_args!(
                "S peak stack_used={used} stack_capacity={} static_ram={}",
                board.painted.stack_top - board.painted.bottom,
                board.painted.bottom - RAM_ORIGIN,
            ));
            board.line(format_args!("END ok steps={}", s.steps));
            EXIT_SUCCESS
        }
        Err(fault) => {
            board.line(format_args!("FAULT {fault}"));
            board.line(format_args!("S peak stack_used={used}"));
            EXIT_FAILURE
        }
    };
    debug::exit(status);
    loop {
        cortex_m::asm::wfi();
    }
}

#[entry]
fn main() -> ! {
    let painted = stack::paint();
    let out = hio::hstdout().ok();
    let Some(mut core) = cortex_m::Peripherals::take() else {
        debug::exit(EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    };
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(SYST_MASK);
    core.SYST.clear_current();
    core.SYST.enable_counter();
    let mut board = Board {
        out,
        syst: core.SYST,
        painted,
        stack_peak: 0,
    };
    if cfg!(feature = "hardfault-test") {
        cortex_m::asm::udf();
    }
    let result = dex_firmware::run(&mut board);
    finish(&mut board, result)
}

/// Any fault ends the run with a non-zero exit status instead of cortex-m-rt's endless loop.
#[exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    if let Ok(mut out) = hio::hstdout() {
        let _ = writeln!(out, "FAULT hardfault pc={:#010x}", frame.pc());
    }
    debug::exit(EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}
