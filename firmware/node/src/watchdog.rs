//! The MCU's independent watchdog (IWDG, board build): started at boot with `TIMEOUT_MS`, fed by
//! the control task each time it has handled the timer's periods. If the control task stops
//! running (starved or hung), the IWDG resets the MCU, and the node boots into pre-operational
//! with its committed policy. The timeout is long (4 s) because committing a slot erases a
//! 128 KiB flash sector, which blocks the control task for 1-2 s (STM32F405 datasheet); the fast
//! safety reaction stays the controller's observation watchdog (3 periods). QEMU's netduinoplus2
//! models no IWDG: the QEMU build's [`Dog`] does nothing.

use stm32f4xx_hal::pac::IWDG;

/// Watchdog timeout: longer than a flash sector erase.
#[cfg(not(feature = "qemu"))]
const TIMEOUT_MS: u32 = 4_000;

/// The independent watchdog, or nothing under QEMU.
pub struct Dog {
    #[cfg(not(feature = "qemu"))]
    iwdg: stm32f4xx_hal::watchdog::IndependentWatchdog,
}

impl Dog {
    /// Starts the watchdog (it cannot be stopped again until reset).
    pub fn start(iwdg: IWDG) -> Self {
        #[cfg(not(feature = "qemu"))]
        {
            use stm32f4xx_hal::prelude::*;
            let mut dog = stm32f4xx_hal::watchdog::IndependentWatchdog::new(iwdg);
            dog.start(TIMEOUT_MS.millis());
            Dog { iwdg: dog }
        }
        #[cfg(feature = "qemu")]
        {
            let _ = iwdg;
            Dog {}
        }
    }

    /// Reloads the watchdog's counter.
    pub fn feed(&mut self) {
        #[cfg(not(feature = "qemu"))]
        self.iwdg.feed();
    }
}
