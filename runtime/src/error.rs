//! Errors of the evaluator and the controller.

use core::fmt;

use dex_policy::FormatError;

/// Why a policy evaluation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum EvalError {
    /// The observation slice has the wrong length.
    ObservationLength {
        /// Values the policy expects.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// The action slice has the wrong length.
    ActionLength {
        /// Joints the policy commands.
        expected: usize,
        /// Slots given.
        got: usize,
    },
    /// An observation value is NaN or infinite.
    NonFiniteObservation {
        /// Index of the value.
        index: usize,
    },
    /// The network produced a NaN or infinite output.
    NonFiniteAction {
        /// Index of the joint.
        index: usize,
    },
    /// The bytes given to [`crate::mlp::Network::act`] do not hold the network's values (too
    /// short, or the values not 4-byte aligned in memory).
    PolicyBytes,
}

impl fmt::Display for EvalError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            EvalError::ObservationLength { expected, got } => {
                write!(f, "observation has {got} values, policy expects {expected}")
            }
            EvalError::ActionLength { expected, got } => {
                write!(
                    f,
                    "action buffer has {got} slots, policy commands {expected} joints"
                )
            }
            EvalError::NonFiniteObservation { index } => {
                write!(f, "observation value {index} is not finite")
            }
            EvalError::NonFiniteAction { index } => {
                write!(f, "network output {index} is not finite")
            }
            EvalError::PolicyBytes => {
                f.write_str("the policy bytes do not hold the network's values")
            }
        }
    }
}

impl core::error::Error for EvalError {}

/// Why the controller refused a policy.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum LoadError {
    /// Policies can be loaded or swapped only outside the operational state.
    Operational,
    /// The file is invalid, does not fit this controller or does not match its layout.
    Format(FormatError),
    /// The policy's control period differs from the controller's.
    ControlPeriod {
        /// Period in the policy file, microseconds.
        policy_us: u32,
        /// Controller period, microseconds.
        controller_us: u32,
    },
}

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoadError::Operational => {
                f.write_str("cannot load a policy while operational: stop the controller first")
            }
            LoadError::Format(e) => write!(f, "policy refused: {e}"),
            LoadError::ControlPeriod {
                policy_us,
                controller_us,
            } => write!(
                f,
                "policy control period {policy_us} us differs from the controller's {controller_us} us"
            ),
        }
    }
}

impl core::error::Error for LoadError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            LoadError::Format(e) => Some(e),
            _ => None,
        }
    }
}

impl From<FormatError> for LoadError {
    fn from(e: FormatError) -> Self {
        LoadError::Format(e)
    }
}
