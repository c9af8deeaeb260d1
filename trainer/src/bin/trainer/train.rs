//! The `trainer train`, `eval`, `export` and `plot` front ends: flags to settings, the library's
//! pipeline ([`dex_trainer::pipeline::train_run`]), and progress bars and lines on the terminal.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};

use dex_runtime::interface::ACT_DIM;
use dex_trainer::env::Scene;
use dex_trainer::evaluate::{PolicyEval, evaluate_policy_file};
use dex_trainer::files::atomic_write::write_atomic;
use dex_trainer::files::result_record::{RecordContext, ResultRecord};
use dex_trainer::learn::Trainer;
use dex_trainer::pipeline::imitation::ImitationEvent;
use dex_trainer::pipeline::train_run::{TrainEvent, TrainPlan, export_latest, export_selected};
use dex_trainer::pipeline::train_settings::{self, PresetArg, RewardArg, TaskArg, TrainSettings};

use crate::{EvalArgs, TrainArgs};

/// Whether any flag of the learner's components (or a preset) is given. Quantisation-aware
/// training counts: it does not go with demonstrations, so it keeps the paper's learner.
fn learner_flags(a: &TrainArgs) -> bool {
    a.preset.is_some()
        || a.quantise_aware_from.is_some()
        || a.demos.is_some()
        || a.record_demos.is_some()
        || a.demo_fraction.is_some()
        || a.bc_weight.is_some()
        || a.no_q_filter
        || a.td3
        || a.n_step.is_some()
        || a.noise_correlation.is_some()
        || a.finger_noise_scale.is_some()
        || a.action_l2.is_some()
        || a.pretrain_updates.is_some()
        || a.pretrain_actor_lr.is_some()
        || a.obs_norm_from_demos
        || a.q_normalisation.is_some()
        || a.init_policy.is_some()
        || a.clone
        || a.features
        || a.critic_warmup_updates.is_some()
        || a.residual.is_some()
        || a.teacher_labels
        || a.ibrl
}

pub(crate) fn apply_flags(s: &mut TrainSettings, a: &TrainArgs) {
    if let Some(t) = a.task {
        s.task = t;
        if a.config.is_none() {
            if a.out.is_none() {
                s.out = PathBuf::from(format!("runs/{}", format!("{t:?}").to_lowercase()));
            }
            // The default reward is Reach's dense one; another task gets its own reward.
            if a.reward.is_none() && t != TaskArg::Reach {
                s.reward = RewardArg::TaskDefault;
            }
        }
    }
    if let Some(r) = a.reward {
        s.reward = r;
    }
    if let Some(st) = a.start {
        s.start.scheme = st;
    }
    if let Some(p) = a.in_hand_probability {
        s.start.in_hand_probability = p;
    }
    if let Some(r) = a.replay_steps {
        s.run.updates_per_step = r;
    }
    if let Some(w) = a.workers {
        s.run.workers = w;
    }
    if let Some(seeds) = &a.seeds {
        s.seeds.clone_from(seeds);
    }
    if let Some(n) = a.transitions {
        s.transitions = n;
    }
    if let Some(b) = a.batch {
        s.run.ddpg.batch_size = b;
    }
    if let Some(h) = &a.hidden {
        s.run.ddpg.actor_hidden.clone_from(h);
        s.run.ddpg.critic_hidden.clone_from(h);
    }
    if a.per_worker_replay {
        s.run.replay.shared = false;
    }
    if let Some(t) = a.quantise_aware_from {
        s.run.quantise.aware_from = Some(t);
    }
    if let Some(o) = &a.out {
        s.out.clone_from(o);
    }
    if let Some(c) = a.checkpoint_every {
        s.checkpoint_every = c;
    }
    if let Some(e) = a.final_eval_episodes {
        s.final_eval_episodes = e;
    }
    if let Some(e) = a.select_best_episodes {
        s.select_best_episodes = e;
    }
    match a.preset {
        Some(PresetArg::Finetune) => {
            PresetArg::Finetune.apply(s);
            if a.transitions.is_none() && a.config.is_none() {
                s.transitions = train_settings::FINETUNE_TRANSITIONS;
            }
            // The seed the task's clone stage is written for (1 where it has members).
            if a.seeds.is_none() && a.config.is_none() {
                s.seeds = vec![s.task.default_pipeline().seed];
            }
        }
        Some(p) => p.apply(s),
        // A task with no settings file and no learner flag gets its default pipeline, at the
        // budget it was measured with (one definition: `TaskArg::default_pipeline`).
        None if a.config.is_none() && !learner_flags(a) => {
            let d = s.task.default_pipeline();
            d.preset.apply(s);
            if a.transitions.is_none() {
                s.transitions = d.transitions;
            }
            if a.seeds.is_none() {
                s.seeds = vec![d.seed];
            }
            if let Some(c) = d.checkpoint_every
                && a.checkpoint_every.is_none()
            {
                s.checkpoint_every = c;
            }
        }
        None => {}
    }
    if let Some(g) = a.guard_episodes {
        s.guard_episodes = g;
    }
    match a.pg_iterations {
        Some(0) => s.pg = None,
        Some(n) => s.pg.get_or_insert_with(Default::default).iterations = n,
        None => {}
    }
    // After the preset, which sets the actor's rate: the flags win over it.
    apply_learning_rates(s, a);
    if let Some(d) = &a.demos {
        s.demo_files.clone_from(d);
    }
    if let Some(n) = a.record_demos {
        s.record_demos = n;
    }
    if let Some(f) = a.demo_fraction {
        s.run.demos.fraction = f;
    }
    if let Some(w) = a.bc_weight {
        s.run.demos.bc_weight = w;
    }
    if a.no_q_filter {
        s.run.demos.q_filter = false;
    }
    if a.td3 {
        s.run.td3 = dex_trainer::learn::Td3Config::td3();
    }
    if let Some(n) = a.n_step {
        s.run.n_step = n;
    }
    if let Some(c) = a.noise_correlation {
        s.run.noise.correlation = c;
    }
    if let Some(f) = a.finger_noise_scale {
        let arm = dex_trainer::env::scene::ARM_JOINTS;
        s.run.noise.scale = (0..ACT_DIM)
            .map(|j| if j < arm { 1.0 } else { f })
            .collect();
    }
    if let Some(w) = a.action_l2 {
        s.run.ddpg.action_l2 = w;
    }
    if let Some(p) = &a.init_policy {
        s.init_policy = Some(p.clone());
    }
    if a.clone {
        s.clone.get_or_insert_with(Default::default);
    }
    if a.features {
        s.features = true;
    }
    if let Some(n) = a.critic_warmup_updates {
        s.run.critic_warmup_updates = n;
    }
    if let Some(n) = a.residual {
        s.run.ddpg.residual = Some(n);
    }
    if a.teacher_labels {
        s.run.teacher_labels = true;
    }
    if a.ibrl {
        s.run.ibrl = true;
    }
    if let Some(n) = a.pretrain_updates {
        s.run.demos.pretrain_updates = n;
    }
    if let Some(lr) = a.pretrain_actor_lr {
        s.run.demos.pretrain_actor_lr = Some(lr);
    }
    if let Some(q) = a.q_normalisation {
        s.run.demos.q_normalisation = q;
    }
    if a.obs_norm_from_demos {
        s.run.obs_norm.enabled = true;
        s.run.obs_norm.frozen_from_demos = true;
    }
}

fn apply_learning_rates(s: &mut TrainSettings, a: &TrainArgs) {
    if let Some(lr) = a.lr {
        s.run.actor_adam.lr = lr;
        s.run.critic_adam.lr = lr;
    }
    if let Some(lr) = a.actor_lr {
        s.run.actor_adam.lr = lr;
    }
    if let Some(lr) = a.critic_lr {
        s.run.critic_adam.lr = lr;
    }
}

/// The MuJoCo scene, or an error that says how to install MuJoCo.
pub fn load_scene() -> anyhow::Result<Scene> {
    Scene::load().context("cannot build the MuJoCo scene; run `bash scripts/setup-mujoco.sh` first")
}

/// A progress bar of `len` steps drawn with `template` (hidden when `quiet`).
pub fn bar(len: u64, quiet: bool, template: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(len);
    if let Ok(style) = ProgressStyle::with_template(template) {
        b.set_style(style.progress_chars("=> "));
    }
    b
}

/// A flag that Ctrl-C raises (installed once per process).
pub fn stop_flag() -> anyhow::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    let raised = Arc::clone(&stop);
    ctrlc::set_handler(move || raised.store(true, Ordering::SeqCst))
        .context("cannot install the Ctrl-C handler")?;
    Ok(stop)
}

/// `trainer train`.
pub fn train(args: TrainArgs) -> anyhow::Result<()> {
    let stop = stop_flag()?;
    train_with(&args, &stop).map(|_| ())
}

/// Trains the runs `args` describes until done or `stop` is raised; returns whether every seed
/// finished (false: stopped with checkpoints saved).
pub fn train_with(args: &TrainArgs, stop: &AtomicBool) -> anyhow::Result<bool> {
    let mut s = train_settings::load(args.config.as_deref())?;
    apply_flags(&mut s, args);
    let plan = TrainPlan::new(s)?;
    let scene = load_scene()?;
    let mut terminal = Terminal::new(args.quiet);
    Ok(plan.train(&scene, args.resume, stop, &mut |ev| terminal.show(ev))?)
}

/// `trainer train`'s output: a progress bar per seed (or, with `--quiet`, a line per evaluation)
/// and a line per milestone.
pub(crate) struct Terminal {
    /// `--quiet`.
    quiet: bool,
    /// The current seed's bar.
    bar: Option<ProgressBar>,
    /// When the current seed started in this call.
    started: Instant,
    /// Updates of the current seed before this call.
    start_updates: u64,
    /// Transitions of the current seed before this call.
    start_transitions: u64,
    /// The latest evaluation, for the bar's message.
    last_eval: String,
}

impl Terminal {
    pub(crate) fn new(quiet: bool) -> Self {
        Terminal {
            quiet,
            bar: None,
            started: Instant::now(),
            start_updates: 0,
            start_transitions: 0,
            last_eval: String::from("no evaluation yet"),
        }
    }

    pub(crate) fn show(&mut self, ev: TrainEvent<'_>) {
        match ev {
            TrainEvent::Started { settings: s } => println!(
                "training {:?} ({:?} reward), {} transitions x {} seed(s), R = {}, W = {}, into {}",
                s.task,
                s.reward,
                s.transitions,
                s.seeds.len(),
                s.run.updates_per_step,
                s.run.workers,
                s.out.display()
            ),
            TrainEvent::CloneStarted { seed, dir } => println!(
                "seed {seed}: clone stage (the imitation learner) in {}",
                dir.display()
            ),
            TrainEvent::EnsembleStarted {
                seed,
                dir,
                members,
                parallel,
            } => println!(
                "seed {seed}: {members} member clones, {parallel} at a time, in {}, then one \
                 network distilled from their mean",
                dir.display()
            ),
            TrainEvent::MemberStarted {
                seed,
                member,
                member_seed,
            } => println!("seed {seed}: member {member} (imitation seed {member_seed}) started"),
            TrainEvent::Member {
                seed,
                member,
                event,
            } => show_member(seed, member, event),
            TrainEvent::MemberDone {
                seed,
                member,
                policy,
            } => println!("seed {seed}: member {member} done: {}", policy.display()),
            TrainEvent::DistilStarted {
                seed,
                dir,
                teachers,
                rounds,
            } => println!(
                "seed {seed}: distilling the mean of {teachers} members into one network \
                 ({rounds} DAgger round(s)) in {}",
                dir.display()
            ),
            TrainEvent::Clone { seed, event } => self.show_clone(seed, event),
            TrainEvent::Cloned { seed, policy } => {
                if let Some(pb) = self.bar.take() {
                    pb.finish_and_clear();
                }
                println!(
                    "seed {seed}: the actor starts from the clone {}",
                    policy.display()
                );
            }
            TrainEvent::ScreeningStarted { seed, starts } => println!(
                "seed {seed}: screening the starting policy on {starts} starts (failed-start revisits)"
            ),
            TrainEvent::Screened {
                seed,
                screening,
                probability,
            } => println!(
                "seed {seed}: the starting policy failed {} of {} screening starts; {:.0}% of the \
                 training episodes revisit them",
                screening.failed.len(),
                screening.screened,
                if screening.failed.is_empty() {
                    0.0
                } else {
                    probability * 100.0
                }
            ),
            TrainEvent::RecordingDemos {
                seed,
                episodes,
                path,
            } => println!(
                "seed {seed}: recording {episodes} Markov-demonstrator episodes into {}",
                path.display()
            ),
            TrainEvent::DemosLoaded {
                seed,
                transitions,
                fraction,
            } => println!(
                "seed {seed}: {transitions} demonstration transitions, {:.0}% of each batch",
                100.0 * fraction
            ),
            TrainEvent::SeedStarted {
                seed,
                budget,
                progress,
            } => {
                let pb = bar(
                    budget,
                    self.quiet,
                    "{prefix} [{elapsed_precise}] [{bar:30}] {pos}/{len} transitions {msg}",
                );
                pb.set_prefix(format!("seed {seed}"));
                pb.set_position(progress.transitions);
                self.bar = Some(pb);
                self.started = Instant::now();
                self.start_updates = progress.updates;
                self.start_transitions = progress.transitions;
                self.last_eval = String::from("no evaluation yet");
            }
            TrainEvent::Eval { seed, record: r } => {
                self.last_eval = format!(
                    "eval {}: return {:.2}, success {:.0}%",
                    r.eval_index,
                    r.mean_return,
                    r.success_rate * 100.0
                );
                if self.quiet {
                    println!(
                        "seed {seed} {} transitions: {}",
                        r.transitions, self.last_eval
                    );
                }
            }
            TrainEvent::Progress { progress: p, .. } => {
                let secs = self.started.elapsed().as_secs_f64().max(1e-9);
                if let Some(pb) = &self.bar {
                    pb.set_position(p.transitions);
                    pb.set_message(format!(
                        "| {:.0} tr/s {:.0} upd/s | {}",
                        (p.transitions - self.start_transitions) as f64 / secs,
                        (p.updates - self.start_updates) as f64 / secs,
                        self.last_eval
                    ));
                }
            }
            TrainEvent::Selection { seed, line } => match (&self.bar, self.quiet) {
                (Some(pb), false) => pb.println(line),
                (None, false) => println!("{line}"),
                (_, true) => println!("seed {seed}: {line}"),
            },
            TrainEvent::Guarded { seed, verdict } => {
                let line = format!("seed {seed}: {}", verdict.line());
                match &self.bar {
                    Some(pb) => pb.println(line),
                    None => println!("{line}"),
                }
            }
            TrainEvent::Stopped { .. } => {
                if let Some(pb) = self.bar.take() {
                    pb.abandon();
                }
                println!("stopped: checkpoint saved; continue with the same command and --resume");
            }
            TrainEvent::Trained { .. } => {
                if let Some(pb) = self.bar.take() {
                    pb.finish();
                }
            }
            TrainEvent::PgStarted {
                seed,
                dir,
                iterations,
            } => {
                println!(
                    "seed {seed}: policy-gradient stage ({iterations} iterations) in {}",
                    dir.display()
                );
                let pb = bar(
                    u64::from(iterations),
                    self.quiet,
                    "{prefix} [{elapsed_precise}] [{bar:30}] {pos}/{len} iterations {msg}",
                );
                pb.set_prefix(format!("seed {seed} pg"));
                self.bar = Some(pb);
            }
            TrainEvent::PgIteration {
                seed,
                report: r,
                replicates,
            } => {
                let line = r.line(replicates);
                match (&self.bar, self.quiet) {
                    (Some(pb), false) => {
                        pb.set_position(u64::from(r.iteration + 1));
                        pb.set_message(line);
                    }
                    _ => println!("seed {seed} pg {line}"),
                }
            }
            TrainEvent::Exported { seed, path, eval } => {
                if let Some(pb) = self.bar.take() {
                    pb.finish_and_clear();
                }
                println!(
                    "seed {seed}: exported {} - runtime evaluation {}",
                    path.display(),
                    describe(eval)
                );
            }
            TrainEvent::MalformedLog { dir, lines } => warn_malformed(dir, lines),
            TrainEvent::Plotted { files } => {
                files.iter().for_each(|f| println!("plot: {}", f.display()));
            }
            TrainEvent::PlotFailed { error } => {
                eprintln!("no plot: {:#}", anyhow::Error::from(error));
            }
            _ => {}
        }
    }
}

impl Terminal {
    /// A clone stage's progress: recording, a bar over the cloning steps, each round's selection.
    fn show_clone(&mut self, seed: u64, event: ImitationEvent<'_>) {
        match event {
            ImitationEvent::Recording { round, episodes } => {
                println!("seed {seed}: clone round {round}: recording {episodes} episodes");
            }
            ImitationEvent::Cloning { round, steps } => {
                let pb = bar(
                    steps,
                    self.quiet,
                    "{prefix} [{elapsed_precise}] [{bar:30}] {pos}/{len} cloning steps",
                );
                pb.set_prefix(format!("seed {seed} clone round {round}"));
                self.bar = Some(pb);
            }
            ImitationEvent::CloneStep(step, _) => {
                if let Some(pb) = &self.bar {
                    pb.set_position(step);
                }
            }
            ImitationEvent::Round(r) => {
                if let Some(pb) = self.bar.take() {
                    pb.finish_and_clear();
                }
                println!(
                    "seed {seed}: clone round {}: {} env steps, {} cloning steps, {:.0} s: \
                     selection success {:.1}%",
                    r.eval_index,
                    r.transitions,
                    r.updates,
                    r.wall_s,
                    100.0 * r.success_rate
                );
            }
        }
    }
}

/// A member clone's progress, one line per milestone (members run side by side, so no bars).
fn show_member(seed: u64, member: &str, event: ImitationEvent<'_>) {
    match event {
        ImitationEvent::Recording { round, episodes } => {
            println!("seed {seed}: member {member} round {round}: recording {episodes} episodes");
        }
        ImitationEvent::Cloning { round, steps } => {
            println!("seed {seed}: member {member} round {round}: {steps} cloning steps");
        }
        ImitationEvent::CloneStep(..) => {}
        ImitationEvent::Round(r) => println!(
            "seed {seed}: member {member} round {}: {} env steps, {:.0} s: selection success \
             {:.1}%",
            r.eval_index,
            r.transitions,
            r.wall_s,
            100.0 * r.success_rate
        ),
    }
}

/// One line: successes, rate, 95% interval and mean return.
pub fn describe(e: &PolicyEval) -> String {
    format!("success {e}")
}

/// The warning about a seed folder's malformed `eval.jsonl` lines.
pub fn warn_malformed(dir: &Path, bad: usize) {
    eprintln!("warning: {bad} malformed lines in {}", dir.display());
}

/// `trainer plot`: learning curves of every seed in a run folder.
pub fn plot_run(run: &Path) -> anyhow::Result<Vec<PathBuf>> {
    Ok(dex_trainer::pipeline::run_plots::plot_run(
        run,
        &mut warn_malformed,
    )?)
}

/// `trainer export`: the policy `trainer train` exports for a seed (the best checkpoint on the
/// selection starts, else the latest checkpoint) as a policy file.
pub fn export_checkpoint(
    dir: &Path,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
    latest: bool,
) -> anyhow::Result<()> {
    let ckpt = dir.join("checkpoint.bin");
    let trainer =
        Trainer::load(&ckpt).with_context(|| format!("cannot read {}", ckpt.display()))?;
    let scene = load_scene()?;
    let eval = if latest {
        export_latest(&trainer, s, seed, out, &scene)?
    } else {
        export_selected(&trainer, s, seed, dir, out, &scene)?
    };
    println!("runtime evaluation {}", describe(&eval));
    Ok(())
}

/// `trainer eval`.
pub fn eval(args: &EvalArgs) -> anyhow::Result<()> {
    let bytes = std::fs::read(&args.policy)
        .with_context(|| format!("cannot read {}", args.policy.display()))?;
    let aligned = dex_runtime::aligned::aligned_copy(&bytes);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes())
        .with_context(|| format!("{} is not a valid policy file", args.policy.display()))?;
    let own = TaskArg::from_policy(view.body().task);
    let task = args.task.unwrap_or(own);
    if task != own {
        bail!(
            "{} is a {own:?} policy; --task {task:?} would evaluate it on another task (leave \
             --task out, or pass {own:?})",
            args.policy.display()
        );
    }
    let scene = load_scene()?;
    let settings = args.at.settings(task, args.episodes, args.envelope);
    let started = Instant::now();
    let pb = bar(
        u64::from(args.episodes),
        false,
        "eval [{elapsed_precise}] [{bar:30}] {pos}/{len} episodes",
    );
    let e = match &args.actions {
        None => evaluate_policy_file(&bytes, &scene, &settings, &|| pb.inc(1))?,
        Some(path) => {
            let traces = dex_trainer::evaluate::episode_traces(&bytes, &scene, &settings)?;
            let mut lines = String::new();
            for (e, (_, _, actions)) in traces.iter().enumerate() {
                for (t, a) in actions.iter().enumerate() {
                    lines.push_str(&dex_runtime::action_trace::action_line(e as u64, t, a));
                }
            }
            write_atomic(path, lines.as_bytes())
                .with_context(|| format!("cannot write {}", path.display()))?;
            let outcomes: Vec<(f64, bool)> = traces.iter().map(|&(r, ok, _)| (r, ok)).collect();
            for (e, (r, ok)) in outcomes.iter().enumerate() {
                println!("episode {e} return {r:.4} success {ok}");
            }
            PolicyEval::from_outcomes(&outcomes)
        }
    };
    pb.finish_and_clear();
    println!(
        "{} on {:?}, {} random starts from seed {}: {}",
        args.policy.display(),
        task,
        args.episodes,
        args.at.seed,
        describe(&e)
    );
    if let (Some(path), Some(section), Some(what)) = (&args.record, &args.section, &args.what) {
        let ctx = RecordContext {
            section,
            what,
            policy: &args.policy,
            bytes: &bytes,
            command: std::env::args().collect::<Vec<_>>().join(" "),
            start_seed: args.at.seed,
            can_quantisation: !args.at.no_can_quantisation,
            envelope: args.envelope,
            wall_s: started.elapsed().as_secs_f64(),
            threads: if args.actions.is_some() {
                1
            } else {
                args.at.threads
            },
        };
        let json = ResultRecord::new(&e, &ctx).to_json()?;
        write_atomic(path, json.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        println!("record written to {}", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    /// `trainer train ARGS` as settings, not yet validated.
    fn flagged(args: &[&str]) -> TrainSettings {
        let cli = crate::Cli::try_parse_from(["trainer", "train"].iter().chain(args).copied())
            .expect("flags parse");
        let crate::Command::Train(a) = cli.command else {
            panic!("not train")
        };
        let mut s = TrainSettings::default();
        apply_flags(&mut s, &a);
        s
    }

    /// `trainer train ARGS` as validated settings.
    fn settings(args: &[&str]) -> TrainSettings {
        let s = flagged(args);
        s.validate().expect("valid");
        s
    }

    #[test]
    fn pg_iterations_add_the_policy_gradient_stage_to_the_default_pipeline() {
        let s = settings(&["--task", "stack", "--pg-iterations", "30"]);
        let mut lib = TrainSettings::for_task(TaskArg::Stack);
        lib.pg = Some(train_settings::PgStage {
            iterations: 30,
            ..Default::default()
        });
        assert_eq!(s, lib, "the default pipeline, then the stage");
        assert_eq!(
            settings(&["--task", "stack", "--pg-iterations", "0"]).pg,
            None
        );
    }

    #[test]
    fn a_task_without_learner_flags_gets_its_default_pipeline() {
        use train_settings::{
            FINETUNE_GUARD_EPISODES, FINETUNE_TRANSITIONS, REACH_DEMOS_CHECKPOINT_EVERY,
            REACH_DEMOS_TRANSITIONS,
        };
        // Grasp, StackInHand, Stack: the clone stage and the guarded fine-tune, as the library
        // defines them for every front end.
        for task in ["grasp", "stack-in-hand", "stack"] {
            let s = settings(&["--task", task]);
            let mut lib = TrainSettings::for_task(s.task);
            lib.seeds.clone_from(&s.seeds);
            assert_eq!(s, lib, "{task}");
            assert!(s.clone.is_some() && s.features, "{task}");
            assert_eq!(
                (s.transitions, s.guard_episodes, s.record_demos),
                (FINETUNE_TRANSITIONS, FINETUNE_GUARD_EPISODES, 200)
            );
            assert_eq!(s.run.ddpg.gamma, 0.98);
            // Grasp: the shipped file's ensemble and distillation, at the seed its members are
            // written for; Stack: the shipped file's close-start clone at its seed, 9;
            // StackInHand: one clone, seed 0.
            let members = !s.clone.as_ref().unwrap().members.is_empty();
            assert_eq!(members, task == "grasp", "{task}");
            let seed = match task {
                "grasp" => 1,
                "stack" => 9,
                _ => 0,
            };
            assert_eq!(s.seeds, vec![seed], "{task}");
        }
        // Budget, seeds and the guard's starts still apply; any learner flag starts from the
        // paper's DDPG instead.
        let s = settings(&[
            "--task",
            "stack",
            "--transitions",
            "5000",
            "--seeds",
            "3",
            "--guard-episodes",
            "50",
        ]);
        assert_eq!(
            (
                s.transitions,
                s.seeds.clone(),
                s.record_demos,
                s.guard_episodes
            ),
            (5000, vec![3], 200, 50)
        );
        for flags in [
            &["--task", "grasp", "--preset", "paper"][..],
            &["--task", "grasp", "--td3"][..],
            &["--task", "reach", "--td3"][..],
            &["--task", "reach", "--quantise-aware-from", "100"][..],
        ] {
            let s = settings(flags);
            assert_eq!(s.record_demos, 0, "{flags:?}");
            assert_eq!(s.run.demos, dex_trainer::learn::DemoDataConfig::default());
            assert!(s.clone.is_none() && s.guard_episodes == 0, "{flags:?}");
        }
        // Reach: the learner from demonstrations, at its own budget and checkpoint interval (and
        // its own discount); explicitly with the preset, at the budget the flags give.
        let s = settings(&["--task", "reach"]);
        assert_eq!(
            (
                s.record_demos,
                s.run.ddpg.gamma,
                s.transitions,
                s.checkpoint_every
            ),
            (
                200,
                0.9,
                REACH_DEMOS_TRANSITIONS,
                REACH_DEMOS_CHECKPOINT_EVERY
            )
        );
        assert_eq!(s.run.demos.pretrain_updates, 20_000);
        assert!(s.clone.is_none());
        let s = settings(&["--task", "reach", "--preset", "demos"]);
        assert_eq!((s.record_demos, s.run.ddpg.gamma), (200, 0.9));
        assert_ne!(s.transitions, REACH_DEMOS_TRANSITIONS);
        // Flags win over the preset, also over the learning rate it sets.
        let s = settings(&["--task", "grasp", "--actor-lr", "1e-4"]);
        assert_eq!((s.record_demos, s.run.actor_adam.lr), (200, 1e-4));
        let s = settings(&["--preset", "demos", "--lr", "2e-4"]);
        assert_eq!((s.run.actor_adam.lr, s.run.critic_adam.lr), (2e-4, 2e-4));
        // A guard without a policy to guard is refused.
        let s = flagged(&[
            "--task",
            "grasp",
            "--preset",
            "paper",
            "--guard-episodes",
            "10",
        ]);
        assert!(matches!(
            s.validate(),
            Err(train_settings::SettingsError::GuardWithoutInit)
        ));
    }

    /// `trainer train --task stack --preset paper EXTRA` as validated settings.
    fn validate(extra: &[&str]) -> Result<(), train_settings::SettingsError> {
        let mut args = vec!["--task", "stack", "--preset", "paper"];
        args.extend_from_slice(extra);
        flagged(&args).validate()
    }

    #[test]
    fn a_residual_needs_a_base_and_a_width_in_range() {
        assert!(matches!(
            validate(&["--residual", "64"]),
            Err(train_settings::SettingsError::ResidualWithoutInit)
        ));
        assert!(matches!(
            validate(&["--residual", "0", "--clone"]),
            Err(train_settings::SettingsError::Learner(_))
        ));
        assert!(matches!(
            validate(&["--residual", "5000", "--clone"]),
            Err(train_settings::SettingsError::Learner(_))
        ));
        let s = settings(&["--task", "stack", "--clone", "--residual", "64"]);
        assert_eq!(s.run.ddpg.residual, Some(64));
        let widened: Vec<usize> = s.run.ddpg.actor_hidden.iter().map(|h| h + 64).collect();
        assert_eq!(s.run.ddpg.actor_widths(), widened);
    }

    #[test]
    fn ibrl_needs_a_starting_policy_and_excludes_a_residual() {
        assert!(matches!(
            validate(&["--ibrl"]),
            Err(train_settings::SettingsError::IbrlWithoutInit)
        ));
        assert!(matches!(
            validate(&["--ibrl", "--clone", "--residual", "64"]),
            Err(train_settings::SettingsError::Learner(_))
        ));
        let s = settings(&["--task", "stack", "--clone", "--ibrl"]);
        assert!(s.run.ibrl);
        assert!(s.validate().is_ok());
    }

    #[test]
    fn the_finetune_preset_is_the_clone_stage_and_rl_that_keeps_the_clone() {
        let s = settings(&["--task", "stack", "--preset", "finetune"]);
        assert_eq!(
            s.clone,
            Some(train_settings::CloneStage::for_task(TaskArg::Stack))
        );
        assert_eq!(s.seeds, vec![9]);
        let s = settings(&["--task", "stack-in-hand", "--preset", "finetune"]);
        assert_eq!(s.clone, Some(train_settings::CloneStage::default()));
        let s = settings(&["--task", "stack", "--preset", "finetune", "--seeds", "2,3"]);
        assert_eq!(s.seeds, vec![2, 3]);
        let s = settings(&["--task", "stack", "--preset", "finetune"]);
        assert!(s.features && s.init_policy.is_none());
        assert_eq!(s.transitions, train_settings::FINETUNE_TRANSITIONS);
        assert_eq!(
            (
                s.run.demos.bc_weight,
                s.run.critic_warmup_updates,
                s.record_demos
            ),
            (5.0, 10_000, 200)
        );
        assert_eq!(s.run.ddpg.actor_hidden, vec![256, 256]);
        // The clone stage takes the task's imitation recipe with the run's seed and actor.
        let cfg = s.clone.as_ref().unwrap().imitation(&s, 7);
        assert_eq!((cfg.seed, cfg.bc.hidden.clone()), (7, vec![256, 256]));
        assert_eq!(cfg.dart_episodes, 800); // Stack's recipe
        let s = settings(&[
            "--task",
            "grasp",
            "--preset",
            "finetune",
            "--transitions",
            "1000",
        ]);
        assert_eq!(s.transitions, 1000);
        // --clone alone adds the single-clone stage to the run's own learner.
        let s = settings(&["--task", "grasp", "--clone", "--hidden", "64,64"]);
        assert!(s.clone.is_some() && s.run.demos.bc_weight != 5.0);
        assert!(s.clone.as_ref().unwrap().members.is_empty());
        // Seed 0 would give Grasp's members negative seeds: refused before any work.
        let s = flagged(&["--task", "grasp", "--seeds", "0,1"]);
        assert!(matches!(
            s.validate(),
            Err(train_settings::SettingsError::CloneMembers(
                dex_trainer::pipeline::clone_members::MembersError::NegativeSeed { .. }
            ))
        ));
    }
}
