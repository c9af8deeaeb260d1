//! Rank 0 and the worker ranks of a distributed run (`trainer train --distributed`): the same
//! pipeline as a local run, with a parameter server in place of local threads.

use super::*;

/// Rank 0 of a distributed run as the pipeline drives it ([`TrainPlan::train_distributed`]).
pub trait ParameterServer {
    /// Serves the worker ranks until the run's transitions reach `until` (see
    /// [`Server::serve`]).
    fn serve(
        &mut self,
        trainer: &mut Trainer,
        until: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<RunSummary, LearnError>;
    /// Tells the worker ranks the run is over.
    fn finish(&mut self) -> Result<(), LearnError>;
    /// The exchange counters (refused messages among them).
    fn stats(&self) -> ExchangeStats;
    /// Every change of a worker rank's membership (lost, re-admitted) so far.
    fn rank_changes(&self) -> Vec<RankChange>;
    /// The worker ranks lost now.
    fn lost_now(&self) -> Vec<usize>;
}

/// The seed folder's `distributed.json`: the exchange counters and the membership changes.
#[derive(serde::Serialize)]
struct DistributedRecord {
    #[serde(flatten)]
    stats: ExchangeStats,
    rank_changes: Vec<RankChange>,
}

impl<T: Transport> ParameterServer for Server<'_, T> {
    fn serve(
        &mut self,
        trainer: &mut Trainer,
        until: u64,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(Event<'_>),
    ) -> Result<RunSummary, LearnError> {
        Server::serve(self, trainer, until, stop, on_event)
    }
    fn finish(&mut self) -> Result<(), LearnError> {
        Server::finish(self)
    }
    fn stats(&self) -> ExchangeStats {
        Server::stats(self)
    }
    fn rank_changes(&self) -> Vec<RankChange> {
        self.membership().changes().to_vec()
    }
    fn lost_now(&self) -> Vec<usize> {
        self.membership().lost_now()
    }
}

/// Refuses settings whose state is per process and would silently diverge across ranks.
fn check_distributable(s: &TrainSettings) -> Result<(), TrainRunError> {
    let no = |why| Err(TrainRunError::NotDistributable { why });
    if s.seeds.len() != 1 {
        return no("one seed per distributed run (start one run per seed)");
    }
    if s.run.obs_norm.enabled && !s.run.obs_norm.frozen_from_demos {
        return no("running observation statistics (use frozen statistics from demonstrations)");
    }
    if s.run.quantise.aware_from.is_some() {
        return no("quantisation-aware training (it starts at a rank-local transition count)");
    }
    if s.clone.is_some() {
        return Err(TrainRunError::CloneDistributed);
    }
    if s.pg.is_some() {
        return no("the policy-gradient stage ([pg]: run it on the export with `trainer pg`)");
    }
    if s.run.ddpg.residual.is_some() {
        return no("a residual actor (run.ddpg.residual: fine-tune a clone in a local run)");
    }
    if s.run.ibrl {
        return no("IBRL's proposal (run.ibrl: fine-tune a clone with it in a local run)");
    }
    if s.start.failed_starts > 0 {
        return no("failed-start revisits (start.failed_starts: screen a clone in a local run)");
    }
    Ok(())
}

impl TrainPlan {
    /// Rank 0 of a distributed run: the run folder's pipeline of [`TrainPlan::train`] (one seed),
    /// with `server` collecting the transitions and updates from the worker ranks instead of local
    /// threads. A lost worker rank is left behind (and re-admitted when it comes back); when no
    /// worker rank is left, the run ends with a checkpoint and the error. The exchange counters
    /// and the membership changes go to the seed folder's `distributed.json`.
    pub fn train_distributed(
        &self,
        scene: &Scene,
        resume: bool,
        stop: &AtomicBool,
        on_event: &mut dyn FnMut(TrainEvent<'_>),
        server: &mut dyn ParameterServer,
    ) -> Result<bool, TrainRunError> {
        let s = &self.settings;
        check_distributable(s)?;
        std::fs::create_dir_all(&s.out).map_err(|source| TrainRunError::Create {
            path: s.out.clone(),
            source,
        })?;
        write_file(&s.out.join("settings.toml"), s.to_toml()?.as_bytes())?;
        on_event(TrainEvent::Started { settings: s });
        let seed = s.seeds[0];
        let done = train_seed(
            self,
            seed,
            scene,
            resume,
            stop,
            on_event,
            Some(&mut *server),
        );
        let record = DistributedRecord {
            stats: server.stats(),
            rank_changes: server.rank_changes(),
        };
        let dir = s.out.join(format!("seed-{seed}"));
        write_file(
            &dir.join("distributed.json"),
            serde_json::to_string(&record)?.as_bytes(),
        )?;
        if !done? {
            server.finish()?;
            return Ok(false);
        }
        plot_and_report(&s.out, on_event);
        Ok(true)
    }

    /// A worker rank of a distributed run: W worker threads on this rank's environments, their
    /// updates exchanged with rank 0 through `transport`, until rank 0 ends the run. Writes
    /// nothing into the run folder; reads the demonstrations rank 0 recorded or was given.
    pub fn train_worker_rank<T: Transport>(
        &self,
        scene: &Scene,
        transport: &mut T,
        cfg: DistributedConfig,
        stop: &AtomicBool,
    ) -> Result<(ExchangeStats, Progress), TrainRunError> {
        let s = &self.settings;
        check_distributable(s)?;
        let seed = s.seeds[0];
        let dir = s.out.join(format!("seed-{seed}"));
        let mut run = s.run.clone();
        run.seed = seed;
        // Each worker rank evaluates on its own episodes: together at the local run's rate.
        let ranks = transport.size().saturating_sub(1).max(1) as u64;
        run.eval.every_episodes = run.eval.every_episodes.saturating_mul(ranks);
        let mut trainer = Trainer::new(run, s.input_dim(), ACT_DIM)?;
        let mut rank = WorkerRank::new(transport, cfg, &trainer)?;
        // After rank 0's state: it has recorded the demonstrations by then.
        if !rank.start(&mut trainer)? {
            return Ok((rank.stats(), trainer.progress()));
        }
        if let Some(d) = load_demonstrations(s, &dir)? {
            trainer.set_demonstrations(d)?;
        }
        let env_cfg = s.reward.env_config(s.task.task());
        let starts = &self.starts;
        let stats = rank.run(
            &mut trainer,
            |_| {
                JacoLearnEnv::with_start_states(scene, env_cfg, starts.clone())
                    .with_features(s.features)
            },
            stop,
            &mut |_| {},
        )?;
        Ok((stats, trainer.progress()))
    }
}

/// The demonstrations of a worker rank: the files rank 0 uses (given, or recorded into the seed
/// folder by rank 0 before the ranks started).
fn load_demonstrations(s: &TrainSettings, dir: &Path) -> Result<Option<DemoBuffer>, TrainRunError> {
    use crate::files::demos::{DemoSet, demo_buffer};
    if !s.run.demos.uses_demos() {
        return Ok(None);
    }
    let env_cfg = s.reward.env_config(s.task.task());
    let paths = if s.demo_files.is_empty() {
        vec![dir.join("demos.dxdm")]
    } else {
        s.demo_files.clone()
    };
    let mut sets = Vec::new();
    for path in paths {
        sets.push((DemoSet::load(&path)?, path));
    }
    Ok(Some(demo_buffer(
        &sets,
        s.task.task(),
        env_cfg.reward,
        s.features,
    )?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_residual_actor_and_the_pg_stage_are_refused_across_ranks() {
        let mut s = TrainSettings {
            init_policy: Some("policies/stack.dxpl".into()),
            ..TrainSettings::default()
        };
        assert!(check_distributable(&s).is_ok());
        s.run.ddpg.residual = Some(64);
        assert!(matches!(
            check_distributable(&s),
            Err(TrainRunError::NotDistributable { why }) if why.contains("residual")
        ));
        s.run.ddpg.residual = None;
        s.pg = Some(crate::pipeline::train_settings::PgStage::default());
        assert!(matches!(
            check_distributable(&s),
            Err(TrainRunError::NotDistributable { why }) if why.contains("[pg]")
        ));
        s.pg = None;
        s.run.ibrl = true;
        assert!(matches!(
            check_distributable(&s),
            Err(TrainRunError::NotDistributable { why }) if why.contains("IBRL")
        ));
    }
}
