//! `trainer demos` (record demonstrations as data) and `trainer clone` (behaviour cloning of them
//! into a policy file, evaluated through the runtime).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;

use dex_trainer::cell::policy_demo::{DemoSource, PolicyDemonstration};
use dex_trainer::env::seeds::EVAL_SEED;
use dex_trainer::env::{Demonstrator, MarkovDemonstrator};
use dex_trainer::evaluate::{EvalSettings, evaluate_policy_file};
use dex_trainer::files::demos::{
    DEMO_SEED, DemoSet, Keep, RecordMode, RecordSettings, record_with,
};
use dex_trainer::learn::bc::BcConfig;

use dex_trainer::pipeline::train_settings::{RewardArg, TaskArg};

/// `trainer demos` flags.
#[derive(Args, Debug)]
pub struct DemosArgs {
    /// Task.
    #[arg(long, value_enum)]
    task: TaskArg,
    /// Episodes to record.
    #[arg(long, default_value_t = 200)]
    episodes: u32,
    /// Seed of the start states (episode i starts from episode_seed(seed, i)).
    #[arg(long, default_value_t = DEMO_SEED)]
    seed: u64,
    /// Which scripted demonstrator: the phase machine or the Markov one (its action depends on the
    /// state alone; the one to clone).
    #[arg(long, value_enum, default_value_t = DemonstratorArg::Markov)]
    demonstrator: DemonstratorArg,
    /// A policy file to record instead of a scripted demonstrator.
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Noise (standard deviation) on the executed arm actions; labels stay clean (DART).
    #[arg(long, default_value_t = 0.0)]
    arm_noise: f32,
    /// Noise on the executed finger actions.
    #[arg(long, default_value_t = 0.0)]
    finger_noise: f32,
    /// Close bursts: the probability per step of holding the executed finger actions fully
    /// closing for 3-8 steps (labels stay the demonstrator's; 0: none, at most 0.5).
    #[arg(long, default_value_t = 0.0)]
    close_bursts: f32,
    /// Open bursts: the probability per step of holding the executed finger actions fully
    /// opening for 3-8 steps (0: none, at most 0.5).
    #[arg(long, default_value_t = 0.0)]
    open_bursts: f32,
    /// Start every episode with the bricks' centres at most this many metres apart (above 0.08,
    /// at most 0.3; default: the task's own start draw).
    #[arg(long)]
    close_spacing: Option<f32>,
    /// Demonstrator takeover: this policy drives each episode for a random number of steps (up to
    /// --takeover-max-step), then the demonstrator takes over; only its part is recorded.
    #[arg(long, conflicts_with = "dagger")]
    takeover: Option<PathBuf>,
    /// Last step at which the demonstrator may take over.
    #[arg(long, default_value_t = 120)]
    takeover_max_step: u32,
    /// DAgger: this policy acts for whole episodes; the (Markov) demonstrator labels its states.
    #[arg(long)]
    dagger: Option<PathBuf>,
    /// Keep failed episodes too.
    #[arg(long)]
    keep_failures: bool,
    /// Keep only the failed episodes (with --dagger: the states a mostly successful policy's
    /// data lacks).
    #[arg(long, conflicts_with = "keep_failures")]
    failures_only: bool,
    /// Reward written into the rows (default: the task's own); a `trainer train` run with
    /// demonstrations needs the reward it trains with.
    #[arg(long, value_enum)]
    reward: Option<RewardArg>,
    /// Output demo file (refused if it exists, unless --force).
    #[arg(long)]
    out: PathBuf,
    /// Overwrite an existing file.
    #[arg(long)]
    force: bool,
}

/// The scripted demonstrators.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DemonstratorArg {
    /// The phase machine (phases, timers, anchors).
    Scripted,
    /// The Markov demonstrator.
    Markov,
}

/// `trainer clone` flags.
#[derive(Args, Debug)]
pub struct CloneArgs {
    /// Demo files (all of one task), comma-separated.
    #[arg(long, value_delimiter = ',', required = true)]
    demos: Vec<PathBuf>,
    /// Task (default: the demo files').
    #[arg(long, value_enum)]
    task: Option<TaskArg>,
    /// Use only the first N episodes of each file (comma-separated, one per file).
    #[arg(long, value_delimiter = ',')]
    episodes: Option<Vec<u32>>,
    /// Gradient steps.
    #[arg(long)]
    steps: Option<u64>,
    /// Hidden layer widths, comma-separated.
    #[arg(long, value_delimiter = ',')]
    hidden: Option<Vec<usize>>,
    /// The policy also takes the controller's task features (docs/imitation.md).
    #[arg(long)]
    features: bool,
    /// Learning rate.
    #[arg(long)]
    lr: Option<f32>,
    /// Seed of initialisation and sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Episodes of the evaluation after export (seed 1,000,000; 0: none).
    #[arg(long, default_value_t = 100)]
    eval_episodes: u32,
    /// Output policy file.
    #[arg(long)]
    out: PathBuf,
}

/// Records demonstrations into a demo file.
pub fn demos(a: &DemosArgs) -> anyhow::Result<()> {
    if a.out.exists() && !a.force {
        bail!("{} exists (pass --force to overwrite)", a.out.display());
    }
    let task = a.task.task();
    let settings = RecordSettings {
        task,
        episodes: a.episodes,
        seed: a.seed,
        arm_noise: a.arm_noise,
        finger_noise: a.finger_noise,
        close_bursts: a.close_bursts,
        open_bursts: a.open_bursts,
        close_spacing: a.close_spacing,
        keep: if a.failures_only {
            Keep::Failures
        } else if a.keep_failures {
            Keep::All
        } else {
            Keep::Successes
        },
        mode: match (&a.takeover, &a.dagger) {
            (Some(_), _) => RecordMode::Takeover {
                max_step: a.takeover_max_step,
            },
            (None, Some(_)) => RecordMode::Dagger,
            (None, None) => RecordMode::Demonstrator,
        },
        reward: a
            .reward
            .map(|r| r.env_config(task).reward)
            .filter(|&r| r != task.default_reward()),
    };
    let lead = match a.takeover.as_ref().or(a.dagger.as_ref()) {
        None => None,
        Some(p) => Some(load_policy(p)?),
    };
    settings.validate()?;
    let source = match &a.policy {
        None => match a.demonstrator {
            DemonstratorArg::Scripted => DemoSource::Scripted(Demonstrator::new(task)),
            DemonstratorArg::Markov => DemoSource::Markov(MarkovDemonstrator::new(task)),
        },
        Some(p) => DemoSource::Policy(Box::new(load_policy(p)?)),
    };
    let scene = crate::train::load_scene()?;
    let pb = crate::train::bar(
        u64::from(a.episodes),
        false,
        "demos [{elapsed_precise}] [{bar:30}] {pos}/{len} episodes",
    );
    let start = std::time::Instant::now();
    let set = record_with(&scene, lead.as_ref(), &source, &settings, &|| pb.inc(1))?;
    pb.finish_and_clear();
    set.save(&a.out)?;
    println!(
        "wrote {}: {} of {} episodes succeeded, {} stored, {} transitions, {:.1} s",
        a.out.display(),
        set.header.successes,
        set.header.tried,
        set.header.episodes,
        set.rows.len(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn load_policy(p: &Path) -> anyhow::Result<PolicyDemonstration> {
    let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
    PolicyDemonstration::from_file_bytes(&bytes)
        .with_context(|| format!("{} is not a usable policy file", p.display()))
}

/// Loads demo files and checks they are all of `task` (or of the first file's task).
pub fn load_demos(
    paths: &[PathBuf],
    task: Option<TaskArg>,
) -> anyhow::Result<(Vec<DemoSet>, TaskArg)> {
    let mut sets = Vec::new();
    for p in paths {
        sets.push(DemoSet::load(p)?);
    }
    let first: TaskArg = sets
        .first()
        .map(|s| s.header.settings.task)
        .map(TaskArg::from_task)
        .context("no demo files")?;
    let task = task.unwrap_or(first);
    for (s, p) in sets.iter().zip(paths) {
        s.check_task(task.task(), p)?;
    }
    Ok((sets, task))
}

/// Clones demonstrations into a policy file and evaluates it.
pub fn clone(a: &CloneArgs) -> anyhow::Result<()> {
    let (mut sets, task) = load_demos(&a.demos, a.task)?;
    if let Some(n) = &a.episodes {
        if n.len() != sets.len() {
            bail!(
                "--episodes needs one count per demo file ({} files, {} counts)",
                sets.len(),
                n.len()
            );
        }
        sets = sets
            .iter()
            .zip(n)
            .map(|(s, &k)| s.first_episodes(k))
            .collect();
    }
    let mut cfg = BcConfig {
        seed: a.seed,
        ..BcConfig::default()
    };
    if let Some(s) = a.steps {
        cfg.steps = s;
    }
    if let Some(h) = &a.hidden {
        cfg.hidden = h.clone();
    }
    cfg.features = a.features;
    if let Some(lr) = a.lr {
        cfg.adam.lr = lr;
    }
    cfg.validate()?;
    let pb = crate::train::bar(
        cfg.steps,
        false,
        "clone [{elapsed_precise}] [{bar:30}] {pos}/{len} steps {msg}",
    );
    let start = std::time::Instant::now();
    let (policy, file) = dex_trainer::pipeline::cloning::clone_to_policy_file(
        &sets,
        task.task(),
        &cfg,
        &mut |step, loss| {
            pb.set_position(step);
            pb.set_message(format!("mse {loss:.4}"));
        },
    )?;
    pb.finish_and_clear();
    write_policy(&a.out, &file)?;
    println!(
        "wrote {}: cloned {} transitions in {:.1} s, final mse {:.4}",
        a.out.display(),
        sets.iter().map(|s| s.rows.len()).sum::<usize>(),
        start.elapsed().as_secs_f64(),
        policy.final_loss
    );
    if a.eval_episodes > 0 {
        let scene = crate::train::load_scene()?;
        let settings = EvalSettings {
            env: RewardArg::TaskDefault.env_config(task.task()),
            episodes: a.eval_episodes,
            seed: EVAL_SEED,
            threads: 2,
            can_quantisation: true,
            envelope: false,
        };
        let e = evaluate_policy_file(&file, &scene, &settings, &|| {})?;
        println!(
            "{} on {:?}: {}",
            a.out.display(),
            task,
            crate::train::describe(&e)
        );
    }
    Ok(())
}

fn write_policy(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d)?;
    }
    dex_trainer::files::atomic_write::write_atomic(path, bytes)
        .with_context(|| format!("cannot write {}", path.display()))
}
