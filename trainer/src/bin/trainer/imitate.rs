//! `trainer imitate`: behaviour cloning of the Markov demonstrator plus DAgger rounds, one run
//! folder per seed, the best round's policy exported and evaluated through the runtime.

use std::path::PathBuf;

use clap::Args;
use indicatif::ProgressBar;

use dex_trainer::env::seeds::EVAL_SEED;
use dex_trainer::evaluate::{EvalSettings, evaluate_policy_file};
use dex_trainer::pipeline::imitation::{ImitationConfig, ImitationEvent, run_imitation};
use dex_trainer::pipeline::rollout_teacher::RolloutTeacher;
use dex_trainer::pipeline::self_imitation::SelfImitation;

use dex_trainer::pipeline::train_settings::TaskArg;

/// `trainer imitate` flags (override the defaults of `ImitationConfig`).
#[derive(Args, Debug)]
pub struct ImitateArgs {
    /// Task.
    #[arg(long, value_enum, default_value_t = TaskArg::Grasp)]
    task: TaskArg,
    /// Clean demonstrator episodes of round 0.
    #[arg(long)]
    demo_episodes: Option<u32>,
    /// Demonstrator episodes of round 0 with noise on the executed actions (DART).
    #[arg(long)]
    dart_episodes: Option<u32>,
    /// Stack only: DART episodes started with brick 1 in the hand (data for carrying and placing).
    #[arg(long)]
    in_hand_episodes: Option<u32>,
    /// DART episodes of round 0 started with the bricks' centres at most `--close-spacing` apart,
    /// beside those of the task's own start draw (data where the Stack files fail).
    #[arg(long)]
    close_dart_episodes: Option<u32>,
    /// The close DART episodes' largest spacing of the bricks' centres, metres (default 0.095;
    /// needs `--close-dart-episodes`).
    #[arg(long)]
    close_spacing: Option<f32>,
    /// Noise (standard deviation) on the DART episodes' arm actions.
    #[arg(long)]
    arm_noise: Option<f32>,
    /// Noise on the DART episodes' finger actions.
    #[arg(long)]
    finger_noise: Option<f32>,
    /// The Markov teacher tucks first: it holds the hand up while a finger whose tip is over
    /// brick 2 is not yet tucked (docs/imitation.md).
    #[arg(long)]
    tuck_first: bool,
    /// The Markov teacher's tuck is a ramp over the knuckle's distance to brick 2 (2-4 cm)
    /// instead of a switch at 3 cm (docs/imitation.md).
    #[arg(long)]
    tuck_ramp: bool,
    /// Distil these policy files (of the task; e.g. clones of other seeds) into one network: their
    /// mean action is the teacher instead of the Markov demonstrator (repeat the flag or separate
    /// with commas).
    #[arg(long, value_delimiter = ',')]
    teacher_policies: Vec<std::path::PathBuf>,
    /// Distil an IBRL run's pair into one network (`trainer train --ibrl`; its seed folder): at
    /// each state the better-rated of the run's actor and its proposal is the teacher.
    #[arg(long, value_name = "SEED_DIR")]
    teacher_pair: Option<std::path::PathBuf>,
    /// Success-filtered self-imitation: this policy file's episodes (of the task), with the DART
    /// noise (`--arm-noise`, `--finger-noise`) on its executed actions, kept when they succeed,
    /// join round 0's data labelled with the executed actions (docs/imitation.md).
    #[arg(long, value_name = "POLICY")]
    self_imitation: Option<std::path::PathBuf>,
    /// Episodes the self-imitation tries.
    #[arg(long, default_value_t = 1000, requires = "self_imitation")]
    self_imitation_episodes: u32,
    /// Times each self-imitation row counts in the cloning data.
    #[arg(long, default_value_t = 1, requires = "self_imitation")]
    self_imitation_repeat: u32,
    /// A rollout teacher: this policy file's (of the task) clean episodes from training starts;
    /// at branch points of the failed ones, noisy branches are rolled out from simulator
    /// snapshots, and the winning branches' actions join round 0's data (docs/imitation.md).
    #[arg(long, value_name = "POLICY")]
    rollout_teacher: Option<std::path::PathBuf>,
    /// Episodes the rollout teacher tries (the failed ones are branched; default 1000).
    #[arg(long, requires = "rollout_teacher")]
    rollout_episodes: Option<u32>,
    /// Branch points every this many steps of a failed episode (default 5).
    #[arg(long, requires = "rollout_teacher")]
    rollout_stride: Option<u32>,
    /// Noisy branches per branch point (default 8).
    #[arg(long, requires = "rollout_teacher")]
    rollout_candidates: Option<u32>,
    /// Times each labelled row counts in the cloning data (default 1).
    #[arg(long, requires = "rollout_teacher")]
    rollout_repeat: Option<u32>,
    /// Noise of the rollout teacher's branches on the arm's actions (default 0.1).
    #[arg(long, requires = "rollout_teacher")]
    rollout_arm_noise: Option<f32>,
    /// Noise of the rollout teacher's branches on the fingers' actions (default 0.05).
    #[arg(long, requires = "rollout_teacher")]
    rollout_finger_noise: Option<f32>,
    /// Close bursts in the DART episodes: the probability per step of holding the executed
    /// finger actions fully closing for 3-8 steps (0: none, at most 0.5).
    #[arg(long)]
    close_bursts: Option<f32>,
    /// Open bursts in the DART episodes: the probability per step of holding the executed finger
    /// actions fully opening for 3-8 steps (0: none, at most 0.5).
    #[arg(long)]
    open_bursts: Option<f32>,
    /// DAgger rounds after round 0.
    #[arg(long)]
    rounds: Option<u32>,
    /// Policy episodes labelled per DAgger round.
    #[arg(long)]
    episodes_per_round: Option<u32>,
    /// DAgger rounds keep only the policy's failed episodes.
    #[arg(long)]
    dagger_failures_only: bool,
    /// Each DAgger round's episodes count this many times in the cloning data (1-100).
    #[arg(long)]
    dagger_repeat: Option<u32>,
    /// Behaviour-cloning gradient steps per round.
    #[arg(long)]
    bc_steps: Option<u64>,
    /// Cloning learning rate at the last step as a fraction of the first (cosine schedule; 1:
    /// constant).
    #[arg(long)]
    bc_final_lr: Option<f32>,
    /// Hidden layer widths, comma-separated.
    #[arg(long, value_delimiter = ',')]
    hidden: Option<Vec<usize>>,
    /// Whether the policy also takes the controller's task features (the pinch site's yaw, the
    /// bricks' yaws relative to it, the pinch-to-brick vectors in its frame; docs/imitation.md):
    /// on by default, `--features false` clones from the observation alone.
    #[arg(long, action = clap::ArgAction::Set)]
    features: Option<bool>,
    /// Selection starts per round (seed 2,000,000).
    #[arg(long)]
    select_episodes: Option<u32>,
    /// Seeds, comma-separated (one run folder each: OUT/seed-S).
    #[arg(long, value_delimiter = ',', default_value = "0")]
    seeds: Vec<u64>,
    /// Episodes of the final evaluation of each exported policy (`trainer eval`'s seed 1,000,000).
    #[arg(long, default_value_t = 100)]
    final_eval_episodes: u32,
    /// Output folder.
    #[arg(long, default_value = "runs/imitate")]
    out: PathBuf,
    /// One line per round instead of progress bars.
    #[arg(long)]
    quiet: bool,
}

impl ImitateArgs {
    /// The validated settings of seed `seed`.
    fn settings(&self, seed: u64) -> anyhow::Result<ImitationConfig> {
        let mut c = ImitationConfig {
            seed,
            ..ImitationConfig::for_task(self.task.task())
        };
        if let Some(v) = self.demo_episodes {
            c.demo_episodes = v;
        }
        if let Some(v) = self.dart_episodes {
            c.dart_episodes = v;
        }
        if let Some(v) = self.in_hand_episodes {
            c.in_hand_episodes = v;
        }
        if let Some(v) = self.close_dart_episodes {
            c.close_dart_episodes = v;
        }
        if let Some(v) = self.close_spacing {
            c.close_spacing = v;
        }
        if let Some(v) = self.arm_noise {
            c.arm_noise = v;
        }
        if let Some(v) = self.finger_noise {
            c.finger_noise = v;
        }
        if let Some(v) = self.close_bursts {
            c.close_bursts = v;
        }
        if let Some(v) = self.open_bursts {
            c.open_bursts = v;
        }
        if self.tuck_first {
            c.tuck_first = true;
        }
        if self.tuck_ramp {
            c.tuck_ramp = true;
        }
        if !self.teacher_policies.is_empty() {
            c.teacher_policies = self.teacher_policies.clone();
        }
        if let Some(p) = &self.teacher_pair {
            c.teacher_pair = Some(p.clone());
        }
        if let Some(v) = self.rounds {
            c.rounds = v;
        }
        if let Some(v) = self.episodes_per_round {
            c.episodes_per_round = v;
        }
        if self.dagger_failures_only {
            c.dagger_failures_only = true;
        }
        if let Some(v) = self.dagger_repeat {
            c.dagger_repeat = v;
        }
        if let Some(v) = self.bc_steps {
            c.bc.steps = v;
        }
        if let Some(v) = self.bc_final_lr {
            c.bc.final_lr_fraction = v;
        }
        if let Some(v) = &self.hidden {
            c.bc.hidden = v.clone();
        }
        if let Some(v) = self.features {
            c.bc.features = v;
        }
        if let Some(v) = self.select_episodes {
            c.select_episodes = v;
        }
        if let Some(p) = &self.self_imitation {
            c.self_imitation = Some(SelfImitation {
                policy: p.clone(),
                episodes: self.self_imitation_episodes,
                arm_noise: c.arm_noise,
                finger_noise: c.finger_noise,
                repeat: self.self_imitation_repeat,
            });
        }
        if let Some(p) = &self.rollout_teacher {
            let mut rt = RolloutTeacher::new(p.clone());
            rt.episodes = self.rollout_episodes.unwrap_or(rt.episodes);
            rt.stride = self.rollout_stride.unwrap_or(rt.stride);
            rt.candidates = self.rollout_candidates.unwrap_or(rt.candidates);
            rt.repeat = self.rollout_repeat.unwrap_or(rt.repeat);
            rt.arm_noise = self.rollout_arm_noise.unwrap_or(rt.arm_noise);
            rt.finger_noise = self.rollout_finger_noise.unwrap_or(rt.finger_noise);
            c.rollout_teacher = Some(rt);
        }
        if self.close_spacing.is_some() && c.close_dart_episodes == 0 {
            anyhow::bail!("--close-spacing places the starts of --close-dart-episodes, which is 0");
        }
        c.validate()?;
        Ok(c)
    }
}

/// Runs (resuming) every seed, then evaluates and plots.
pub fn imitate(a: &ImitateArgs) -> anyhow::Result<()> {
    let configs: Vec<ImitationConfig> = a
        .seeds
        .iter()
        .map(|&s| a.settings(s))
        .collect::<anyhow::Result<_>>()?;
    let scene = crate::train::load_scene()?;
    for cfg in &configs {
        let dir = a.out.join(format!("seed-{}", cfg.seed));
        let pb: Option<ProgressBar> = (!a.quiet).then(|| {
            crate::train::bar(
                cfg.bc.steps,
                false,
                "{msg} [{elapsed_precise}] [{bar:30}] {pos}/{len}",
            )
        });
        let start = std::time::Instant::now();
        let summary = run_imitation(&scene, cfg, &dir, &mut |ev| match ev {
            ImitationEvent::Recording { round, episodes } => {
                let line = format!(
                    "seed {} round {round}: recording {episodes} episodes",
                    cfg.seed
                );
                match &pb {
                    Some(pb) => pb.set_message(line),
                    None => println!("{line}"),
                }
            }
            ImitationEvent::Cloning { round, steps } => {
                if let Some(pb) = &pb {
                    pb.set_length(steps);
                    pb.set_position(0);
                    pb.set_message(format!("seed {} round {round}: cloning", cfg.seed));
                }
            }
            ImitationEvent::CloneStep(step, _) => {
                if let Some(pb) = &pb {
                    pb.set_position(step);
                }
            }
            ImitationEvent::Round(r) => {
                let line = format!(
                    "seed {} round {}: {} env steps, {} BC steps, {:.0} s: selection success {:.1}%",
                    cfg.seed,
                    r.eval_index,
                    r.transitions,
                    r.updates,
                    r.wall_s,
                    100.0 * r.success_rate
                );
                match &pb {
                    Some(pb) => pb.println(line),
                    None => println!("{line}"),
                }
            }
        })?;
        if let Some(pb) = pb {
            pb.finish_and_clear();
        }
        println!(
            "seed {}: best round {} -> {} ({:.0} s in this call)",
            cfg.seed,
            summary.best_round,
            summary.policy.display(),
            start.elapsed().as_secs_f64()
        );
        if a.final_eval_episodes > 0 {
            let bytes = std::fs::read(&summary.policy)?;
            let settings = EvalSettings {
                env: dex_trainer::env::EnvConfig::new(cfg.task),
                episodes: a.final_eval_episodes,
                seed: EVAL_SEED,
                threads: cfg.eval_threads,
                can_quantisation: true,
                envelope: false,
            };
            let e = evaluate_policy_file(&bytes, &scene, &settings, &|| {})?;
            println!(
                "{} on {:?}, {} random starts from seed {EVAL_SEED}: {}",
                summary.policy.display(),
                cfg.task,
                a.final_eval_episodes,
                crate::train::describe(&e)
            );
        }
    }
    for f in crate::train::plot_run(&a.out)? {
        println!("wrote {}", f.display());
    }
    Ok(())
}
