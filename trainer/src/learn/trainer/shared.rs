//! The shared side of a running [`Trainer`]: the per-network locks, the run's counters, and what a
//! distributed rank's exchange ([`RankSync`]) may touch.

use super::*;

pub(super) struct Ctx<'a> {
    pub(super) cfg: &'a RunConfig,
    pub(super) nets: &'a Networks,
    pub(super) actor: Mutex<NetShared>,
    pub(super) critic: Mutex<NetShared>,
    /// The twin critic, with `td3.twin_critics`.
    pub(super) critic2: Option<Mutex<NetShared>>,
    pub(super) demos: Option<&'a DemoBuffer>,
    /// The frozen proposal actor of [`RunConfig::ibrl`].
    pub(super) proposal: Option<&'a [f32]>,
    /// Steps on which the proposal's action was executed, and steps, since the last evaluation.
    pub(super) proposal_chosen: AtomicU64,
    pub(super) proposal_steps: AtomicU64,
    pub(super) returns: Mutex<(f64, u64)>,
    pub(super) obs_stats: Mutex<ObsStats>,
    pub(super) replay: Option<Mutex<Replay>>,
    pub(super) transitions: AtomicU64,
    pub(super) per_worker: Vec<AtomicU64>,
    pub(super) updates: AtomicU64,
    pub(super) episodes: AtomicU64,
    pub(super) evals: AtomicU64,
    pub(super) stop: &'a AtomicBool,
    pub(super) failed: AtomicBool,
    /// Set by a [`RankSync`] that ends the run (the parameter server said stop).
    pub(super) ended: AtomicBool,
    pub(super) until: u64,
    pub(super) start: Instant,
    pub(super) base_wall: f64,
}

impl Ctx<'_> {
    pub(super) fn wall_s(&self) -> f64 {
        self.base_wall + self.start.elapsed().as_secs_f64()
    }

    pub(super) fn progress(&self) -> Progress {
        Progress {
            transitions: self.transitions.load(Ordering::Relaxed),
            transitions_per_worker: self
                .per_worker
                .iter()
                .map(|a| a.load(Ordering::Relaxed))
                .collect(),
            updates: self.updates.load(Ordering::Relaxed),
            episodes: self.episodes.load(Ordering::Relaxed),
            wall_s: self.wall_s(),
        }
    }

    /// Whether the actor is used quantisation-aware from now on.
    pub(super) fn quantisation_aware(&self) -> bool {
        self.cfg
            .quantise
            .active(self.transitions.load(Ordering::Relaxed))
    }

    pub(super) fn halted(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
            || self.failed.load(Ordering::Relaxed)
            || self.ended.load(Ordering::Relaxed)
    }
}

/// The exchange of a distributed worker rank, polled on the run's calling thread (the only
/// thread of the rank that talks to other ranks).
pub(crate) trait RankSync {
    /// Moves parameters between this rank's shared state and the parameter server; `fresh` holds
    /// the evaluations finished since the last call (the sync takes what it forwards). Returns
    /// true when the run should end.
    fn poll(
        &mut self,
        shared: &SharedNets<'_, '_>,
        fresh: &mut Vec<EvalRecord>,
    ) -> Result<bool, LearnError>;
}

/// What a [`RankSync`] may touch of a running [`Trainer`]: the networks' shared halves (under
/// their locks) and the counters.
pub(crate) struct SharedNets<'c, 'a> {
    pub(super) ctx: &'c Ctx<'a>,
}

impl SharedNets<'_, '_> {
    /// Runs `f` on network `i` (see [`SharedNets::net_count`]) under its lock; the workers copy
    /// the parameters and target again afterwards.
    pub(crate) fn with_net<R>(
        &self,
        i: usize,
        f: impl FnOnce(&mut NetShared) -> R,
    ) -> Result<R, LearnError> {
        let m = match i {
            0 => &self.ctx.actor,
            1 => &self.ctx.critic,
            _ => self
                .ctx
                .critic2
                .as_ref()
                .ok_or(LearnError::Worker("no such network"))?,
        };
        let mut g = lock(m)?;
        let r = f(&mut g);
        g.version += 1;
        g.target_version += 1;
        Ok(r)
    }

    /// The update counter (all of this rank's workers).
    pub(crate) fn updates(&self) -> &AtomicU64 {
        &self.ctx.updates
    }

    /// The rank's counters now.
    pub(crate) fn progress(&self) -> Progress {
        self.ctx.progress()
    }
}

pub(super) fn poisoned<T>(_: std::sync::PoisonError<T>) -> LearnError {
    LearnError::Worker("shared state lock poisoned")
}

pub(super) fn lock<T>(m: &Mutex<T>) -> Result<MutexGuard<'_, T>, LearnError> {
    m.lock()
        .map_err(|_| LearnError::Worker("a lock was poisoned by a panicking worker"))
}

/// One network's shared half during a run.
pub(crate) struct NetShared {
    pub(crate) params: Vec<f32>,
    pub(crate) target: Vec<f32>,
    pub(crate) adam: AdamShared,
    pub(super) version: u64,
    pub(super) target_version: u64,
}

impl NetShared {
    /// Copies the online and target parameters into a worker's copies (each with the version it
    /// last copied) where the shared version moved on since.
    pub(super) fn refresh_into(
        &self,
        online: (&mut [f32], &mut u64),
        target: (&mut [f32], &mut u64),
    ) {
        for ((local, seen), shared, version) in [
            (online, &self.params, self.version),
            (target, &self.target, self.target_version),
        ] {
            if *seen != version {
                local.copy_from_slice(shared);
                *seen = version;
            }
        }
    }
}
