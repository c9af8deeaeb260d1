//! The bus server's settings and its source of bus time.

use std::net::SocketAddr;
use std::path::PathBuf;

use crate::wire::WireConfig;
#[cfg(doc)]
use crate::wire_fd::BusWire;

#[cfg(doc)]
use super::Bus;

/// Where bus time comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BusClock {
    /// Microseconds of wall clock since the bus started.
    Wall,
    /// Simulation time, set by [`Bus::set_time`] or the `< time US >` control verb (lockstep).
    Virtual,
}

/// Settings of the bus server.
#[derive(Debug, Clone)]
pub struct BusConfig {
    /// Address to listen on (port 0: a free port).
    pub addr: SocketAddr,
    /// Source of bus time.
    pub clock: BusClock,
    /// Messages queued per client before frames to it are dropped.
    pub queue_depth: usize,
    /// candump-format log file.
    pub log: Option<PathBuf>,
    /// Channel name in the log.
    pub channel: String,
    /// Fixed kernel send buffer per client socket (`SO_SNDBUF`); `None` keeps autotuning. A small
    /// one makes a stalled client's queue fill quickly (tests of the slow-client path).
    pub send_buffer: Option<usize>,
    /// Time on the wire: bit rate and stuffing of every frame, arbitration by identifier,
    /// end-of-frame timestamps. `None`: untimed (a frame's timestamp is when it arrived).
    pub wire: Option<WireConfig>,
    /// CAN FD (`hil-sim bus --fd --data-bitrate D`): the data-phase bit rate. The bus then carries
    /// FD frames (`< fdsend >`, delivered as `< fdframe >`) beside classic ones, each FD frame
    /// timed over the two bit rates ([`BusWire`]). `None`: a classic bus, which ignores FD frames
    /// (counted in `unknown_messages`).
    pub fd_data_bitrate: Option<u32>,
}

impl Default for BusConfig {
    fn default() -> Self {
        BusConfig {
            addr: SocketAddr::from(([127, 0, 0, 1], 0)),
            clock: BusClock::Wall,
            queue_depth: 4096,
            log: None,
            channel: "vcan0".to_string(),
            send_buffer: None,
            wire: None,
            fd_data_bitrate: None,
        }
    }
}
