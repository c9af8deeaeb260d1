//! The errors of the bindings, and the Python exception each becomes.

use dex_env::EnvError;
use dex_env::evaluate::EvalError;
use pyo3::PyErr;
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyValueError};

/// Everything the bindings refuse or fail at. Bad input ([`Error::is_bad_input`]) leaves the
/// environment as it was.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A task name that is not one of the four.
    #[error("unknown task `{0}` (expected one of: reach, grasp, stack-in-hand, stack)")]
    UnknownTask(String),
    /// A reward name that is not one of the reward functions.
    #[error("unknown reward `{name}` (expected one of: {expected})")]
    UnknownReward {
        /// The name given.
        name: String,
        /// The names known.
        expected: String,
    },
    /// A start-scheme name that is not one of the three.
    #[error(
        "unknown start scheme `{0}` (expected one of: original, mixture, along-demonstrations)"
    )]
    UnknownStart(String),
    /// A demonstrator kind that is not `scripted` or `markov`.
    #[error("unknown demonstrator kind `{0}` (expected scripted or markov)")]
    UnknownDemonstrator(String),
    /// An option out of its range (episode length, probabilities, number of environments).
    #[error("{0}")]
    BadOption(String),
    /// An action or observation buffer of the wrong size.
    #[error("{what} has {got} float32 values, expected {expected}")]
    Shape {
        /// What was passed (action, actions, observation, ...).
        what: &'static str,
        /// Values passed.
        got: usize,
        /// Values expected.
        expected: usize,
    },
    /// A NaN or infinite action component.
    #[error(
        "action[{index}] = {value} is not finite{env}; actions must be finite (values outside [-1, 1] are clipped)"
    )]
    NonFinite {
        /// Component index within one action.
        index: usize,
        /// Its value.
        value: f32,
        /// ` (environment k)` in a vector environment, else empty.
        env: String,
    },
    /// A NaN or infinite observation given to a policy.
    #[error("observation[{index}] = {value} is not finite")]
    NonFiniteObservation {
        /// Component index.
        index: usize,
        /// Its value.
        value: f32,
    },
    /// `step` before the first `reset`, or after the episode ended.
    #[error("{0}")]
    ResetNeeded(String),
    /// The environment itself failed (assets missing, no start state, diverged physics).
    #[error("{0}")]
    Env(#[from] EnvError),
    /// The policy file is invalid or does not fit the Jaco cell.
    #[error("{0}")]
    Policy(#[from] EvalError),
    /// A policy made for another task than the one asked for.
    #[error("the policy is a {found} policy, not a {expected} one")]
    PolicyTask {
        /// The task the file names.
        found: String,
        /// The task asked for.
        expected: String,
    },
    /// An ONNX model that cannot be imported, or a policy file that cannot be exported.
    #[error("{0}")]
    Onnx(#[from] dex_policy_tool::OnnxError),
    /// The renderer's part on the Rust side failed (saving the scene's binary model).
    #[error("{0}")]
    Render(String),
    /// The policy file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
}

impl Error {
    /// Whether the error is about what the caller passed (a `ValueError` in Python).
    pub fn is_bad_input(&self) -> bool {
        !matches!(
            self,
            Error::Env(_) | Error::Io { .. } | Error::ResetNeeded(_) | Error::Render(_)
        )
    }
}

impl From<Error> for PyErr {
    fn from(e: Error) -> PyErr {
        let text = e.to_string();
        match e {
            Error::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
                PyFileNotFoundError::new_err(text)
            }
            Error::Io { .. } => PyOSError::new_err(text),
            Error::Env(EnvError::AssetsMissing { .. }) => PyOSError::new_err(text),
            Error::Env(EnvError::NonFiniteAction { .. }) => PyValueError::new_err(text),
            Error::Env(_) | Error::ResetNeeded(_) | Error::Render(_) => {
                PyRuntimeError::new_err(text)
            }
            _ => PyValueError::new_err(text),
        }
    }
}

/// The bindings' result type.
pub type Result<T> = std::result::Result<T, Error>;
