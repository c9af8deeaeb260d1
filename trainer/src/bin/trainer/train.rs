//! The `trainer` subcommands' work: training loop with checkpoints, export, evaluation and plots.

use std::fs::OpenOptions;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};

use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_trainer::env::{Demonstrator, Scene, StartStates};
use dex_trainer::evaluate::{EvalSettings, PolicyEval, evaluate_policy_file};
use dex_trainer::export::{ExportInfo, ObsNormalisation, export_actor};
use dex_trainer::jaco::JacoLearnEnv;
use dex_trainer::learn::{EvalRecord, Event, Trainer};
use dex_trainer::plot::{Condition, Metric, XAxis, plot, read_eval_log};
use dex_trainer::policy_demo::{DemoSource, PolicyDemonstration};

use crate::config::{self, TaskArg, TrainSettings};
use crate::{EvalArgs, TrainArgs};

/// Writes `bytes` to `path` atomically (temporary file, fsync, rename).
fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let tmp = path.with_extension("tmp");
    {
        let mut f = std::fs::File::create(&tmp)
            .with_context(|| format!("cannot create {}", tmp.display()))?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

fn apply_flags(s: &mut TrainSettings, a: &TrainArgs) {
    if let Some(t) = a.task {
        s.task = t;
        if a.config.is_none() {
            if a.out.is_none() {
                s.out = PathBuf::from(format!("runs/{}", format!("{t:?}").to_lowercase()));
            }
            // The default reward is Reach's dense one; another task gets its own reward.
            if a.reward.is_none() && t != TaskArg::Reach {
                s.reward = config::RewardArg::TaskDefault;
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
    if let Some(p) = a.preset {
        p.apply(s);
    }
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
    if let Some(n) = a.pretrain_updates {
        s.run.demos.pretrain_updates = n;
    }
    if let Some(q) = a.q_normalisation {
        s.run.demos.q_normalisation = q;
    }
    if a.obs_norm_from_demos {
        s.run.obs_norm.enabled = true;
        s.run.obs_norm.frozen_from_demos = true;
    }
}

/// The demonstration buffer of a seed's run: the settings' files, or `record_demos` episodes of
/// the Markov demonstrator recorded into the seed's folder (`demos.dxdm`, reused when there).
fn demonstrations(
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    scene: &Scene,
) -> anyhow::Result<Option<dex_trainer::learn::DemoBuffer>> {
    use dex_trainer::demos::{DEMO_SEED, DemoSet, RecordSettings, demo_buffer, record_with};
    if !s.run.demos.uses_demos() {
        return Ok(None);
    }
    let env_cfg = s.reward.env_config(s.task.task());
    let mut sets = Vec::new();
    for path in &s.demo_files {
        sets.push((DemoSet::load(path)?, path.clone()));
    }
    if sets.is_empty() {
        let path = dir.join("demos.dxdm");
        let want = RecordSettings {
            episodes: s.record_demos,
            seed: DEMO_SEED + 500_000 + seed,
            arm_noise: s.demo_noise,
            finger_noise: 0.5 * s.demo_noise,
            reward: Some(env_cfg.reward),
            ..RecordSettings::new(s.task.task())
        };
        let set = match DemoSet::load(&path) {
            Ok(set) if set.header.settings == want => set,
            _ => {
                println!(
                    "seed {seed}: recording {} Markov-demonstrator episodes into {}",
                    want.episodes,
                    path.display()
                );
                let source =
                    DemoSource::Markov(dex_trainer::env::MarkovDemonstrator::new(s.task.task()));
                let set = record_with(scene, None, &source, &want, &|| {})?;
                set.save(&path)?;
                set
            }
        };
        sets.push((set, path));
    }
    Ok(Some(demo_buffer(&sets, s.task.task(), env_cfg.reward)?))
}

/// The MuJoCo scene, or an error that says how to install MuJoCo.
pub fn load_scene() -> anyhow::Result<Scene> {
    Scene::load().context("cannot build the MuJoCo scene; run `bash scripts/setup-mujoco.sh` first")
}

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
    let mut s = config::load(args.config.as_deref())?;
    apply_flags(&mut s, args);
    s.validate()?;
    let demo = match &s.start.demonstrator_policy {
        None => DemoSource::Scripted(Demonstrator::new(s.task.task())),
        Some(path) => {
            let bytes = std::fs::read(path)
                .with_context(|| format!("cannot read demonstrator policy {}", path.display()))?;
            DemoSource::Policy(Box::new(
                PolicyDemonstration::from_file_bytes(&bytes)
                    .with_context(|| format!("demonstrator policy {}", path.display()))?,
            ))
        }
    };
    let starts = StartStates::new(s.start.scheme(), demo).context("invalid [start] settings")?;
    let scene = load_scene()?;
    std::fs::create_dir_all(&s.out)
        .with_context(|| format!("cannot create {}", s.out.display()))?;
    // Held until the run ends: a second trainer on this folder is refused at once.
    let _lock = dex_trainer::run_lock::RunLock::acquire(&s.out)?;
    write_atomic(&s.out.join("settings.toml"), s.to_toml()?.as_bytes())?;
    println!(
        "training {:?} ({:?} reward), {} transitions x {} seed(s), R = {}, W = {}, into {}",
        s.task,
        s.reward,
        s.transitions,
        s.seeds.len(),
        s.run.updates_per_step,
        s.run.workers,
        s.out.display()
    );
    for &seed in &s.seeds {
        if !train_seed(&s, seed, &scene, &starts, stop, args)? {
            println!("stopped: checkpoint saved; continue with the same command and --resume");
            return Ok(false);
        }
    }
    match plot_run(&s.out) {
        Ok(files) => files.iter().for_each(|f| println!("plot: {}", f.display())),
        Err(e) => eprintln!("no plot: {e:#}"),
    }
    Ok(true)
}

/// Trains one seed; returns false if interrupted.
fn train_seed(
    s: &TrainSettings,
    seed: u64,
    scene: &Scene,
    starts: &StartStates<DemoSource>,
    stop: &AtomicBool,
    args: &TrainArgs,
) -> anyhow::Result<bool> {
    let dir = s.out.join(format!("seed-{seed}"));
    std::fs::create_dir_all(&dir)?;
    let ckpt = dir.join("checkpoint.bin");
    let log_path = dir.join("eval.jsonl");
    let mut per_seed = s.clone();
    per_seed.seeds = vec![seed];
    per_seed.run.seed = seed;
    let mut trainer = if ckpt.exists() {
        if !args.resume {
            bail!(
                "{} exists: add --resume to continue it, or choose another --out",
                ckpt.display()
            );
        }
        let t = Trainer::load(&ckpt)
            .with_context(|| format!("cannot resume from {}", ckpt.display()))?;
        let saved: Option<TrainSettings> = std::fs::read_to_string(dir.join("settings.toml"))
            .ok()
            .and_then(|t| toml::from_str(&t).ok());
        let same_env = saved.as_ref().is_none_or(|o| {
            (o.task, o.reward, &o.start) == (s.task, s.reward, &s.start)
                && (&o.demo_files, o.record_demos, o.demo_noise.to_bits())
                    == (&s.demo_files, s.record_demos, s.demo_noise.to_bits())
        });
        if t.config() != &per_seed.run || !same_env {
            bail!(
                "settings differ from the checkpoint's in {} (learner, task, reward, start \
                 scheme or demonstrations); resume with the same settings",
                dir.display()
            );
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
        ] {
            let _ = std::fs::remove_file(stale);
        }
        Trainer::new(per_seed.run.clone(), OBS_DIM, ACT_DIM)?
    };
    if let Some(d) = demonstrations(s, seed, &dir, scene)? {
        println!(
            "seed {seed}: {} demonstration transitions, {:.0}% of each batch",
            d.len(),
            100.0 * s.run.demos.fraction
        );
        trainer.set_demonstrations(d)?;
    }
    write_atomic(&dir.join("settings.toml"), per_seed.to_toml()?.as_bytes())?;
    let mut log = OpenOptions::new()
        .create(true)
        .append(true)
        .open(&log_path)
        .with_context(|| format!("cannot open {}", log_path.display()))?;
    let env_cfg = s.reward.env_config(s.task.task());
    let pb = bar(
        s.transitions,
        args.quiet,
        "{prefix} [{elapsed_precise}] [{bar:30}] {pos}/{len} transitions {msg}",
    );
    pb.set_prefix(format!("seed {seed}"));
    pb.set_position(trainer.progress().transitions);
    let started = Instant::now();
    let start_updates = trainer.progress().updates;
    let start_transitions = trainer.progress().transitions;
    let mut last_eval = String::from("no evaluation yet");
    loop {
        let done = trainer.progress().transitions;
        if done >= s.transitions {
            break;
        }
        let target = (done / s.checkpoint_every + 1) * s.checkpoint_every;
        let mut write_err = None;
        let summary = trainer.run(
            |_| JacoLearnEnv::with_start_states(scene, env_cfg, starts.clone()),
            target.min(s.transitions),
            stop,
            &mut |ev| match ev {
                Event::Eval(r) => {
                    if let Err(e) = writeln!(log, "{}", r.to_json_line()) {
                        write_err = Some(e);
                    }
                    last_eval = format!(
                        "eval {}: return {:.2}, success {:.0}%",
                        r.eval_index,
                        r.mean_return,
                        r.success_rate * 100.0
                    );
                    if args.quiet {
                        println!("seed {seed} {} transitions: {last_eval}", r.transitions);
                    }
                }
                Event::Progress(p) => {
                    let secs = started.elapsed().as_secs_f64().max(1e-9);
                    pb.set_position(p.transitions);
                    pb.set_message(format!(
                        "| {:.0} tr/s {:.0} upd/s | {last_eval}",
                        (p.transitions - start_transitions) as f64 / secs,
                        (p.updates - start_updates) as f64 / secs
                    ));
                }
            },
        )?;
        if let Some(e) = write_err {
            return Err(e).context("cannot append to eval.jsonl");
        }
        log.flush()?;
        // Selection before the checkpoint: a kill in between repeats this chunk on resume, which
        // reaches the same policy and the same selection (deterministic), so the exported file is
        // the uninterrupted run's.
        if !summary.stopped
            && let Some(line) = select_best(&trainer, s, seed, &dir, scene)?
        {
            if args.quiet {
                println!("seed {seed}: {line}");
            } else {
                pb.println(line);
            }
        }
        trainer
            .save(&ckpt)
            .with_context(|| format!("cannot write checkpoint {}", ckpt.display()))?;
        if summary.stopped {
            pb.abandon();
            return Ok(false);
        }
    }
    pb.finish();
    let out = dir.join("policy.dxpl");
    let eval = export_selected(&trainer, s, seed, &dir, &out, scene)?;
    println!(
        "seed {seed}: exported {} - runtime evaluation {}",
        out.display(),
        describe(&eval)
    );
    Ok(true)
}

/// One line: successes, rate, 95% interval and mean return.
pub fn describe(e: &PolicyEval) -> String {
    format!("success {e}")
}

/// Exports the policy of a seed's run folder `dir`: the best checkpoint on the selection starts
/// (`best_actor.bin`) when there is one, else the trainer's current actor; evaluates the file and
/// writes it (see [`export_and_evaluate`]).
fn export_selected(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    out: &Path,
    scene: &Scene,
) -> anyhow::Result<PolicyEval> {
    match read_best(dir)? {
        Some((params, best)) => {
            let (net, _) = trainer.actor();
            export_and_evaluate(net, &params, None, best.transitions, s, seed, out, scene)
        }
        None => export_checkpoint_trainer(trainer, s, seed, out, scene),
    }
}

/// Exports the trainer's actor, evaluates the file through the runtime, and writes the file with the
/// measured success rate in its provenance, plus `final_eval.json`.
fn export_checkpoint_trainer(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
    scene: &Scene,
) -> anyhow::Result<PolicyEval> {
    let (net, raw) = trainer.actor();
    // Quantisation-aware: the int8-grid weights the learner trained (no normaliser then).
    let grid;
    let params = if trainer.quantisation_aware() {
        grid = trainer.policy_params()?;
        &grid[..]
    } else {
        raw
    };
    let normaliser = trainer.obs_normalizer();
    let norm = normaliser.as_ref().map(|n| ObsNormalisation {
        mean: &n.mean,
        inv_std: &n.inv_std,
    });
    export_and_evaluate(
        net,
        params,
        norm,
        trainer.progress().transitions,
        s,
        seed,
        out,
        scene,
    )
}

/// Keeps the records of `eval.jsonl` up to `transitions` (those a checkpoint holds), rewriting the
/// file atomically when it has later ones.
fn truncate_log(path: &Path, transitions: u64) -> anyhow::Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let keep: Vec<&str> = text
        .lines()
        .filter(|l| {
            serde_json::from_str::<serde_json::Value>(l)
                .ok()
                .and_then(|v| v["transitions"].as_u64())
                .is_some_and(|t| t <= transitions)
        })
        .collect();
    if keep.len() != text.lines().count() {
        let mut out = keep.join("\n");
        if !out.is_empty() {
            out.push('\n');
        }
        write_atomic(path, out.as_bytes())?;
    }
    Ok(())
}

/// Start seed of the checkpoint-selection evaluations: apart from the final evaluation's
/// (1,000,000) and from `trainer eval`'s default, so the final figure of a selected policy is not
/// biased by the selection.
pub const SELECTION_SEED: u64 = 2_000_000;

/// The best checkpoint so far of a seed (`best.json` beside `best_actor.bin`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
struct BestPolicy {
    transitions: u64,
    success_rate: f64,
    mean_return: f64,
    episodes: u32,
}

/// Evaluates the trainer's current policy on the selection starts and keeps it when it beats the
/// best so far (success rate, then mean return). Returns a line to print.
fn select_best(
    trainer: &Trainer,
    s: &TrainSettings,
    seed: u64,
    dir: &Path,
    scene: &Scene,
) -> anyhow::Result<Option<String>> {
    // A quantisation-aware run chooses among its quantised policies only: the exported policy is
    // then the one trained for int8.
    if s.select_best_episodes == 0
        || (s.run.quantise.aware_from.is_some() && !trainer.quantisation_aware())
    {
        return Ok(None);
    }
    let (net, _) = trainer.actor();
    // Normalisation folded into the first layer: the candidate stands alone.
    let params = trainer.policy_params()?;
    let info = ExportInfo {
        task: s.task.task(),
        seed,
        transitions: trainer.progress().transitions,
        success_rate: None,
        eval_episodes: 0,
    };
    let draft = export_actor(net, &params, None, &info)?;
    let settings = EvalSettings {
        env: s.reward.env_config(s.task.task()),
        episodes: s.select_best_episodes,
        seed: SELECTION_SEED,
        threads: s.eval_threads,
        can_quantisation: true,
    };
    let e = evaluate_policy_file(&draft, scene, &settings, &|| {})?;
    let now = BestPolicy {
        transitions: info.transitions,
        success_rate: e.success_rate(),
        mean_return: e.mean_return,
        episodes: e.episodes,
    };
    let best = read_best(dir)?.map(|(_, b)| b);
    let better =
        best.is_none_or(|b| (now.success_rate, now.mean_return) > (b.success_rate, b.mean_return));
    let line = format!(
        "selection at {} transitions: {:.0}% ({} starts), return {:.2}{}",
        now.transitions,
        now.success_rate * 100.0,
        now.episodes,
        now.mean_return,
        if better { " - new best" } else { "" }
    );
    if better {
        let bytes: Vec<u8> = params.iter().flat_map(|x| x.to_le_bytes()).collect();
        write_atomic(&dir.join("best_actor.bin"), &bytes)?;
        write_atomic(
            &dir.join("best.json"),
            serde_json::to_string(&now)?.as_bytes(),
        )?;
    }
    Ok(Some(line))
}

/// The best checkpoint's actor parameters (normalisation folded in) and its record, if any.
fn read_best(dir: &Path) -> anyhow::Result<Option<(Vec<f32>, BestPolicy)>> {
    let (json, bin) = (dir.join("best.json"), dir.join("best_actor.bin"));
    if !json.exists() || !bin.exists() {
        return Ok(None);
    }
    let best: BestPolicy = serde_json::from_str(&std::fs::read_to_string(&json)?)
        .with_context(|| format!("{} is damaged", json.display()))?;
    let bytes = std::fs::read(&bin)?;
    if bytes.len() % 4 != 0 {
        bail!("{} is damaged (length {})", bin.display(), bytes.len());
    }
    let params = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(Some((params, best)))
}

/// Exports `params` of `net`, evaluates the file through the runtime on the final-evaluation
/// starts, and writes it with the measured success in its provenance, plus `final_eval.json`.
#[allow(clippy::too_many_arguments)]
fn export_and_evaluate(
    net: &dex_trainer::learn::nets::Mlp,
    params: &[f32],
    norm: Option<ObsNormalisation<'_>>,
    transitions: u64,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
    scene: &Scene,
) -> anyhow::Result<PolicyEval> {
    let mut info = ExportInfo {
        task: s.task.task(),
        seed,
        transitions,
        success_rate: None,
        eval_episodes: 0,
    };
    let draft = export_actor(net, params, norm, &info)?;
    let settings = EvalSettings {
        env: s.reward.env_config(s.task.task()),
        episodes: s.final_eval_episodes,
        seed: 1_000_000,
        threads: s.eval_threads,
        can_quantisation: true,
    };
    let eval = evaluate_policy_file(&draft, scene, &settings, &|| {})?;
    info.success_rate = Some(eval.success_rate() as f32);
    info.eval_episodes = eval.episodes;
    write_atomic(out, &export_actor(net, params, norm, &info)?)?;
    let json = serde_json::json!({
        "policy": out.file_name().map(|n| n.to_string_lossy().to_string()),
        "episodes": eval.episodes,
        "successes": eval.successes,
        "success_rate": eval.success_rate(),
        "ci95": [eval.ci95.0, eval.ci95.1],
        "mean_return": eval.mean_return,
        "start_seed": settings.seed,
        "transitions": info.transitions,
    });
    if let Some(dir) = out.parent() {
        write_atomic(&dir.join("final_eval.json"), json.to_string().as_bytes())?;
    }
    Ok(eval)
}

/// `trainer export`: the policy `trainer train` exports for a seed (the best checkpoint on the
/// selection starts, else the latest checkpoint) as a policy file.
pub fn export_checkpoint(
    dir: &Path,
    s: &TrainSettings,
    seed: u64,
    out: &Path,
) -> anyhow::Result<()> {
    let ckpt = dir.join("checkpoint.bin");
    let trainer =
        Trainer::load(&ckpt).with_context(|| format!("cannot read {}", ckpt.display()))?;
    let scene = load_scene()?;
    let eval = export_selected(&trainer, s, seed, dir, out, &scene)?;
    println!("runtime evaluation {}", describe(&eval));
    Ok(())
}

/// `trainer eval`.
pub fn eval(args: &EvalArgs) -> anyhow::Result<()> {
    let bytes = std::fs::read(&args.policy)
        .with_context(|| format!("cannot read {}", args.policy.display()))?;
    let aligned = dex_runtime::testkit::aligned_copy(&bytes);
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
    let settings = EvalSettings {
        env: config::RewardArg::TaskDefault.env_config(task.task()),
        episodes: args.episodes,
        seed: args.seed,
        threads: args.threads,
        can_quantisation: !args.no_can_quantisation,
    };
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
                    lines.push_str(&dex_runtime::testkit::action_line(e as u64, t, a));
                }
            }
            write_atomic(path, lines.as_bytes())?;
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
        args.seed,
        describe(&e)
    );
    Ok(())
}

/// The evaluation records of every seed in a run folder (seed-*/eval.jsonl) and its settings.
pub fn read_run(run: &Path) -> anyhow::Result<(Vec<Vec<EvalRecord>>, Option<TrainSettings>)> {
    let mut seeds = Vec::new();
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(run)
        .with_context(|| format!("cannot read run folder {}", run.display()))?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.join("eval.jsonl").exists())
        .collect();
    dirs.sort();
    for d in &dirs {
        let (records, bad) = read_eval_log(&d.join("eval.jsonl"))?;
        if bad > 0 {
            eprintln!("warning: {bad} malformed lines in {}", d.display());
        }
        if !records.is_empty() {
            seeds.push(records);
        }
    }
    if seeds.is_empty() {
        bail!("no evaluations in {} (seed-*/eval.jsonl)", run.display());
    }
    let settings: Option<TrainSettings> = std::fs::read_to_string(run.join("settings.toml"))
        .ok()
        .and_then(|t| toml::from_str(&t).ok());
    Ok((seeds, settings))
}

/// Return and success plots (PNG + SVG) of `conditions` as `dir`/`prefix`return.* and
/// `dir`/`prefix`success.* (and `..._per_worker` too when `per_worker`).
pub fn plot_conditions(
    dir: &Path,
    prefix: &str,
    title: &str,
    conditions: &[Condition],
    per_worker: bool,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let titled = |what: String| {
        if title.is_empty() {
            what
        } else {
            format!("{title}: {what}")
        }
    };
    let name_of = |suffix: &str| dir.join(format!("{prefix}{suffix}"));
    for (metric, name) in [
        (Metric::MeanReturn, "return"),
        (Metric::SuccessRate, "success"),
        (Metric::TrainReturn, "train_return"),
    ] {
        files.extend(plot(
            &name_of(name),
            &titled(format!("{name} against transitions")),
            conditions,
            metric,
            XAxis::Total,
        )?);
        if per_worker {
            files.extend(plot(
                &name_of(&format!("{name}_per_worker")),
                &titled(format!("{name} against transitions per worker")),
                conditions,
                metric,
                XAxis::PerWorker,
            )?);
        }
    }
    Ok(files)
}

/// `trainer plot`: learning curves of every seed in a run folder.
pub fn plot_run(run: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let (seeds, settings) = read_run(run)?;
    let (label, workers) = match &settings {
        Some(s) => (
            format!(
                "{:?} {:?}, R={}, W={}",
                s.task, s.reward, s.run.updates_per_step, s.run.workers
            ),
            s.run.workers,
        ),
        None => (run.display().to_string(), 1),
    };
    let conditions = [Condition { label, seeds }];
    plot_conditions(run, "", "", &conditions, workers > 1)
}
