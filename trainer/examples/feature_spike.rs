//! Spike (issue #26): does a cloned actor that also sees the runtime's task features
//! (`dex_runtime::features`: the pinch site's yaw, the bricks' yaws relative to it modulo the half
//! turn, the pinch-to-brick vectors in the pinch frame) follow the demonstrator more closely than
//! one that sees the observation alone? Clones the same recorded demonstrations both ways with the
//! same settings and runs both actors in-process (trainer networks, no file, no CAN quantisation)
//! on the same starts. The number is for the A/B only; a shipped figure comes from `trainer eval`.
//!
//! ```text
//! cargo run --release -p dex-trainer --example feature_spike -- \
//!     runs/s14/grasp-d3/seed-0/demos-0.dxdm runs/s14/grasp-d3/seed-0/demos-0-dart.dxdm \
//!     --hidden 256,256 --steps 30000 --episodes 300
//! ```

use anyhow::Context;
use clap::Parser;
use dex_runtime::features::{FEATURE_DIM, task_features};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};
use dex_trainer::files::demos::DemoSet;
use dex_trainer::learn::bc::{BcConfig, BcPolicy, train_bc};
use dex_trainer::pipeline::cloning::{clone_rows, with_features};

#[derive(Parser)]
struct Args {
    /// Demonstration files (`.dxdm`) of one task.
    demos: Vec<std::path::PathBuf>,
    /// Task.
    #[arg(long, default_value = "grasp")]
    task: Task,
    /// Hidden widths.
    #[arg(long, value_delimiter = ',', default_values_t = [256usize, 256])]
    hidden: Vec<usize>,
    /// Cloning steps.
    #[arg(long, default_value_t = 30_000)]
    steps: u64,
    /// Evaluation episodes (starts from `--seed`).
    #[arg(long, default_value_t = 300)]
    episodes: u64,
    /// Seed of the evaluation starts.
    #[arg(long, default_value_t = 4_000_000)]
    seed: u64,
    /// Cloning seed.
    #[arg(long, default_value_t = 0)]
    bc_seed: u64,
    /// Which arms: "both", "plain" or "features".
    #[arg(long, default_value = "both")]
    arms: String,
}

/// The observation, with the task features after it when `features`.
fn input(obs: &[f32; OBS_DIM], features: bool) -> Vec<f32> {
    let mut v = obs.to_vec();
    if features {
        v.extend_from_slice(&task_features(obs));
    }
    v
}

fn evaluate(
    policy: &BcPolicy,
    features: bool,
    scene: &Scene,
    args: &Args,
) -> anyhow::Result<(u64, f64)> {
    let mut env = JacoEnv::new(scene, EnvConfig::new(args.task));
    let mut scratch = policy.actor.scratch(1);
    let (mut successes, mut total) = (0u64, 0.0f64);
    for i in 0..args.episodes {
        let mut obs = env.reset(episode_seed(args.seed, i))?;
        loop {
            let mut x = input(&obs, features);
            policy.scaling.apply_rows(&mut x);
            let y = policy.actor.forward(&policy.params, &x, 1, &mut scratch)?;
            let action: [f32; ACT_DIM] = core::array::from_fn(|k| y[k].clamp(-1.0, 1.0));
            let out = env.step(&action)?;
            total += f64::from(out.reward);
            obs = out.observation;
            if out.done {
                successes += u64::from(out.success);
                break;
            }
        }
    }
    Ok((successes, total / args.episodes.max(1) as f64))
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let mut sets = Vec::new();
    for p in &args.demos {
        sets.push(DemoSet::load(p).with_context(|| format!("cannot load {}", p.display()))?);
    }
    let (obs, labels) = clone_rows(&sets, args.task)?;
    let scene = Scene::load().context("cannot build the MuJoCo scene (scripts/setup-mujoco.sh)")?;
    for features in [false, true] {
        let name = if features { "features" } else { "plain" };
        if args.arms != "both" && args.arms != name {
            continue;
        }
        let rows = if features {
            with_features(&obs)
        } else {
            obs.clone()
        };
        let dim = OBS_DIM + if features { FEATURE_DIM } else { 0 };
        let cfg = BcConfig {
            hidden: args.hidden.clone(),
            steps: args.steps,
            seed: args.bc_seed,
            ..BcConfig::default()
        };
        let started = std::time::Instant::now();
        let policy = train_bc(&rows, &labels, dim, ACT_DIM, &cfg, &mut |_, _| {})?;
        let trained = started.elapsed().as_secs_f64();
        let (s, r) = evaluate(&policy, features, &scene, &args)?;
        println!(
            "{name}: inputs {dim}, hidden {:?}, {} rows, {} steps, final loss {:.5}: {s}/{} = {:.1}% success, mean return {r:.1} (clone {trained:.0} s, eval {:.0} s)",
            args.hidden,
            labels.len() / ACT_DIM,
            args.steps,
            policy.final_loss,
            args.episodes,
            100.0 * s as f64 / args.episodes.max(1) as f64,
            started.elapsed().as_secs_f64() - trained,
        );
    }
    Ok(())
}
