//! The bus server's errors.

use std::net::SocketAddr;
use std::path::PathBuf;

/// Errors of the bus server.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    /// The listening socket could not be set up.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// Address asked for.
        addr: SocketAddr,
        /// Cause.
        source: std::io::Error,
    },
    /// The bus log could not be created.
    #[error("cannot create bus log {path}: {source}")]
    Log {
        /// Path asked for.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// A thread could not be started.
    #[error("cannot start a bus thread: {0}")]
    Thread(std::io::Error),
}
