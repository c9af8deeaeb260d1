//! `trainer pg POLICY --out DIR`: fine-tunes a policy file by the group-relative policy gradient
//! (`dex_trainer::pipeline::group_pg`: on-policy, from the task's success, no critic). Resumes
//! from `DIR`'s checkpoint when there is one (the iteration budget may grow, nothing else may
//! change); writes `DIR/policy.dxpl` at the end. Ctrl-C stops it before the next iteration.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use dex_trainer::files::atomic_write::write_atomic;
use dex_trainer::files::comparison_record::ComparisonRecord;
use dex_trainer::files::result_record::sha256_hex;
use dex_trainer::pipeline::group_pg::{GroupPg, PROGRESS, run_until};

use crate::train::{bar, load_scene, stop_flag};

/// `trainer pg` flags (defaults: [`GroupPg::new`]).
#[derive(Args, Debug)]
pub struct PgArgs {
    /// The f32 policy file to start from (its task is the run's).
    policy: PathBuf,
    /// Run folder (checkpoint, progress lines, policy files).
    #[arg(long)]
    out: PathBuf,
    /// Iterations (each: the rollouts, then the update).
    #[arg(long)]
    iterations: Option<u32>,
    /// Training starts per iteration.
    #[arg(long)]
    groups: Option<u32>,
    /// Episodes from each start (at least 2).
    #[arg(long)]
    replicates: Option<u32>,
    /// Noise on the arm's actions (standard deviation, action units).
    #[arg(long)]
    arm_noise: Option<f32>,
    /// Noise on the fingers' actions.
    #[arg(long)]
    finger_noise: Option<f32>,
    /// Adam's step size.
    #[arg(long)]
    lr: Option<f32>,
    /// Passes over an iteration's steps.
    #[arg(long)]
    epochs: Option<u32>,
    /// Steps per Adam step.
    #[arg(long)]
    minibatch: Option<u32>,
    /// PPO's ratio clip.
    #[arg(long)]
    clip: Option<f32>,
    /// Weight of the KL divergence to the starting file.
    #[arg(long)]
    anchor: Option<f32>,
    /// Share of the groups that revisit starts where a recent group failed.
    #[arg(long)]
    revisit: Option<f32>,
    /// Groups per iteration, beside `--groups`, from states where the policy stalled before its
    /// grasp (`dex_trainer::pipeline::stall_starts`).
    #[arg(long)]
    stall_groups: Option<u32>,
    /// Noise-free episodes of the starting file whose stalls fill the pool before the first
    /// iteration (needs `--stall-groups`).
    #[arg(long)]
    stall_harvest: Option<u32>,
    /// Weight of the KL divergence to the starting file on every step of the start-seed groups
    /// (holds the policy where it works while the stall groups move it).
    #[arg(long)]
    fresh_anchor: Option<f32>,
    /// Steps before each stall that the pool keeps (0: the stalled state; needs `--stall-groups`).
    #[arg(long)]
    stall_back: Option<u32>,
    /// Steps at the beginning of each stall group's episodes that carry noise; the rest run the
    /// policy's own action and stay out of the update (0: every step; needs `--stall-groups`).
    #[arg(long)]
    stall_noise_steps: Option<u32>,
    /// Groups per iteration, beside `--groups`, from fresh starts drawn with the bricks' centres
    /// at most `--close-spacing` apart, where the Stack files' failures lie.
    #[arg(long)]
    close_groups: Option<u32>,
    /// The close groups' largest spacing of the bricks' centres, metres (default 0.095; needs
    /// `--close-groups`).
    #[arg(long)]
    close_spacing: Option<f32>,
    /// Steps at the beginning of each close group's episodes that carry noise; the rest run the
    /// policy's own action and stay out of the update (0: every step; needs `--close-groups`).
    #[arg(long)]
    close_noise_steps: Option<u32>,
    /// Groups per iteration, beside `--groups`, from starts the starting file fails without
    /// noise, listed by `--failed-from`.
    #[arg(long)]
    failed_groups: Option<u32>,
    /// A `trainer compare --json` record of the starting file on training starts (e.g.
    /// `--seed 9000000`, the screening block): its failed starts are the failed-start groups'
    /// pool (needs `--failed-groups`).
    #[arg(long)]
    failed_from: Option<PathBuf>,
    /// Steps at the beginning of each failed-start group's episodes that carry noise; the rest
    /// run the policy's own action and stay out of the update (0: every step; needs
    /// `--failed-groups`).
    #[arg(long)]
    failed_noise_steps: Option<u32>,
    /// What an episode in which the robot touches brick 2 before it grasps brick 1 loses beside
    /// its success, in [0, 1] (default 0).
    #[arg(long)]
    contact_cost: Option<f32>,
    /// With `--contact-cost`: metres within which a fingertip passing brick 2 before the grasp
    /// pays a share of the cost, `(margin - clearance) / margin` (default 0: only a contact).
    #[arg(long)]
    contact_margin: Option<f32>,
    /// Correlation of each joint's exploration noise from one step to the next, in [0, 1)
    /// (default 0: white noise): an AR(1) drift of the same spread, which moves the approach.
    #[arg(long)]
    noise_correlation: Option<f32>,
    /// Seed of the starts, the noise and the minibatch order.
    #[arg(long)]
    seed: Option<u64>,
    /// Rollout threads (the result does not depend on them).
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Keep the actor as `policy-NNNN.dxpl` every this many iterations (0: only the latest).
    #[arg(long, default_value_t = 10)]
    save_every: u32,
    /// One line per iteration instead of a progress bar.
    #[arg(long)]
    quiet: bool,
}

impl PgArgs {
    fn settings(&self) -> anyhow::Result<GroupPg> {
        let d = GroupPg::new(self.policy.clone());
        let failed_starts = match (&self.failed_from, self.failed_groups) {
            (Some(path), Some(n)) if n > 0 => {
                let record = ComparisonRecord::read(path)?;
                let file = std::fs::read(&self.policy)
                    .with_context(|| format!("reading {}", self.policy.display()))?;
                record.failed_seeds_of(&sha256_hex(&file), &path.display().to_string())?
            }
            (Some(_), _) => {
                anyhow::bail!("--failed-from lists the starts of --failed-groups, which is 0")
            }
            (None, _) => Vec::new(),
        };
        Ok(GroupPg {
            iterations: self.iterations.unwrap_or(d.iterations),
            groups: self.groups.unwrap_or(d.groups),
            replicates: self.replicates.unwrap_or(d.replicates),
            arm_noise: self.arm_noise.unwrap_or(d.arm_noise),
            finger_noise: self.finger_noise.unwrap_or(d.finger_noise),
            lr: self.lr.unwrap_or(d.lr),
            epochs: self.epochs.unwrap_or(d.epochs),
            minibatch: self.minibatch.unwrap_or(d.minibatch),
            clip: self.clip.unwrap_or(d.clip),
            anchor: self.anchor.unwrap_or(d.anchor),
            revisit: self.revisit.unwrap_or(d.revisit),
            stall_groups: self.stall_groups.unwrap_or(d.stall_groups),
            stall_harvest: self.stall_harvest.unwrap_or(d.stall_harvest),
            fresh_anchor: self.fresh_anchor.unwrap_or(d.fresh_anchor),
            stall_back: self.stall_back.unwrap_or(d.stall_back),
            stall_noise_steps: self.stall_noise_steps.unwrap_or(d.stall_noise_steps),
            close_groups: self.close_groups.unwrap_or(d.close_groups),
            close_spacing: self.close_spacing.unwrap_or(d.close_spacing),
            close_noise_steps: self.close_noise_steps.unwrap_or(d.close_noise_steps),
            failed_groups: self.failed_groups.unwrap_or(d.failed_groups),
            failed_starts,
            failed_noise_steps: self.failed_noise_steps.unwrap_or(d.failed_noise_steps),
            contact_cost: self.contact_cost.unwrap_or(d.contact_cost),
            contact_margin: self.contact_margin.unwrap_or(d.contact_margin),
            noise_correlation: self.noise_correlation.unwrap_or(d.noise_correlation),
            seed: self.seed.unwrap_or(d.seed),
            ..d
        })
    }
}

/// Runs `trainer pg`.
pub fn pg(args: &PgArgs) -> anyhow::Result<()> {
    let settings = args.settings()?;
    settings.validate()?;
    if args.close_spacing.is_some() && settings.close_groups == 0 {
        anyhow::bail!("--close-spacing places the starts of --close-groups, which is 0");
    }
    let task = settings.task()?;
    let scene = load_scene()?;
    let stop = stop_flag()?;
    let pb = bar(
        u64::from(settings.iterations),
        args.quiet,
        "group PG {bar:30} {pos}/{len} iterations ({elapsed}, eta {eta}) {msg}",
    );
    let file = run_until(
        &settings,
        &scene,
        task,
        &args.out,
        args.threads,
        args.save_every,
        &stop,
        &mut |r| {
            let line = r.line(settings.replicates);
            if args.quiet {
                println!("{line}");
            } else {
                pb.set_position(u64::from(r.iteration + 1));
                pb.set_message(format!("{}/{}", r.successes, r.episodes));
            }
        },
    )?;
    pb.finish_and_clear();
    if stop.load(std::sync::atomic::Ordering::SeqCst) {
        println!(
            "stopped: the checkpoint holds every finished iteration; run the same command again \
             to continue"
        );
        return Ok(());
    }
    let out = args.out.join("policy.dxpl");
    write_atomic(&out, &file).with_context(|| format!("cannot write {}", out.display()))?;
    println!(
        "wrote {} (progress: {})",
        out.display(),
        args.out.join(PROGRESS).display()
    );
    Ok(())
}
