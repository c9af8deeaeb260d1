//! How a Reach policy fails: over `--episodes` starts (from `trainer eval`'s seed 1,000,000, CAN
//! quantisation on, through the runtime), how many episodes end in the reach box, how many were in
//! it at some step and left it, and how many never got there; for the failures, the step of the
//! first entry, the final pinch-to-brick distance and how far brick 1 was pushed.
//!
//! ```text
//! cargo run --release -p dex-trainer --example reach_failures -- POLICY.dxpl [--episodes 300]
//! ```

use anyhow::Context;
use clap::Parser;
use dex_runtime::Mlp;
use dex_runtime::interface::OBSERVATION_FIELDS;
use dex_trainer::env::seeds::{EVAL_SEED, episode_seed};
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};

#[derive(Parser)]
struct Args {
    /// Reach policy file.
    policy: std::path::PathBuf,
    /// Episodes.
    #[arg(long, default_value_t = 300)]
    episodes: u64,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let bytes = std::fs::read(&args.policy)
        .with_context(|| format!("cannot read {}", args.policy.display()))?;
    let aligned = dex_runtime::testkit::aligned_copy(&bytes);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    let mut mlp = Mlp::<256>::new(&view)?;
    let scene = Scene::load().context("cannot build the MuJoCo scene (scripts/setup-mujoco.sh)")?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Reach));
    // Offsets of observation fields.
    let offset_of = |name: &str| -> anyhow::Result<usize> {
        let field = OBSERVATION_FIELDS
            .iter()
            .position(|f| f.name == name)
            .with_context(|| format!("no {name} field"))?;
        Ok(OBSERVATION_FIELDS[..field].iter().map(|f| f.size).sum())
    };
    let (offset, brick) = (offset_of("pinch_to_brick1")?, offset_of("brick1_pos")?);
    let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
    let (mut ended_in, mut left) = (0, Vec::new());
    let mut never = Vec::new();
    for i in 0..args.episodes {
        let mut obs = env.reset(episode_seed(EVAL_SEED, i))?;
        let brick_start = [obs[brick], obs[brick + 1], obs[brick + 2]];
        let mut first_in = None;
        let mut step = 0u32;
        let (success, distance) = loop {
            let command = controller_command(&mut mlp, &obs, true, None)?;
            let out = env.step(&physical_to_env_action(&command))?;
            step += 1;
            if out.success && first_in.is_none() {
                first_in = Some(step);
            }
            obs = out.observation;
            if out.done {
                break (out.success, norm(&obs[offset..offset + 3]));
            }
        };
        let pushed = norm(&core::array::from_fn::<f32, 3, _>(|k| {
            obs[brick + k] - brick_start[k]
        }));
        match (success, first_in) {
            (true, _) => ended_in += 1,
            (false, Some(first)) => left.push((first, distance, pushed)),
            (false, None) => never.push(distance),
        }
    }
    println!(
        "{} episodes: ended in the reach box {ended_in}, in it at some step but not at the end {}, never in it {}",
        args.episodes,
        left.len(),
        never.len()
    );
    let summary = |mut v: Vec<f32>| -> String {
        if v.is_empty() {
            return "-".into();
        }
        v.sort_by(f32::total_cmp);
        format!(
            "min {:.3} / median {:.3} / max {:.3}",
            v[0],
            v[v.len() / 2],
            v[v.len() - 1]
        )
    };
    println!(
        "left the box: first entry at step {}; final distance to brick 1 (m) {}; brick 1 pushed by (m) {}",
        summary(left.iter().map(|l| l.0 as f32).collect()),
        summary(left.iter().map(|l| l.1).collect()),
        summary(left.iter().map(|l| l.2).collect())
    );
    println!("never in it: final distance (m) {}", summary(never));
    Ok(())
}
