//! How a policy file's episodes change under small perturbations of its actions (issue #26,
//! session 25; through the runtime with CAN quantisation, as `trainer eval`):
//!
//! - default: can a failed episode be rescued by perturbing its actions for a few steps at one
//!   point and then following the policy? For each failed episode over `--episodes` starts from
//!   `--seed`, at every `--every`-th step, `--candidates` perturbations (the policy's action plus
//!   Gaussian noise `--noise`, re-drawn each step, for `--hold` steps) are tried from a
//!   snapshot, then the policy runs to the episode's end; prints which branch points rescue it.
//! - `--noisy-episodes M`: from every start, the deterministic episode and `M` episodes with
//!   noise `--noise` on every action; prints each start's outcomes.
//!
//! ```text
//! cargo run --release -p dex-trainer --example perturbed_episodes -- POLICY.dxpl [--episodes 300] \
//!     [--seed 9000000] [--every 5] [--candidates 8] [--noise 0.3] [--hold 5] [--noisy-episodes M]
//! ```

use anyhow::Context;
use clap::Parser;
use dex_runtime::Mlp;
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};
use dex_trainer::learn::Rng;

#[derive(Parser)]
struct Args {
    policy: std::path::PathBuf,
    #[arg(long, default_value_t = 300)]
    episodes: u64,
    #[arg(long, default_value_t = 9_000_000)]
    seed: u64,
    #[arg(long, default_value_t = 5)]
    every: u32,
    #[arg(long, default_value_t = 8)]
    candidates: u32,
    #[arg(long, default_value_t = 0.3)]
    noise: f32,
    #[arg(long, default_value_t = 5)]
    hold: u32,
    /// Instead of branching: from each start, this many episodes with noise on every step.
    #[arg(long)]
    noisy_episodes: Option<u32>,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let bytes = std::fs::read(&args.policy)
        .with_context(|| format!("cannot read {}", args.policy.display()))?;
    let aligned = dex_runtime::testkit::aligned_copy(&bytes);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    let task = Task::from(view.body().task);
    let mut mlp = Mlp::<1024>::new(&view)?;
    let scene = Scene::load().context("cannot build the MuJoCo scene")?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(task));
    let (mut failed, mut rescued) = (0, 0);
    for i in 0..args.episodes {
        let mut obs = env.reset(episode_seed(args.seed, i))?;
        let mut snaps = Vec::new();
        let success = loop {
            snaps.push(env.snapshot());
            let action = physical_to_env_action(&controller_command(&mut mlp, &obs, true, None)?);
            let out = env.step(&action)?;
            obs = out.observation;
            if out.done {
                break out.success;
            }
        };
        if let Some(m) = args.noisy_episodes {
            let mut rng = Rng::derive(args.seed, i);
            let mut n = 0;
            for _ in 0..m {
                let mut o = env.restore(&snaps[0])?;
                let ok = loop {
                    let mut a =
                        physical_to_env_action(&controller_command(&mut mlp, &o, true, None)?);
                    for v in &mut a {
                        *v = (*v + rng.normal(0.0, args.noise)).clamp(-1.0, 1.0);
                    }
                    let out = env.step(&a)?;
                    o = out.observation;
                    if out.done {
                        break out.success;
                    }
                };
                n += u32::from(ok);
            }
            println!("start {i}: deterministic {success}, noisy {n}/{m}");
            continue;
        }
        if success {
            continue;
        }
        failed += 1;
        let mut rng = Rng::derive(args.seed, i);
        let mut wins = Vec::new();
        for t in (0..snaps.len()).step_by(args.every as usize) {
            let mut n = 0;
            for _ in 0..args.candidates {
                let mut o = env.restore(&snaps[t])?;
                let mut k = 0;
                let ok = loop {
                    let mut a =
                        physical_to_env_action(&controller_command(&mut mlp, &o, true, None)?);
                    if k < args.hold {
                        for v in &mut a {
                            *v = (*v + rng.normal(0.0, args.noise)).clamp(-1.0, 1.0);
                        }
                    }
                    k += 1;
                    let out = env.step(&a)?;
                    o = out.observation;
                    if out.done {
                        break out.success;
                    }
                };
                n += u32::from(ok);
            }
            if n > 0 {
                wins.push((t, n));
            }
        }
        if !wins.is_empty() {
            rescued += 1;
        }
        println!(
            "episode {i}: rescues (step, of {}) {wins:?}",
            args.candidates
        );
    }
    println!("{failed} failed, {rescued} rescued by some branch");
    Ok(())
}
