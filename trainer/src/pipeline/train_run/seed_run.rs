//! One seed of a run: train in checkpoint chunks (fresh or resumed), select, export.

use super::*;

/// Trains one seed, holding its run lock, on local threads or (with `server`) on the worker
/// ranks of a distributed run; returns false if interrupted.
#[allow(clippy::too_many_arguments)]
pub(super) fn train_seed(
    plan: &TrainPlan,
    seed: u64,
    scene: &Scene,
    resume: bool,
    stop: &AtomicBool,
    on_event: &mut dyn FnMut(TrainEvent<'_>),
    mut server: Option<&mut dyn ParameterServer>,
) -> Result<bool, TrainRunError> {
    let (s, starts) = (&plan.settings, &plan.starts);
    let dir = s.out.join(format!("seed-{seed}"));
    std::fs::create_dir_all(&dir).map_err(io_at(&dir))?;
    // Held until this seed is done: a second trainer on it is refused at once.
    let _lock = RunLock::acquire(&dir)?;
    let ckpt = dir.join("checkpoint.bin");
    let log_path = dir.join("eval.jsonl");
    let mut per_seed = s.clone();
    per_seed.seeds = vec![seed];
    per_seed.run.seed = seed;
    let mut trainer = if ckpt.exists() {
        if !resume {
            return Err(TrainRunError::CheckpointExists { path: ckpt });
        }
        let t = Trainer::load(&ckpt).map_err(|source| TrainRunError::Resume {
            path: ckpt.clone(),
            source,
        })?;
        let saved: Option<TrainSettings> = std::fs::read_to_string(dir.join("settings.toml"))
            .ok()
            .and_then(|t| toml::from_str(&t).ok());
        let same_env = saved.as_ref().is_none_or(|o| {
            (o.task, o.reward, &o.start) == (s.task, s.reward, &s.start)
                && (&o.demo_files, o.record_demos, o.demo_noise.to_bits())
                    == (&s.demo_files, s.record_demos, s.demo_noise.to_bits())
                && o.init_policy == s.init_policy
                && o.features == s.features
        });
        if t.config() != &per_seed.run || !same_env {
            return Err(TrainRunError::SettingsDiffer { dir });
        }
        // Records written after the checkpoint (a kill between the two) are dropped: the resumed
        // run writes them again.
        truncate_log(&log_path, t.progress().transitions)?;
        t
    } else {
        // A fresh run: nothing of an earlier one in this folder may be mistaken for its own.
        for stale in [
            &log_path,
            &dir.join("best.json"),
            &dir.join("best_actor.bin"),
            &dir.join("guard.json"),
        ] {
            let _ = std::fs::remove_file(stale);
        }
        let mut t = Trainer::new(per_seed.run.clone(), s.input_dim(), ACT_DIM)?;
        match &plan.init_actor {
            None => {}
            Some(InitActor::Folded(params)) => t.set_initial_actor(params.clone())?,
            Some(InitActor::Normalised(a)) => {
                t.set_initial_actor_normalised(a.params.clone(), &a.mean, &a.inv_std)?;
            }
        }
        t
    };
    if s.run.ibrl {
        // The proposal is the starting policy as the actor takes it (not in checkpoints).
        match &plan.init_actor {
            Some(InitActor::Folded(params)) => trainer.set_proposal(params.clone())?,
            Some(InitActor::Normalised(a)) => trainer.set_proposal(a.params.clone())?,
            None => return Err(SettingsError::IbrlWithoutInit.into()),
        }
    }
    if let Some(d) = demonstrations(s, seed, &dir, scene, on_event)? {
        on_event(TrainEvent::DemosLoaded {
            seed,
            transitions: d.len(),
            fraction: s.run.demos.fraction,
        });
        trainer.set_demonstrations(d)?;
    }
    write_file(&dir.join("settings.toml"), per_seed.to_toml()?.as_bytes())?;
    let mut log = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .map_err(|source| TrainRunError::Open {
            path: log_path.clone(),
            source,
        })?;
    let env_cfg = s.reward.env_config(s.task.task());
    on_event(TrainEvent::SeedStarted {
        seed,
        budget: s.transitions,
        progress: &trainer.progress(),
    });
    loop {
        let done = trainer.progress().transitions;
        if done >= s.transitions {
            break;
        }
        let target = (done / s.checkpoint_every + 1) * s.checkpoint_every;
        let mut write_err = None;
        let mut forward = |ev: Event<'_>| match ev {
            Event::Eval(record) => {
                if let Err(e) = writeln!(log, "{}", record.to_json_line()) {
                    write_err = Some(e);
                }
                on_event(TrainEvent::Eval { seed, record });
            }
            Event::Progress(progress) => on_event(TrainEvent::Progress { seed, progress }),
        };
        let until = target.min(s.transitions);
        let summary = match server.as_deref_mut() {
            None => trainer.run(
                |_| {
                    JacoLearnEnv::with_start_states(scene, env_cfg, starts.clone())
                        .with_features(s.features)
                },
                until,
                stop,
                &mut forward,
            )?,
            Some(srv) => match srv.serve(&mut trainer, until, stop, &mut forward) {
                Ok(summary) => summary,
                Err(LearnError::Distributed(e @ DistributedError::RankLost { .. })) => {
                    // What the server holds is a consistent state: keep it, then fail.
                    let _ = log.flush();
                    trainer
                        .save(&ckpt)
                        .map_err(|source| TrainRunError::SaveCheckpoint {
                            path: ckpt.clone(),
                            source,
                        })?;
                    return Err(LearnError::Distributed(e).into());
                }
                Err(e) => return Err(e.into()),
            },
        };
        if let Some(source) = write_err {
            return Err(TrainRunError::AppendLog {
                path: log_path,
                source,
            });
        }
        log.flush().map_err(io_at(&log_path))?;
        // On disk before the checkpoint that covers these records (resume keeps the log's records
        // up to the checkpoint's, so a power cut must not lose them while keeping the checkpoint).
        log.sync_data().map_err(io_at(&log_path))?;
        // Selection before the checkpoint: a kill in between repeats this chunk on resume, which
        // reaches the same policy and the same selection (deterministic), so the exported file is
        // the uninterrupted run's.
        if !summary.stopped
            && let Some(line) = select_best(&trainer, s, seed, &dir, scene)?
        {
            on_event(TrainEvent::Selection { seed, line });
        }
        trainer
            .save(&ckpt)
            .map_err(|source| TrainRunError::SaveCheckpoint {
                path: ckpt.clone(),
                source,
            })?;
        if summary.stopped {
            on_event(TrainEvent::Stopped { seed });
            return Ok(false);
        }
    }
    if let Some(srv) = server {
        // The worker ranks stop before the export's evaluation takes the cores.
        srv.finish()?;
    }
    on_event(TrainEvent::Trained { seed });
    if let Some(verdict) = run_guard(&trainer, s, seed, &dir, scene)? {
        on_event(TrainEvent::Guarded {
            seed,
            verdict: &verdict,
        });
    }
    let out = dir.join("policy.dxpl");
    let eval = export_selected(&trainer, s, seed, &dir, &out, scene)?;
    on_event(TrainEvent::Exported {
        seed,
        path: &out,
        eval: &eval,
    });
    Ok(true)
}
