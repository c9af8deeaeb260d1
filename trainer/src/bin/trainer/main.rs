//! `trainer`: train DPG-R / ADPG-R policies on the Jaco tasks, export them as policy files, evaluate
//! the files through the controller's runtime, and plot learning curves.
//!
//! ```text
//! trainer train [--config FILE.toml] [--task reach] [--transitions N] [--seeds 0,1,2] [-R 5] [-W 2] ...
//! trainer eval POLICY.dxpl [--episodes 100] [--seed 0]
//! trainer plot RUN_DIR
//! trainer figure experiments/figures/FIGURE.toml [--transitions N] [--seeds 0,1] [--plot-only]
//! trainer export RUN_DIR [--seed 0] [--out FILE.dxpl] [--int8]
//! trainer demos --task grasp [--episodes 200] [--arm-noise 0.2] --out FILE.dxdm
//! trainer clone --demos FILE.dxdm[,...] --out POLICY.dxpl [--steps 20000]
//! trainer imitate --task grasp [--rounds 4] [--seeds 0,1,2] [--out runs/imitate]
//! trainer soup OUT.dxpl FILE.dxpl... [--weights 0.5,0.25,0.25]
//! ```

mod compare;
mod critic_rank;
mod demos;
mod distributed;
mod eval_flags;
mod figure;
mod imitate;
mod pg;
mod pool;
mod power;
mod soup;
mod train;

use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Parser, Subcommand};

use dex_trainer::env::seeds::EVAL_SEED;
use dex_trainer::pipeline::train_settings::{
    PresetArg, RewardArg, StartArg, TaskArg, TrainSettings,
};

#[derive(Parser)]
#[command(
    name = "trainer",
    version,
    about = "DPG-R / ADPG-R on the Jaco stacking tasks"
)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Command,
}

#[derive(Subcommand)]
pub(crate) enum Command {
    /// Train one run per seed; writes checkpoints, eval.jsonl, policy.dxpl per seed, and plots.
    Train(Box<TrainArgs>),
    /// Success rate of a policy file over random starts, with a 95% confidence interval.
    Eval(EvalArgs),
    /// Policy files (and the teacher) on the same starts, with the McNemar test of every pair.
    Compare(compare::CompareArgs),
    /// `trainer compare` records of disjoint starts pooled into one comparison (a long test run
    /// in chunks).
    Pool(pool::PoolArgs),
    /// How many paired starts a test needs: the power of the exact McNemar test at a comparison
    /// record's discordant rates.
    Power(power::PowerArgs),
    /// Plot a run folder's learning curves (PNG and SVG).
    Plot {
        /// Run folder (holds seed-*/eval.jsonl).
        run: PathBuf,
    },
    /// Export a seed's policy file again: the checkpoint the run selected, or with --latest its
    /// latest one.
    Export(ExportArgs),
    /// Train (resuming) the runs of a figure file, then plot them together (PNG and SVG).
    Figure(FigureArgs),
    /// Record demonstrations (scripted demonstrator or a policy file) into a demo file.
    Demos(demos::DemosArgs),
    /// Behaviour cloning of demo files into a policy file, evaluated through the runtime.
    Clone(demos::CloneArgs),
    /// Imitation learner: clone the Markov demonstrator, then DAgger rounds; exports the best round.
    Imitate(imitate::ImitateArgs),
    /// Weight-space average of policy files of one network (seeds of a fine-tune, their clone).
    Soup(soup::SoupArgs),
    /// Whether a run's critic orders actions as rollouts in the simulator do.
    CriticRank(critic_rank::CriticRankArgs),
    /// Fine-tune a policy file by the group-relative policy gradient (on-policy, no critic).
    Pg(pg::PgArgs),
    /// The toy point-mass task across MPI ranks (a check of the distributed learner; under mpirun).
    #[command(hide = true)]
    DistributedPointMass(distributed::PointMassArgs),
}

/// `trainer figure` flags.
#[derive(Args, Debug)]
struct FigureArgs {
    /// Figure file (see experiments/figures/).
    figure: PathBuf,
    /// Transition budget per seed for every run (a smaller honest version, or more).
    #[arg(long)]
    transitions: Option<u64>,
    /// Seeds for every run, comma-separated.
    #[arg(long, value_delimiter = ',')]
    seeds: Option<Vec<u64>>,
    /// Only draw the plots from what is trained.
    #[arg(long)]
    plot_only: bool,
    /// One line per evaluation instead of progress bars.
    #[arg(long)]
    quiet: bool,
}

/// Flags override the config file, which overrides the defaults.
#[derive(Args, Debug, Default, Clone)]
struct TrainArgs {
    /// TOML settings file (see experiments/ for examples).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Task.
    #[arg(long, value_enum)]
    task: Option<TaskArg>,
    /// Reward function.
    #[arg(long, value_enum)]
    reward: Option<RewardArg>,
    /// Where training episodes start (evaluation always uses the task's original starts).
    #[arg(long, value_enum)]
    start: Option<StartArg>,
    /// Probability of the in-hand start under `--start mixture`.
    #[arg(long)]
    in_hand_probability: Option<f64>,
    /// Mini-batch updates per environment step (the paper's R).
    #[arg(short = 'R', long = "replay-steps")]
    replay_steps: Option<usize>,
    /// Worker threads (the paper's ADPG-R workers; 1 = DPG-R).
    #[arg(short = 'W', long)]
    workers: Option<usize>,
    /// Seeds, comma-separated (one run each; default 0, 1 for the default pipelines of Grasp and
    /// Stack, whose clone stage's member seeds are written for seed 1).
    #[arg(long, value_delimiter = ',')]
    seeds: Option<Vec<u64>>,
    /// Transition budget per seed (all workers together).
    #[arg(long)]
    transitions: Option<u64>,
    /// Learning rate of the actor and the critic (sets both; the paper tunes only this).
    #[arg(long)]
    lr: Option<f32>,
    /// Actor learning rate.
    #[arg(long)]
    actor_lr: Option<f32>,
    /// Critic learning rate.
    #[arg(long)]
    critic_lr: Option<f32>,
    /// Mini-batch size.
    #[arg(long)]
    batch: Option<usize>,
    /// Hidden layer widths of actor and critic, comma-separated.
    #[arg(long, value_delimiter = ',')]
    hidden: Option<Vec<usize>>,
    /// One replay buffer per worker instead of a shared one.
    #[arg(long)]
    per_worker_replay: bool,
    /// Quantisation-aware training from this many transitions on: the actor is trained and
    /// exported with int8-grid weights, so `trainer export --int8` loses (almost) nothing.
    #[arg(long)]
    quantise_aware_from: Option<u64>,
    /// Output folder.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Checkpoint period in transitions.
    #[arg(long)]
    checkpoint_every: Option<u64>,
    /// Episodes of the final evaluation of each exported policy.
    #[arg(long)]
    final_eval_episodes: Option<u32>,
    /// Selection starts per checkpoint (0: export the last policy instead of the best).
    #[arg(long)]
    select_best_episodes: Option<u32>,
    /// A run that starts from a policy (--init-policy or the clone stage) ships the starting
    /// policy when it solves more of this many selection starts than the selected one (0: off;
    /// the fine-tune preset's 500).
    #[arg(long)]
    guard_episodes: Option<u32>,
    /// After each seed's export, fine-tune its file by the group-relative policy gradient
    /// (`trainer pg`, the `[pg]` stage: the file's defaults or the settings file's `[pg]`) for
    /// this many iterations into `OUT/seed-S/pg`, whose `policy.dxpl` is the seed's final file
    /// (0: no such stage).
    #[arg(long)]
    pg_iterations: Option<u32>,
    /// Continue from the checkpoints in the output folder.
    #[arg(long)]
    resume: bool,
    /// No progress bar (logs only).
    #[arg(long)]
    quiet: bool,
    /// One run across MPI ranks (start with `mpirun -np N trainer train --distributed ...`; rank
    /// 0 is the parameter server, ranks 1..N-1 run W workers each; docs/distributed.md). Needs a
    /// build with `--features mpi`.
    #[arg(long)]
    distributed: bool,
    /// Distributed: a worker rank exchanges with rank 0 after this many of its updates (10).
    #[arg(long, requires = "distributed")]
    exchange_every: Option<u64>,
    /// Distributed: seconds after which a silent worker rank is lost (60); rank 0 then writes a
    /// checkpoint and fails naming it.
    #[arg(long, requires = "distributed")]
    rank_timeout: Option<f64>,
    /// Distributed: rank 0 starts a replacement (MPI_Comm_spawn of this same command) for a
    /// worker rank lost for this many seconds more (off; needs a free slot: mpirun
    /// --oversubscribe or more slots than ranks; docs/distributed.md).
    #[arg(long, requires = "distributed")]
    respawn_after: Option<f64>,
    /// Start from a named configuration (`paper`: plain DDPG, none of the components below;
    /// `demos`: the learner from demonstrations, Reach's default; `finetune`: the clone stage (on
    /// Grasp and Stack an ensemble of clones distilled into one network) and the fine-tune that
    /// keeps the clone, the default of Grasp, StackInHand and Stack without --config and without
    /// component flags); conflicts with the component flags.
    #[arg(long, value_enum, conflicts_with_all = [
        "demos", "record_demos", "demo_fraction", "bc_weight", "no_q_filter", "td3", "n_step",
        "noise_correlation", "finger_noise_scale", "action_l2", "pretrain_updates",
        "obs_norm_from_demos", "q_normalisation", "pretrain_actor_lr",
    ])]
    preset: Option<PresetArg>,
    /// Demonstration files (`trainer demos`), comma-separated: the run's demonstration buffer.
    #[arg(long, value_delimiter = ',')]
    demos: Option<Vec<PathBuf>>,
    /// Record this many Markov-demonstrator episodes into each seed's folder as the
    /// demonstration buffer (when no --demos are given).
    #[arg(long)]
    record_demos: Option<u32>,
    /// Fraction of each mini-batch drawn from the demonstrations (0-1).
    #[arg(long)]
    demo_fraction: Option<f32>,
    /// Weight of the behaviour-cloning term on the demonstration rows.
    #[arg(long)]
    bc_weight: Option<f32>,
    /// Apply the cloning term on every demonstration row (no Q-filter).
    #[arg(long)]
    no_q_filter: bool,
    /// TD3's pieces: twin critics, target smoothing (0.2, clip 0.5), actor every 2nd update.
    #[arg(long)]
    td3: bool,
    /// n-step returns.
    #[arg(long)]
    n_step: Option<usize>,
    /// Temporal correlation of the exploration noise (AR(1) coefficient, 0 = white).
    #[arg(long)]
    noise_correlation: Option<f32>,
    /// Noise scale of the three finger joints relative to the arm joints'.
    #[arg(long)]
    finger_noise_scale: Option<f32>,
    /// Weight of the action penalty in the actor's loss.
    #[arg(long)]
    action_l2: Option<f32>,
    /// Updates on the demonstrations alone before the first environment step (DDPGfD's
    /// pre-training: the actor clones them, the critic learns their returns).
    #[arg(long)]
    pretrain_updates: Option<u64>,
    /// Normalise observations by statistics measured once on the demonstrations (fixed).
    #[arg(long)]
    obs_norm_from_demos: bool,
    /// TD3+BC's scale of the `-Q` term: alpha / mean|Q| (0: off; TD3+BC uses 2.5).
    #[arg(long)]
    q_normalisation: Option<f32>,
    /// The actor's learning rate during the pre-training (default: the actor's).
    #[arg(long)]
    pretrain_actor_lr: Option<f32>,
    /// Start the actor from this exported f32 policy file of the task (e.g. `trainer imitate`'s
    /// clone); run.ddpg.actor_hidden must be its hidden sizes.
    #[arg(long)]
    init_policy: Option<PathBuf>,
    /// A clone stage first: per seed, the imitation learner (`trainer imitate`'s recipe for the
    /// task, the run's actor sizes and task features) clones the Markov demonstrator into
    /// OUT/clone/seed-S, and the actor starts from that file (resumed like the rest of the run).
    #[arg(long)]
    clone: bool,
    /// The networks also take the controller's task features after the observation (the pinch
    /// site's yaw, the bricks' yaws relative to it, the pinch-to-brick vectors in its frame);
    /// an --init-policy must take them too.
    #[arg(long)]
    features: bool,
    /// Updates that train the critic alone (the actor stays as it started) before the actor
    /// moves: the critic rates the starting policy's own transitions first.
    #[arg(long)]
    critic_warmup_updates: Option<u64>,
    /// A residual actor on the frozen starting policy (--init-policy or --clone): this many
    /// residual units beside the base's in every hidden layer, summed before the output's tanh
    /// (run.ddpg.residual; the exported file is one MLP, the base's widths plus this).
    #[arg(long, value_name = "UNITS")]
    residual: Option<usize>,
    /// Store the teacher's (Markov demonstrator's) action with every collected transition and
    /// apply the cloning term (--bc-weight) to every batch row toward it (run.teacher_labels).
    #[arg(long)]
    teacher_labels: bool,
    /// IBRL: the starting policy (--init-policy or --clone) stays beside the actor as a frozen
    /// proposal; each step executes whichever of the two actions the critic rates higher, and
    /// the critic bootstraps from the better one (run.ibrl). The export is the actor alone.
    #[arg(long)]
    ibrl: bool,
}

#[derive(Args, Debug)]
struct EvalArgs {
    /// Policy file.
    policy: PathBuf,
    /// Task (default: the policy's own).
    #[arg(long, value_enum)]
    task: Option<TaskArg>,
    /// Episodes (random starts).
    #[arg(long, default_value_t = 100)]
    episodes: u32,
    /// The starts, threads and bus.
    #[command(flatten)]
    at: eval_flags::EvalFlags,
    /// Apply the controller's safety envelope (its default settings) to every action, as the
    /// controller node does (docs/runtime.md).
    #[arg(long)]
    envelope: bool,
    /// Also write every applied command to this file, one line per step (`episode step a0 ...
    /// a8`; one thread), to compare with `hil-sim plant --actions` over the bus.
    #[arg(long)]
    actions: Option<PathBuf>,
    /// Also write the evaluation as a record for docs/results/ (JSON: the file and its sha256,
    /// this command, successes, episodes, 95% interval, start seed, date, machine, wall time);
    /// `python3 scripts/results.py` builds docs/results.md from the records.
    #[arg(long, requires_all = ["section", "what"])]
    record: Option<PathBuf>,
    /// The record's section of docs/results.md (`table2`, `main-job`, ...).
    #[arg(long, requires = "record")]
    section: Option<String>,
    /// The record's row label (e.g. "Grasp").
    #[arg(long, requires = "record")]
    what: Option<String>,
}

#[derive(Args, Debug)]
struct ExportArgs {
    /// Run folder.
    run: PathBuf,
    /// Seed whose checkpoint to export.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Export the latest checkpoint's actor instead of what the run exports (its best checkpoint
    /// on the selection starts, or the policy it started from where its guard kept that): a run's
    /// policy at a point of its training, e.g. for a learning curve measured on many starts.
    /// Default file RUN/seed-S/policy-latest.dxpl (with --int8 also policy-latest-int8.dxpl), its
    /// record final_eval-latest.json: the run's policy.dxpl and final_eval.json stay as they are.
    #[arg(long)]
    latest: bool,
    /// Output file (default RUN/seed-S/policy.dxpl, with --int8 RUN/seed-S/policy-int8.dxpl).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also write an int8 policy (format version 2: per-output-channel symmetric weight scales,
    /// int32 accumulation in the runtime), evaluated like the f32 one, with its worst action error
    /// against the f32 policy on held-out observations. A quantisation-aware trained policy is
    /// quantised as it is; any other first gets input folding and cross-layer equalisation
    /// calibrated on 20 episodes from seed 8,000,000. The f32 policy still goes to
    /// RUN/seed-S/policy.dxpl.
    #[arg(long)]
    int8: bool,
}

/// `trainer export --int8`: quantises the exported f32 file, evaluates the int8 file through the
/// runtime (same episodes and start seeds as the f32 export's evaluation) and writes it with its own
/// success rate (the steps: `dex_trainer::files::int8_export`).
fn export_int8(
    f32_path: &std::path::Path,
    out: &std::path::Path,
    settings: &TrainSettings,
) -> anyhow::Result<()> {
    let f32_file =
        std::fs::read(f32_path).with_context(|| format!("cannot read {}", f32_path.display()))?;
    let scene = train::load_scene()?;
    let env = settings.reward.env_config(settings.task.task());
    let eval = dex_trainer::evaluate::EvalSettings {
        env,
        episodes: settings.final_eval_episodes,
        seed: EVAL_SEED,
        threads: settings.eval_threads,
        can_quantisation: true,
        envelope: false,
    };
    let x = dex_trainer::files::int8_export::export_int8(&f32_file, &scene, env, &eval)?;
    if x.on_grid {
        println!(
            "the f32 weights are on the int8 grid (quantisation-aware training): quantised as they are"
        );
    } else {
        println!(
            "equalised on {} calibration observations (f32 function change {:.2e} of a joint's range)",
            x.calibration, x.equalisation_change
        );
    }
    println!(
        "int8 against f32 on {} held-out observations: worst action error {:.3}% of a joint's range",
        x.heldout,
        x.worst_error * 100.0
    );
    if x.needs_aware_training() {
        println!(
            "warning: over 1% - the policy was not trained for int8; train it with \
             `--quantise-aware-from` (docs/training.md, \"Training for int8\")"
        );
    }
    dex_trainer::files::atomic_write::write_atomic(out, &x.file)
        .with_context(|| format!("cannot write {}", out.display()))?;
    let weight_bytes = |bytes: &[u8]| -> anyhow::Result<usize> {
        let aligned = dex_runtime::aligned::aligned_copy(bytes);
        Ok(dex_policy::PolicyView::decode(aligned.as_bytes())?.weight_bytes())
    };
    println!(
        "wrote {} (int8: {} weight bytes, f32 {}; {} bytes in all) - runtime evaluation {}",
        out.display(),
        weight_bytes(&x.file)?,
        weight_bytes(&f32_file)?,
        x.file.len(),
        train::describe(&x.eval)
    );
    Ok(())
}

/// Writes `value` as pretty JSON to `path` (atomically) and says so: the `--json` report of
/// `compare`, `pool` and `critic-rank`.
pub(crate) fn write_json(
    path: &std::path::Path,
    value: &impl serde::Serialize,
) -> anyhow::Result<()> {
    let json = serde_json::to_string_pretty(value)?;
    dex_trainer::files::atomic_write::write_atomic(path, json.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Train(args) if args.distributed => distributed::train(&args),
        Command::Train(args) => train::train(*args),
        Command::DistributedPointMass(args) => distributed::point_mass(&args),
        Command::Eval(args) => train::eval(&args),
        Command::Compare(args) => compare::compare(&args),
        Command::Pool(args) => pool::pool(&args),
        Command::Power(args) => power::power(&args),
        Command::Demos(args) => demos::demos(&args),
        Command::Clone(args) => demos::clone(&args),
        Command::Imitate(args) => imitate::imitate(&args),
        Command::Soup(args) => soup::soup_files(&args),
        Command::CriticRank(args) => critic_rank::critic_rank(&args),
        Command::Pg(args) => pg::pg(&args),
        Command::Plot { run } => {
            let files = train::plot_run(&run)?;
            for f in files {
                println!("wrote {}", f.display());
            }
            Ok(())
        }
        Command::Figure(f) => {
            let overrides = TrainArgs {
                transitions: f.transitions,
                seeds: f.seeds,
                quiet: f.quiet,
                ..TrainArgs::default()
            };
            figure::figure(&f.figure, &overrides, f.plot_only)
        }
        Command::Export(args) => {
            let dir = args.run.join(format!("seed-{}", args.seed));
            // The latest checkpoint never replaces the run's own export (policy.dxpl).
            let stem = if args.latest {
                "policy-latest"
            } else {
                "policy"
            };
            let f32_out = dir.join(format!("{stem}.dxpl"));
            let out = match (&args.out, args.int8) {
                (Some(out), _) => out.clone(),
                (None, false) => f32_out.clone(),
                (None, true) => dir.join(format!("{stem}-int8.dxpl")),
            };
            let settings: TrainSettings = toml::from_str(
                &std::fs::read_to_string(dir.join("settings.toml"))
                    .with_context(|| format!("{} is not a run folder", dir.display()))?,
            )
            .context("settings.toml")?;
            if args.int8 {
                train::export_checkpoint(&dir, &settings, args.seed, &f32_out, args.latest)?;
                println!("wrote {}", f32_out.display());
                export_int8(&f32_out, &out, &settings)
            } else {
                train::export_checkpoint(&dir, &settings, args.seed, &out, args.latest)?;
                println!("wrote {}", out.display());
                Ok(())
            }
        }
    }
}
