//! The parameter server (rank 0): applies the worker ranks' pushes to a [`Trainer`]'s shared
//! state and answers each with the state as it is then.
//!
//! Applying a push of k updates: `params += delta` and `v = beta2^steps v + dv` per network
//! (steps: the network's Adam steps in the push), the Adam step count and the update count move
//! on, and the targets are moved for each of the k updates the way a local run moves them
//! ([`crate::learn::TargetUpdate::apply`], only on actor updates with TD3's delay). The
//! transitions count toward the run's budget (kept in the trainer's first worker slot, so
//! checkpoints and `Progress` carry the run's total), the evaluations are logged with the run's
//! counters.
//!
//! Faults: a rank that sends nothing for [`DistributedConfig::rank_timeout`], or does not take a
//! send for that long, is lost: the server records it ([`Membership`]), tells the observer
//! ([`Server::on_rank_change`]) and goes on with the other ranks. A lost rank that is heard from
//! again is re-admitted: its message is applied as any other (what a rank pushes is what it did
//! since the server's state it last took, so nothing is counted twice; a killed rank's push that
//! never arrived whole is never applied) and it gets the current state. Only when no worker rank
//! is left does the server fail ([`DistributedError::RankLost`]); the caller writes a checkpoint.
//! With [`DistributedConfig::respawn_after`] set, a rank lost for that long is replaced: the
//! transport starts a new worker rank ([`Transport::replace`]), numbered after every rank so far,
//! which gets the current state as the ranks did at the start and counts from then on like any
//! other. Each lost rank is replaced at most once, and a run makes at most as many replacements as
//! it started with worker ranks (a replacement that keeps dying does not spawn for ever); the time
//! spent starting one is nobody's silence. A replacement that cannot be started is recorded and
//! the run goes on without it.
//! Silence is measured on the server's own clock, which runs only inside [`Server::serve`]: the
//! time the caller spends between calls (selection, checkpoints) is nobody's silence, and a rank's
//! silence carries over from one call to the next (resetting it at each call let a stopped rank
//! live for ever once the checkpoint chunks were shorter than the timeout).
//! A refused message is counted ([`ExchangeStats::refused`]) and never applied; its sender gets
//! the current state as if its push had been empty (it then drops what it pushed).

use super::membership::{Membership, RankChange, RankChangeKind};
use super::message::{self, Message, NetParams, Params, Push};
use super::worker::{net_beta2, net_sizes};
use super::{DistributedConfig, DistributedError, ExchangeStats, Transport};
use crate::learn::{EvalRecord, Event, LearnError, Progress, RunSummary, Trainer};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// What [`Server::on_rank_change`] calls with each membership change.
type RankObserver<'t> = Box<dyn FnMut(&RankChange) + 't>;

/// Rank 0 of a distributed run.
pub struct Server<'t, T: Transport> {
    transport: &'t mut T,
    cfg: DistributedConfig,
    sizes: Vec<usize>,
    beta2: Vec<f32>,
    /// Serve-clock time of each rank's last message.
    last_seen: Vec<Duration>,
    /// Serve-clock start times of each rank's sends still in flight, oldest first.
    sends: Vec<VecDeque<Duration>>,
    /// Time spent inside `serve` by earlier calls.
    served: Duration,
    started: bool,
    stats: ExchangeStats,
    membership: Membership,
    observer: Option<RankObserver<'t>>,
    /// The most replacements of this run (the worker ranks it started with).
    max_replacements: u64,
}

impl<T: Transport> std::fmt::Debug for Server<'_, T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Server")
            .field("ranks", &self.transport.size())
            .field("stats", &self.stats)
            .finish()
    }
}

impl<'t, T: Transport> Server<'t, T> {
    /// The server of one run (the networks are the first [`Server::serve`] call's trainer's).
    pub fn new(transport: &'t mut T, cfg: DistributedConfig) -> Result<Self, LearnError> {
        cfg.validate()?;
        let n = transport.size();
        Ok(Server {
            transport,
            cfg,
            sizes: Vec::new(),
            beta2: Vec::new(),
            last_seen: vec![Duration::ZERO; n],
            sends: vec![VecDeque::new(); n],
            served: Duration::ZERO,
            started: false,
            stats: ExchangeStats::default(),
            membership: Membership::new(n),
            observer: None,
            max_replacements: n.saturating_sub(1) as u64,
        })
    }

    /// Calls `f` with every change of a worker rank's membership (lost, re-admitted) as it
    /// happens, e.g. to log it.
    pub fn on_rank_change(mut self, f: impl FnMut(&RankChange) + 't) -> Self {
        self.observer = Some(Box::new(f));
        self
    }

    /// Which worker ranks are present and the changes so far.
    pub fn membership(&self) -> &Membership {
        &self.membership
    }

    fn changed(&mut self, c: RankChange) {
        match c.kind {
            RankChangeKind::Lost => self.stats.lost += 1,
            RankChangeKind::Readmitted => self.stats.readmitted += 1,
            RankChangeKind::Replaced => self.stats.replaced += 1,
            RankChangeKind::ReplacementFailed => {}
        }
        if let Some(f) = self.observer.as_mut() {
            f(&c);
        }
    }

    /// The exchange counters so far (refused messages included).
    pub fn stats(&self) -> ExchangeStats {
        self.stats
    }

    /// Serves the worker ranks until the run's transitions reach `until` (or `stop` is raised).
    /// The first call pre-trains on the demonstrations where configured (here, once, before any
    /// rank starts) and sends every rank the state to start from.
    pub fn serve(
        &mut self,
        trainer: &mut Trainer,
        until: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<RunSummary, LearnError> {
        let t0 = Instant::now();
        let base_wall = trainer.counters.wall_s;
        let base_served = self.served;
        // The serve clock: time inside this and the earlier calls.
        let clock = move || base_served + t0.elapsed();
        let result = self.serve_until(trainer, until, stop, on_event, &clock, base_wall, t0);
        self.served = clock();
        result
    }

    #[allow(clippy::too_many_arguments)]
    fn serve_until(
        &mut self,
        trainer: &mut Trainer,
        until: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
        clock: &dyn Fn() -> Duration,
        base_wall: f64,
        t0: Instant,
    ) -> Result<RunSummary, LearnError> {
        if !self.started {
            self.sizes = net_sizes(trainer);
            self.beta2 = net_beta2(trainer);
            trainer.pretrain_only(stop, on_event)?;
            for r in 1..self.membership.ranks() {
                self.send_params(trainer, r, clock())?;
            }
            // Pre-training is the server's time, not the ranks' silence.
            let now = clock();
            self.last_seen.iter_mut().for_each(|t| *t = now);
            self.started = true;
        }
        let mut records = Vec::new();
        let mut shown = Instant::now();
        loop {
            trainer.counters.wall_s = base_wall + t0.elapsed().as_secs_f64();
            let progress = trainer.progress();
            if progress.transitions >= until || stop.load(Ordering::Relaxed) {
                return Ok(RunSummary {
                    records,
                    stopped: stop.load(Ordering::Relaxed) && progress.transitions < until,
                    progress,
                });
            }
            let mut busy = false;
            while let Some((from, bytes)) = self.transport.try_recv(None)? {
                busy = true;
                self.stats.bytes_received += bytes.len() as u64;
                if let Some(t) = self.last_seen.get_mut(from) {
                    *t = clock();
                }
                if self.membership.is_lost(from) {
                    self.readmit(trainer, from, clock());
                }
                match message::decode(&bytes, &self.sizes) {
                    Ok((r, Message::Push(p))) if r as usize == from && from > 0 => {
                        self.apply(trainer, from, p, &mut records, on_event);
                        self.stats.exchanges += 1;
                        self.send_params(trainer, from, clock())?;
                    }
                    _ => {
                        // Refused, never applied; the rank still gets the state, so it drops
                        // what it pushed and goes on from the server's state.
                        self.stats.refused += 1;
                        if from > 0 && from < self.membership.ranks() {
                            self.send_params(trainer, from, clock())?;
                        }
                    }
                }
            }
            let now = clock();
            for r in 1..self.membership.ranks() {
                if self.membership.is_lost(r) {
                    continue;
                }
                let silent = now.saturating_sub(self.last_seen.get(r).copied().unwrap_or(now));
                let stuck = self
                    .oldest_send(r)
                    .map_or(Duration::ZERO, |t| now.saturating_sub(t));
                let worst = silent.max(stuck);
                if worst > self.cfg.rank_timeout {
                    let transitions = trainer.progress().transitions;
                    let c = self.membership.lose(r, now, worst, transitions);
                    self.changed(c);
                    if self.membership.present() == 0 {
                        return Err(DistributedError::RankLost {
                            rank: r,
                            silent_s: worst.as_secs_f64(),
                        }
                        .into());
                    }
                }
            }
            if let Some(after) = self.cfg.respawn_after {
                self.replace_lost(trainer, after, clock)?;
            }
            if shown.elapsed() >= Duration::from_millis(500) {
                on_event(Event::Progress(&trainer.progress()));
                shown = Instant::now();
            }
            if !busy {
                std::thread::sleep(Duration::from_micros(500));
            }
        }
    }

    /// Tells every worker rank to stop (lost ones too: a stopped or cut-off rank that comes back
    /// takes it and ends) and waits (up to the rank timeout) until the ranks present took it.
    pub fn finish(&mut self) -> Result<(), LearnError> {
        let bytes = message::encode(0, &Message::Stop)?;
        for r in 1..self.membership.ranks() {
            self.transport.send(r, bytes.clone())?;
        }
        let t0 = Instant::now();
        while t0.elapsed() < self.cfg.rank_timeout {
            // Pushes still arriving are dropped: the run is over.
            while self.transport.try_recv(None)?.is_some() {}
            let pending = (1..self.membership.ranks())
                .filter(|&r| !self.membership.is_lost(r))
                .any(|r| self.transport.in_flight(r) > 0);
            if !pending {
                return Ok(());
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(())
    }

    /// Starts a replacement for each rank lost for `after` or longer that has none yet (up to
    /// the run's limit); each gets the current state.
    fn replace_lost(
        &mut self,
        trainer: &Trainer,
        after: Duration,
        clock: &dyn Fn() -> Duration,
    ) -> Result<(), LearnError> {
        for r in 1..self.membership.ranks() {
            if self.membership.was_replaced(r)
                || self
                    .membership
                    .lost_for(r, clock())
                    .is_none_or(|l| l < after)
            {
                continue;
            }
            if self.stats.replaced >= self.max_replacements {
                return Ok(());
            }
            let t = Instant::now();
            let got = self.transport.replace(r);
            // Starting the process is the server's time, not the other ranks' silence.
            let took = t.elapsed();
            self.last_seen.iter_mut().for_each(|s| *s += took);
            for q in &mut self.sends {
                q.iter_mut().for_each(|s| *s += took);
            }
            let transitions = trainer.progress().transitions;
            let by = match got {
                Ok(by) => {
                    let n = self.membership.add_rank();
                    if n != by {
                        return Err(DistributedError::Config {
                            why: "the transport numbered a replacement rank out of order",
                        }
                        .into());
                    }
                    self.last_seen.push(clock());
                    self.sends.push(VecDeque::new());
                    Ok(by)
                }
                Err(DistributedError::Spawn { why }) => Err(why),
                Err(e) => Err(e.to_string()),
            };
            let started = by.as_ref().ok().copied();
            let c = self.membership.replace(r, by, clock(), transitions);
            self.changed(c);
            if let Some(by) = started {
                self.send_params(trainer, by, clock())?;
            }
        }
        Ok(())
    }

    /// Takes the lost rank `r` back (it was heard from at serve-clock `now`): its sends still
    /// in flight count from now, as its silence does.
    fn readmit(&mut self, trainer: &Trainer, r: usize, now: Duration) {
        if let Some(q) = self.sends.get_mut(r) {
            q.iter_mut().for_each(|t| *t = now);
        }
        let transitions = trainer.progress().transitions;
        if let Some(c) = self.membership.readmit(r, now, transitions) {
            self.changed(c);
        }
    }

    /// Moves the sends on and gives the serve-clock start of the oldest send to `r` still in
    /// flight. (Sends to one rank complete in order, MPI's non-overtaking rule for one tag; were
    /// one to complete early, the age of the rest would read younger, never older.)
    fn oldest_send(&mut self, r: usize) -> Option<Duration> {
        let n = self.transport.in_flight(r);
        let q = self.sends.get_mut(r)?;
        while q.len() > n {
            q.pop_front();
        }
        q.front().copied()
    }

    /// Sends the current state to `to`; `now` is the serve clock (for the send's age).
    fn send_params(
        &mut self,
        trainer: &Trainer,
        to: usize,
        now: Duration,
    ) -> Result<(), LearnError> {
        self.oldest_send(to);
        if let Some(q) = self.sends.get_mut(to) {
            q.push_back(now);
        }
        let sh = &trainer.shared;
        let all = [
            (&sh.actor, &sh.target_actor, &sh.actor_adam),
            (&sh.critic, &sh.target_critic, &sh.critic_adam),
            (&sh.critic2, &sh.target_critic2, &sh.critic2_adam),
        ];
        let nets = all
            .iter()
            .take(self.sizes.len())
            .map(|(p, t, a)| NetParams {
                params: p.to_vec(),
                target: t.to_vec(),
                v: a.v.clone(),
                t: a.t,
            })
            .collect();
        let msg = Message::Params(Params {
            updates: sh.updates,
            transitions: trainer.progress().transitions,
            nets,
        });
        let bytes = message::encode(0, &msg)?;
        self.stats.bytes_sent += bytes.len() as u64;
        self.transport.send(to, bytes)?;
        Ok(())
    }

    fn apply(
        &mut self,
        trainer: &mut Trainer,
        from: usize,
        p: Push,
        records: &mut Vec<EvalRecord>,
        on_event: &mut dyn FnMut(Event<'_>),
    ) {
        let target = trainer.cfg.ddpg.target;
        let td3 = trainer.cfg.td3;
        let workers = trainer.cfg.workers;
        let sh = &mut trainer.shared;
        let u0 = sh.updates;
        let mut all = [
            (&mut sh.actor, &mut sh.target_actor, &mut sh.actor_adam),
            (&mut sh.critic, &mut sh.target_critic, &mut sh.critic_adam),
            (
                &mut sh.critic2,
                &mut sh.target_critic2,
                &mut sh.critic2_adam,
            ),
        ];
        for (((params, tgt, adam), d), &b2) in all.iter_mut().zip(&p.nets).zip(&self.beta2) {
            params.iter_mut().zip(&d.delta).for_each(|(x, dx)| *x += dx);
            let f = b2.powf(d.steps as f32);
            adam.v
                .iter_mut()
                .zip(&d.dv)
                .for_each(|(v, dv)| *v = (f * *v + dv).max(0.0));
            adam.t += d.steps;
            for u in u0 + 1..=u0 + p.updates {
                if td3.actor_due(u) {
                    target.apply(u, params, tgt);
                }
            }
        }
        sh.updates = u0 + p.updates;
        sh.train_return_sum += p.return_sum;
        sh.train_return_n += p.return_n;
        if let Some(w) = trainer.workers.first_mut() {
            w.transitions += p.transitions;
        }
        trainer.counters.episodes += p.episodes;
        for e in p.evals {
            trainer.counters.evals += 1;
            let pr: Progress = trainer.progress();
            let rec = EvalRecord {
                eval_index: trainer.counters.evals,
                episodes: pr.episodes,
                transitions: pr.transitions,
                transitions_per_worker: pr.transitions_per_worker,
                updates: pr.updates,
                wall_s: pr.wall_s,
                mean_return: e.mean_return,
                success_rate: e.success_rate,
                train_return: e.train_return,
                worker: (from - 1) * workers + e.worker as usize,
                proposal_share: None,
            };
            on_event(Event::Eval(&rec));
            records.push(rec);
        }
    }
}
