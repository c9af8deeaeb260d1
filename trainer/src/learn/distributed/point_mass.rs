//! The toy [`PointMass`] task across ranks: the same server and worker code as a Jaco run, without
//! MuJoCo or a run folder. `trainer distributed-point-mass` (hidden) runs it; the CI's
//! distributed tests use it to check that several ranks learn together.

use super::server::Server;
use super::worker::WorkerRank;
use super::{DistributedConfig, ExchangeStats, Transport};
use crate::learn::trainer::evaluate_actor;
use crate::learn::{
    DdpgConfig, EvalConfig, LearnError, PointMass, PointMassConfig, Progress, ReplayConfig,
    RunConfig, TargetUpdate, Trainer,
};
use std::sync::atomic::AtomicBool;

/// The learner of the point-mass runs (as `trainer/tests/learn_point_mass.rs` uses locally).
pub fn point_mass_config(seed: u64, workers: usize) -> RunConfig {
    RunConfig {
        ddpg: DdpgConfig {
            actor_hidden: vec![64, 64],
            critic_hidden: vec![64, 64],
            batch_size: 64,
            gamma: 0.95,
            target: TargetUpdate::Polyak { tau: 0.01 },
            ..DdpgConfig::default()
        },
        workers,
        learning_starts: 500,
        replay: ReplayConfig {
            capacity: 50_000,
            shared: true,
        },
        eval: EvalConfig {
            every_episodes: 20,
            episodes: 20,
            max_steps: 100,
            ..EvalConfig::default()
        },
        seed,
        ..RunConfig::default()
    }
}

/// What rank 0 of a point-mass run reports.
#[derive(Debug, Clone, PartialEq)]
pub struct PointMassOutcome {
    /// Success rate of the final actor over the evaluation episodes.
    pub success_rate: f64,
    /// Mean return there.
    pub mean_return: f64,
    /// The run's counters.
    pub progress: Progress,
    /// The server's exchange counters.
    pub stats: ExchangeStats,
}

/// Trains the point-mass task on all ranks of `transport` until `transitions` (all ranks); rank 0
/// then evaluates the actor on `eval_episodes` episodes and returns the outcome, the worker ranks
/// return `None` (and their counters).
pub fn run_point_mass<T: Transport>(
    transport: &mut T,
    cfg: DistributedConfig,
    run: RunConfig,
    transitions: u64,
    eval_episodes: usize,
) -> Result<(Option<PointMassOutcome>, ExchangeStats, Progress), LearnError> {
    let env = |_| PointMass::new(PointMassConfig::default());
    let stop = AtomicBool::new(false);
    let mut trainer = Trainer::new(run, 6, 2)?;
    if transport.rank() == 0 {
        let mut server = Server::new(transport, cfg)?;
        server.serve(&mut trainer, transitions, &stop, &mut |_| {})?;
        server.finish()?;
        let (net, params) = trainer.actor();
        let mut e = env(0);
        let (mean_return, success_rate) =
            evaluate_actor(net, params, &mut e, eval_episodes, 100, 1_000_000)?;
        let stats = server.stats();
        let progress = trainer.progress();
        Ok((
            Some(PointMassOutcome {
                success_rate,
                mean_return,
                progress: progress.clone(),
                stats,
            }),
            stats,
            progress,
        ))
    } else {
        let mut rank = WorkerRank::new(transport, cfg, &trainer)?;
        if !rank.start(&mut trainer)? {
            return Ok((None, rank.stats(), trainer.progress()));
        }
        let stats = rank.run(&mut trainer, env, &stop, &mut |_| {})?;
        Ok((None, stats, trainer.progress()))
    }
}
