//! The controller's compute time per control step on its target, for bus time: instructions per
//! step (by default the Cortex-M4F's worst step in `firmware/budget.txt`, compiled in, so a new
//! budget moves the figures with no edit here) at a clock rate (the STM32F4's 168 MHz), one
//! instruction per cycle: a lower bound, since a Cortex-M4F's loads, multiplies and branches can
//! take more than one cycle.

/// `firmware/budget.txt` as this build saw it.
pub const BUDGET_TXT: &str = include_str!("../../firmware/budget.txt");

/// The budget line the controller's step comes from: the f32 44-256-256-9 policy with the
/// safety envelope, the worst step of the golden trace.
pub const STEP_KEY: &str = "controller_step";

/// The Cortex-M4F clock of the STM32F405 (netduinoplus2) the firmware targets.
pub const DEFAULT_CPU_HZ: u64 = 168_000_000;

/// Errors of [`StepCompute`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ComputeError {
    /// The budget file has no such line (or its value is not a number).
    #[error("firmware/budget.txt has no numeric line `{0} N`")]
    MissingKey(String),
    /// A clock rate of zero.
    #[error("the clock rate must be above 0 Hz")]
    ZeroClock,
}

/// Instructions per control step at a clock rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StepCompute {
    /// Instructions per step.
    pub instructions: u64,
    /// Clock rate (Hz), one instruction per cycle.
    pub cpu_hz: u64,
}

/// The value of `key` in a budget file's text (`key value` lines, `#` comments).
pub fn budget_value(text: &str, key: &str) -> Result<u64, ComputeError> {
    text.lines()
        .filter(|l| !l.trim_start().starts_with('#'))
        .find_map(|l| {
            let mut words = l.split_whitespace();
            (words.next() == Some(key))
                .then(|| words.next()?.parse().ok())
                .flatten()
        })
        .ok_or_else(|| ComputeError::MissingKey(key.to_string()))
}

impl StepCompute {
    /// `instructions` (or, if `None`, [`STEP_KEY`] of the compiled-in budget) at `cpu_hz`.
    pub fn new(instructions: Option<u64>, cpu_hz: u64) -> Result<Self, ComputeError> {
        if cpu_hz == 0 {
            return Err(ComputeError::ZeroClock);
        }
        let instructions = match instructions {
            Some(n) => n,
            None => budget_value(BUDGET_TXT, STEP_KEY)?,
        };
        Ok(StepCompute {
            instructions,
            cpu_hz,
        })
    }

    /// Nanoseconds per step (rounded up).
    pub fn ns(&self) -> u64 {
        (u128::from(self.instructions) * 1_000_000_000).div_ceil(u128::from(self.cpu_hz)) as u64
    }

    /// Microseconds per step (rounded up): the bus's resolution.
    pub fn us(&self) -> u64 {
        self.ns().div_ceil(1000)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_step_comes_from_the_budget_file() {
        let c = StepCompute::new(None, DEFAULT_CPU_HZ).expect("budget has controller_step");
        assert_eq!(
            Some(c.instructions),
            BUDGET_TXT.lines().find_map(|l| l
                .strip_prefix("controller_step ")?
                .trim()
                .parse()
                .ok())
        );
        let fixed = StepCompute::new(Some(168_000), DEFAULT_CPU_HZ).expect("valid");
        assert_eq!((fixed.ns(), fixed.us()), (1_000_000, 1_000));
        assert_eq!(
            StepCompute::new(Some(1), 3).map(|c| c.ns()),
            Ok(333_333_334)
        );
    }

    #[test]
    fn bad_budgets_are_refused() {
        assert_eq!(
            budget_value("# controller_step 5\nmlp_step 7\n", "controller_step"),
            Err(ComputeError::MissingKey("controller_step".into()))
        );
        assert_eq!(
            budget_value("controller_step x\ncontroller_step 9", "controller_step"),
            Ok(9)
        );
        assert_eq!(StepCompute::new(Some(1), 0), Err(ComputeError::ZeroClock));
    }
}
