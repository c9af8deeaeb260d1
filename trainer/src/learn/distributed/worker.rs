//! A worker rank: a local [`Trainer`] whose shared state follows the parameter server's.
//!
//! The exchange (module docs of [`super`]) runs on the run's calling thread, polled about every
//! millisecond: push when [`DistributedConfig::exchange_every`] updates were made since the last
//! push (or after [`super::HEARTBEAT`] without any) and no answer is outstanding; when the answer
//! arrives, rebase: `params = server + (params - at_push)`, the second moment likewise
//! (`v = beta2^k' v_server + (v - beta2^k' v_at_push)` for the k' steps since the push), the
//! targets and the step counts are the server's. A stop message ends the run.
//!
//! An answer that comes more than half the [`DistributedConfig::rank_timeout`] after the answer
//! before it (the rank was stopped or cut off, and the server has likely counted it lost) is
//! adopted outright instead: the rank drops what it learned since its push, and the transitions
//! it collected meanwhile are never pushed, so the server's count holds only the work it applied
//! and a rank's stale progress from a long partition is not added to the shared parameters when
//! it is re-admitted. (Measured from the previous answer, not from the push: the server counts
//! silence from the rank's last message, and a push made just after a cut began would read
//! younger than the rank's absence. Half the timeout leaves room for the round trip.)

use super::message::{self, Message, NetDelta, Params, Push, RemoteEval};
use super::{DistributedConfig, DistributedError, ExchangeStats, HEARTBEAT, Transport};
use crate::learn::env::Env;
use crate::learn::rng::Rng;
use crate::learn::trainer::{NetShared, RankSync, SharedNets};
use crate::learn::{EvalRecord, Event, LearnError, Trainer};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Generator streams of worker ranks' threads (apart from the local trainer's).
const STREAM_RANK: u64 = 1 << 30;

/// The longest a worker rank waits for the server's first state (rank 0 may pre-train on
/// demonstrations first).
const START_WAIT: Duration = Duration::from_secs(3600);

/// The least a worker rank waits for the answer to a push before it gives the server up.
const SERVER_WAIT: Duration = Duration::from_secs(600);

/// The shared state as this rank last synchronised it, per network.
#[derive(Debug, Clone)]
struct Base {
    params: Vec<f32>,
    v: Vec<f32>,
    t: u64,
}

/// A worker rank's end of the exchange.
pub struct WorkerRank<'t, T: Transport> {
    transport: &'t mut T,
    cfg: DistributedConfig,
    sizes: Vec<usize>,
    beta2: Vec<f32>,
    base: Vec<Base>,
    /// The rank's update count at the last push (in the server's count).
    updates_at_push: u64,
    /// Transitions and episodes already pushed.
    pushed: (u64, u64),
    awaiting: Option<Instant>,
    /// When the last state from the server arrived.
    last_answer: Instant,
    last_push: Instant,
    stats: ExchangeStats,
}

impl<T: Transport> std::fmt::Debug for WorkerRank<'_, T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerRank")
            .field("rank", &self.transport.rank())
            .field("stats", &self.stats)
            .finish()
    }
}

/// The parameter counts of a trainer's networks: actor, critic (and the twin critic).
pub(crate) fn net_sizes(trainer: &Trainer) -> Vec<usize> {
    let n = trainer.networks();
    let mut v = vec![n.actor.num_params(), n.critic.num_params()];
    if trainer.config().td3.twin_critics {
        v.push(n.critic.num_params());
    }
    v
}

/// Adam's beta2 of each network.
pub(crate) fn net_beta2(trainer: &Trainer) -> Vec<f32> {
    let c = trainer.config();
    let mut v = vec![c.actor_adam.beta2, c.critic_adam.beta2];
    if c.td3.twin_critics {
        v.push(c.critic_adam.beta2);
    }
    v
}

impl<'t, T: Transport> WorkerRank<'t, T> {
    /// This rank's end for a trainer built with the run's configuration.
    pub fn new(
        transport: &'t mut T,
        cfg: DistributedConfig,
        trainer: &Trainer,
    ) -> Result<Self, LearnError> {
        cfg.validate()?;
        Ok(WorkerRank {
            transport,
            cfg,
            sizes: net_sizes(trainer),
            beta2: net_beta2(trainer),
            base: Vec::new(),
            updates_at_push: 0,
            pushed: (0, 0),
            awaiting: None,
            last_answer: Instant::now(),
            last_push: Instant::now(),
            stats: ExchangeStats::default(),
        })
    }

    /// Waits (up to an hour, or the rank timeout if longer) for the server's first state and puts it into `trainer`;
    /// gives the rank's threads their own generator streams. Returns false when the server ends
    /// the run instead (it had nothing left to train).
    pub fn start(&mut self, trainer: &mut Trainer) -> Result<bool, LearnError> {
        let t0 = Instant::now();
        let params = loop {
            if let Some(m) = self.receive()? {
                match m {
                    Message::Params(p) => break p,
                    // The run was already over (a resumed finished run): nothing to do.
                    Message::Stop => return Ok(false),
                    Message::Push(_) => self.stats.refused += 1,
                }
            }
            if t0.elapsed() > self.cfg.rank_timeout.max(START_WAIT) {
                return Err(DistributedError::NoServer {
                    rank: self.transport.rank(),
                    waited_s: t0.elapsed().as_secs_f64(),
                }
                .into());
            }
            std::thread::sleep(Duration::from_millis(1));
        };
        let sh = &mut trainer.shared;
        let nets: [(
            &mut Vec<f32>,
            &mut Vec<f32>,
            &mut crate::learn::adam::AdamShared,
        ); 3] = [
            (&mut sh.actor, &mut sh.target_actor, &mut sh.actor_adam),
            (&mut sh.critic, &mut sh.target_critic, &mut sh.critic_adam),
            (
                &mut sh.critic2,
                &mut sh.target_critic2,
                &mut sh.critic2_adam,
            ),
        ];
        self.base.clear();
        for ((p, t, a), n) in nets.into_iter().zip(&params.nets) {
            p.clone_from(&n.params);
            t.clone_from(&n.target);
            a.v.clone_from(&n.v);
            a.t = n.t;
            self.base.push(Base {
                params: n.params.clone(),
                v: n.v.clone(),
                t: n.t,
            });
        }
        sh.updates = params.updates;
        self.updates_at_push = params.updates;
        self.last_answer = Instant::now();
        let rank = self.transport.rank() as u64;
        let seed = trainer.cfg.seed;
        for (i, w) in trainer.workers.iter_mut().enumerate() {
            let stream = STREAM_RANK + (rank << 12) + i as u64;
            w.rng = Rng::derive(seed ^ params.updates.rotate_left(17), stream);
        }
        Ok(true)
    }

    /// Trains until the server says stop (or `stop` is raised); returns the exchange counters.
    pub fn run<E, F>(
        &mut self,
        trainer: &mut Trainer,
        make_env: F,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<ExchangeStats, LearnError>
    where
        E: Env,
        F: Fn(usize) -> E + Sync,
    {
        self.pushed = {
            let p = trainer.progress();
            (p.transitions, p.episodes)
        };
        trainer.run_synced(make_env, u64::MAX, stop, on_event, Some(self))?;
        Ok(self.stats)
    }

    /// The exchange counters so far.
    pub fn stats(&self) -> ExchangeStats {
        self.stats
    }

    /// A message from the server, if one arrived (refused ones are counted and dropped).
    fn receive(&mut self) -> Result<Option<Message>, LearnError> {
        let Some((from, bytes)) = self.transport.try_recv(Some(0))? else {
            return Ok(None);
        };
        self.stats.bytes_received += bytes.len() as u64;
        match message::decode(&bytes, &self.sizes) {
            Ok((0, m)) if from == 0 => Ok(Some(m)),
            _ => {
                self.stats.refused += 1;
                Ok(None)
            }
        }
    }

    fn push(
        &mut self,
        shared: &SharedNets<'_, '_>,
        fresh: &mut Vec<EvalRecord>,
    ) -> Result<(), LearnError> {
        let mut nets = Vec::with_capacity(self.base.len());
        for (i, (base, &b2)) in self.base.iter_mut().zip(&self.beta2).enumerate() {
            nets.push(shared.with_net(i, |n: &mut NetShared| {
                let steps = n.adam.t.saturating_sub(base.t);
                let f = b2.powf(steps as f32);
                let delta = n
                    .params
                    .iter()
                    .zip(&base.params)
                    .map(|(a, b)| a - b)
                    .collect();
                let dv = n
                    .adam
                    .v
                    .iter()
                    .zip(&base.v)
                    .map(|(a, b)| a - f * b)
                    .collect();
                base.params.clone_from(&n.params);
                base.v.clone_from(&n.adam.v);
                base.t = n.adam.t;
                NetDelta { steps, delta, dv }
            })?);
        }
        let updates_now = shared.updates().load(Ordering::Relaxed);
        let p = shared.progress();
        let push = Push {
            transitions: p.transitions.saturating_sub(self.pushed.0),
            episodes: p.episodes.saturating_sub(self.pushed.1),
            updates: updates_now.saturating_sub(self.updates_at_push),
            return_sum: 0.0,
            return_n: 0,
            nets,
            evals: fresh
                .drain(..)
                .map(|r| RemoteEval {
                    success_rate: r.success_rate,
                    mean_return: r.mean_return,
                    train_return: r.train_return,
                    worker: r.worker as u32,
                })
                .collect(),
        };
        self.pushed = (p.transitions, p.episodes);
        self.updates_at_push = updates_now;
        let bytes = message::encode(self.transport.rank() as u32, &Message::Push(push))?;
        self.stats.bytes_sent += bytes.len() as u64;
        self.transport.send(0, bytes)?;
        self.stats.exchanges += 1;
        self.awaiting = Some(Instant::now());
        self.last_push = Instant::now();
        Ok(())
    }

    fn rebase(&mut self, shared: &SharedNets<'_, '_>, p: &Params) -> Result<(), LearnError> {
        for (i, ((base, &b2), s)) in self
            .base
            .iter_mut()
            .zip(&self.beta2)
            .zip(&p.nets)
            .enumerate()
        {
            shared.with_net(i, |n: &mut NetShared| {
                let since = n.adam.t.saturating_sub(base.t);
                let f = b2.powf(since as f32);
                for ((x, b), sp) in n.params.iter_mut().zip(&base.params).zip(&s.params) {
                    *x = sp + (*x - b);
                }
                for ((x, b), sv) in n.adam.v.iter_mut().zip(&base.v).zip(&s.v) {
                    *x = (f * sv + (*x - f * b)).max(0.0);
                }
                n.adam.t = s.t + since;
                n.target.clone_from(&s.target);
                base.params.clone_from(&s.params);
                base.v.clone_from(&s.v);
                base.t = s.t;
            })?;
        }
        // The count moves to the server's: everything up to the push is in `p.updates`.
        shared.updates().fetch_add(
            p.updates.wrapping_sub(self.updates_at_push),
            Ordering::Relaxed,
        );
        self.updates_at_push = p.updates;
        Ok(())
    }
}

impl<T: Transport> WorkerRank<'_, T> {
    /// Takes the server's state outright (a late answer: see the module docs): parameters,
    /// second moments, step counts, targets and the update count are the server's, and the
    /// transitions and episodes since the last push are never pushed.
    fn adopt(&mut self, shared: &SharedNets<'_, '_>, p: &Params) -> Result<(), LearnError> {
        for (i, (base, s)) in self.base.iter_mut().zip(&p.nets).enumerate() {
            shared.with_net(i, |n: &mut NetShared| {
                n.params.clone_from(&s.params);
                n.adam.v.clone_from(&s.v);
                n.adam.t = s.t;
                n.target.clone_from(&s.target);
                base.params.clone_from(&s.params);
                base.v.clone_from(&s.v);
                base.t = s.t;
            })?;
        }
        let now = shared.updates().load(Ordering::Relaxed);
        shared
            .updates()
            .fetch_add(p.updates.wrapping_sub(now), Ordering::Relaxed);
        self.updates_at_push = p.updates;
        let progress = shared.progress();
        self.pushed = (progress.transitions, progress.episodes);
        Ok(())
    }
}

impl<T: Transport> RankSync for WorkerRank<'_, T> {
    fn poll(
        &mut self,
        shared: &SharedNets<'_, '_>,
        fresh: &mut Vec<EvalRecord>,
    ) -> Result<bool, LearnError> {
        let _ = self.transport.in_flight(0);
        while let Some(m) = self.receive()? {
            match m {
                Message::Params(p) => {
                    let late = self.last_answer.elapsed() > self.cfg.rank_timeout / 2;
                    self.last_answer = Instant::now();
                    if late {
                        self.adopt(shared, &p)?;
                        self.stats.readmitted += 1;
                    } else {
                        self.rebase(shared, &p)?;
                    }
                    if let Some(t) = self.awaiting.take() {
                        let s = t.elapsed().as_secs_f64();
                        self.stats.latency_sum_s += s;
                        self.stats.latency_max_s = self.stats.latency_max_s.max(s);
                    }
                }
                Message::Stop => return Ok(true),
                Message::Push(_) => self.stats.refused += 1,
            }
        }
        if let Some(t) = self.awaiting {
            // Rank 0 pauses for selections and checkpoints; far longer means it is gone.
            let limit = (self.cfg.rank_timeout * 10).max(SERVER_WAIT);
            if t.elapsed() > limit {
                return Err(DistributedError::NoServer {
                    rank: self.transport.rank(),
                    waited_s: t.elapsed().as_secs_f64(),
                }
                .into());
            }
        } else {
            let made = shared
                .updates()
                .load(Ordering::Relaxed)
                .saturating_sub(self.updates_at_push);
            if made >= self.cfg.exchange_every || self.last_push.elapsed() >= HEARTBEAT {
                self.push(shared, fresh)?;
            }
        }
        Ok(false)
    }
}
