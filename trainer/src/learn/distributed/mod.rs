//! ADPG-R across processes: a parameter server (rank 0) and worker ranks, over any
//! [`Transport`] (MPI behind the `mpi` feature: [`mpi_transport`]). See docs/distributed.md.
//!
//! - Rank 0 ([`server::Server`]) owns the actor and critic parameters, their targets, Adam's
//!   shared second moments and the update and transition counters: the state of a [`Trainer`]
//!   that never runs workers itself. It applies what the worker ranks push, moves the targets,
//!   logs their evaluations, and (through [`crate::pipeline::train_run`]) writes checkpoints, selects,
//!   exports and plots exactly as a local run does.
//! - Ranks 1..N-1 ([`worker`]) each run a local [`Trainer`] with W worker threads (their own
//!   environments, replay and Adam first moments, today's ADPG-R among the threads). The run's
//!   calling thread is the rank's only thread that talks to other ranks: every
//!   [`DistributedConfig::exchange_every`] updates (or [`HEARTBEAT`] without updates) it pushes
//!   the change of the parameters and second moments since its previous push, and when the
//!   server's answer arrives it moves its state onto the server's (keeping what it learned
//!   meanwhile). The threads never wait for the network.
//! - [`message`] is the wire format; a corrupt message is refused and counted, never applied.
//! - [`membership`]: a silent worker rank is lost and the run goes on; one heard from again is
//!   re-admitted; with [`DistributedConfig::respawn_after`] one lost for long enough is replaced
//!   by a newly started rank ([`Transport::replace`]; `MPI_Comm_spawn` over MPI).
//!
//! Why a push carries parameter changes rather than raw gradients: each rank applies its own Adam
//! steps (first moment local, the second moment a copy of the server's, refreshed at every
//! exchange), so the push is the sum of K steps plus the second moment's increment
//! `v_now - beta2^K v_then`; the server adds both, which keeps the shared second moment exactly the
//! running mean of all ranks' squared gradients. Sending the summed gradient instead would make K
//! local updates into one large-batch step on the server.

pub mod membership;
pub mod message;
#[cfg(feature = "mpi")]
pub mod mpi_transport;
pub mod point_mass;
pub mod server;
pub mod worker;

use std::time::Duration;

#[cfg(doc)]
use super::Trainer;

/// How often a worker rank pushes when it makes no updates (before `learning_starts`), so the
/// server sees it alive and counts its transitions.
pub const HEARTBEAT: Duration = Duration::from_millis(200);

/// Settings of a distributed run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistributedConfig {
    /// A worker rank pushes after this many of its updates (all its threads together).
    pub exchange_every: u64,
    /// A rank silent this long (no message, or a send to it not taken) is lost: the server goes
    /// on without it (and re-admits it when it is heard from again); when no worker rank is left
    /// it writes a checkpoint and fails naming the last.
    pub rank_timeout: Duration,
    /// When set, a worker rank lost for this long is replaced: the server asks the transport to
    /// start a new worker rank ([`Transport::replace`]; over MPI, `MPI_Comm_spawn`), which gets
    /// the current state like a rank at the start. Off (`None`) by default: a replacement needs a
    /// free slot in the MPI job (`mpirun --oversubscribe` or more slots than ranks), and a lost
    /// rank that was only stopped or cut off comes back beside its replacement.
    pub respawn_after: Option<Duration>,
}

impl Default for DistributedConfig {
    fn default() -> Self {
        DistributedConfig {
            exchange_every: 10,
            rank_timeout: Duration::from_secs(60),
            respawn_after: None,
        }
    }
}

impl DistributedConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), DistributedError> {
        if self.exchange_every == 0 {
            return Err(DistributedError::Config {
                why: "exchange_every must be at least 1",
            });
        }
        if self.rank_timeout < Duration::from_millis(500) {
            return Err(DistributedError::Config {
                why: "rank_timeout must be at least 0.5 s",
            });
        }
        Ok(())
    }
}

/// Moves of messages between ranks; implemented over MPI by [`mpi_transport`] (feature `mpi`).
/// All calls come from one thread.
pub trait Transport {
    /// This process's rank (0 is the parameter server).
    fn rank(&self) -> usize;
    /// Number of ranks: on the server, every rank so far (replacements included); on a
    /// replacement worker rank, the ranks the run started with.
    fn size(&self) -> usize;
    /// A message that has arrived (from `from`, or any rank when `None`), without waiting:
    /// the sending rank and the bytes.
    fn try_recv(
        &mut self,
        from: Option<usize>,
    ) -> Result<Option<(usize, Vec<u8>)>, DistributedError>;
    /// Starts sending `bytes` to rank `to`; the send completes in the background.
    fn send(&mut self, to: usize, bytes: Vec<u8>) -> Result<(), DistributedError>;
    /// Moves the sends in flight on; returns how many sends to `to` are still in flight (the
    /// server times how long they take on its own clock).
    fn in_flight(&mut self, to: usize) -> usize;
    /// Server: starts a new worker rank in place of the lost rank `lost` and returns its rank
    /// (the next after every rank so far: [`Transport::size`] grows by one). The default cannot
    /// start processes and fails with [`DistributedError::Spawn`].
    fn replace(&mut self, lost: usize) -> Result<usize, DistributedError> {
        let _ = lost;
        Err(DistributedError::Spawn {
            why: "this transport cannot start worker ranks".into(),
        })
    }
}

/// Why a distributed run failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DistributedError {
    /// A message is not a valid message for this run (it is refused and counted).
    #[error("refused message: {why}")]
    BadMessage {
        /// What is wrong with it.
        why: &'static str,
    },
    /// The last worker rank present died or stopped answering (the server goes on while any
    /// is left).
    #[error(
        "worker rank {rank} did not answer for {silent_s:.1} s (dead or stopped) and no worker \
         rank is left: the checkpoint holds the run up to now; continue it with --resume (any \
         number of ranks)"
    )]
    RankLost {
        /// The rank.
        rank: usize,
        /// Seconds since its last message (or since a send to it started).
        silent_s: f64,
    },
    /// The parameter server did not send the run's state in time.
    #[error("rank {rank}: no parameters from rank 0 within {waited_s:.1} s")]
    NoServer {
        /// This rank.
        rank: usize,
        /// Seconds waited.
        waited_s: f64,
    },
    /// The MPI library cannot give the threading level the ranks need.
    #[error("MPI provides threading level {got}, the trainer needs {wanted}")]
    Threading {
        /// The level asked for.
        wanted: &'static str,
        /// The level provided.
        got: &'static str,
    },
    /// MPI could not be initialised (or was already).
    #[error("MPI could not be initialised")]
    Init,
    /// A replacement worker rank could not be started (the server goes on without it).
    #[error("no replacement worker rank could be started: {why}")]
    Spawn {
        /// What the transport (MPI) said.
        why: String,
    },
    /// A setting of the distributed run is out of range or does not go with it.
    #[error("invalid distributed settings: {why}")]
    Config {
        /// What is wrong.
        why: &'static str,
    },
}

/// Counters of a rank's exchanges, for the log and the benchmarks.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct ExchangeStats {
    /// Pushes sent (worker) or applied (server).
    pub exchanges: u64,
    /// Messages refused as corrupt (never applied).
    pub refused: u64,
    /// Bytes sent.
    pub bytes_sent: u64,
    /// Bytes received.
    pub bytes_received: u64,
    /// Worker: sum of the seconds from a push to the server's answer.
    pub latency_sum_s: f64,
    /// Worker: the longest of them.
    pub latency_max_s: f64,
    /// Server: worker ranks lost (a rank lost twice counts twice).
    pub lost: u64,
    /// Server: lost worker ranks re-admitted. Worker: answers that came after more than the rank
    /// timeout, on which the rank dropped what it had learned since its push.
    pub readmitted: u64,
    /// Server: replacement worker ranks started for lost ones
    /// ([`DistributedConfig::respawn_after`]).
    pub replaced: u64,
}

impl ExchangeStats {
    /// Mean seconds from a push to its answer (worker ranks).
    pub fn mean_latency_s(&self) -> f64 {
        self.latency_sum_s / self.exchanges.max(1) as f64
    }
}
