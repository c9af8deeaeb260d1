//! How a Grasp / StackInHand / Stack policy fails: over `--episodes` starts from `--seed` (default
//! `trainer eval`'s 1,000,000; CAN quantisation on, through the runtime, the task features computed
//! as the controller does for a policy that takes them), for every failed episode the highest brick 1
//! got, where it ended (height, distance to the pinch site, offset from the stacking site) and the
//! mean finger angle at the end; the failures are grouped by the predicates that held at some step.
//! A traced episode also prints the Markov teacher's phase and label at every step.
//!
//! ```text
//! cargo run --release -p dex-trainer --example task_failures -- POLICY.dxpl [--episodes 100] \
//!     [--seed 1000000] [--verbose] [--trace EPISODE]
//! ```

use anyhow::Context;
use clap::Parser;
use dex_runtime::Mlp;
use dex_trainer::env::seeds::{EVAL_SEED, episode_seed};
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};

#[derive(Parser)]
struct Args {
    /// Policy file.
    policy: std::path::PathBuf,
    /// Episodes.
    #[arg(long, default_value_t = 100)]
    episodes: u64,
    /// Start seed of the episodes.
    #[arg(long, default_value_t = EVAL_SEED)]
    seed: u64,
    /// Print every failed episode.
    #[arg(long)]
    verbose: bool,
    /// Print every step of this episode.
    #[arg(long)]
    trace: Option<u64>,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let bytes = std::fs::read(&args.policy)
        .with_context(|| format!("cannot read {}", args.policy.display()))?;
    let aligned = dex_runtime::testkit::aligned_copy(&bytes);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    let task = Task::from(view.body().task);
    let mut mlp = Mlp::<1024>::new(&view)?;
    let scene = Scene::load().context("cannot build the MuJoCo scene (scripts/setup-mujoco.sh)")?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(task));
    // The Markov teacher's label at each traced step, beside the policy's action.
    let teacher = dex_trainer::env::MarkovDemonstrator::new(task);
    let mut groups = std::collections::BTreeMap::<String, u32>::new();
    let mut successes = 0;
    for i in 0..args.episodes {
        let mut obs = env.reset(episode_seed(args.seed, i))?;
        let (mut ever_reach, mut ever_grasp, mut ever_stack) = (false, false, false);
        let mut max_z = 0.0f64;
        let mut wrist_travel = 0.0f32;
        let mut last_wrist = obs[5].atan2(obs[11]);
        let out = loop {
            let action = physical_to_env_action(&controller_command(&mut mlp, &obs, true, None)?);
            let label = (args.trace == Some(i)).then(|| (teacher.phase(&env), teacher.act(&env)));
            let out = env.step(&action)?;
            let p = out.predicates;
            if args.trace == Some(i) {
                let s = env.reward_state();
                let rel: Vec<f64> = (0..3).map(|k| s.pinch[k] - s.brick1_pos[k]).collect();
                println!(
                    "t {:3} j6 {:+.2} pinch-b1 {:+.3?} b1z {:.3} fingers q {:.2?} act arm {:+.2?} fingers {:+.2?} {:?}",
                    env.steps_taken(),
                    obs[5].atan2(obs[11]),
                    rel,
                    s.brick1_pos[2],
                    &obs[12..15],
                    &action[..6],
                    &action[6..],
                    p
                );
                if let Some((phase, l)) = label {
                    println!(
                        "      teacher {phase:?} arm {:+.2?} fingers {:+.2?}",
                        &l[..6],
                        &l[6..]
                    );
                }
            }
            ever_reach |= p.reach;
            ever_grasp |= p.grasp;
            ever_stack |= p.stack;
            max_z = max_z.max(env.reward_state().brick1_pos[2]);
            let w = out.observation[5].atan2(out.observation[11]);
            let mut d = w - last_wrist;
            if d > std::f32::consts::PI {
                d -= std::f32::consts::TAU;
            } else if d < -std::f32::consts::PI {
                d += std::f32::consts::TAU;
            }
            wrist_travel += d.abs();
            last_wrist = w;
            obs = out.observation;
            if out.done {
                break out;
            }
        };
        if out.success {
            successes += 1;
            continue;
        }
        let s = env.reward_state();
        let d = s
            .brick1_pos
            .iter()
            .zip(&s.pinch)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        let fingers = obs[12..15].iter().sum::<f32>() / 3.0;
        let group = format!(
            "reach {} grasp {} stack {} | at end: reach {} grasp {}",
            u8::from(ever_reach),
            u8::from(ever_grasp),
            u8::from(ever_stack),
            u8::from(out.predicates.reach),
            u8::from(out.predicates.grasp)
        );
        *groups.entry(group).or_default() += 1;
        if args.verbose {
            println!(
                "episode {i}: max brick z {max_z:.3}, end z {:.3}, pinch distance {d:.3}, stack offset {:.3?}, fingers {fingers:.2}, wrist travel {wrist_travel:.1} rad",
                s.brick1_pos[2],
                s.stack_offset()
            );
        }
    }
    println!(
        "{task:?}: {successes}/{} successes; failures by predicates seen:",
        args.episodes
    );
    for (g, n) in groups {
        println!("  {n:4}  {g}");
    }
    Ok(())
}
