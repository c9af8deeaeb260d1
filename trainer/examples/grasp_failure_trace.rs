//! One Grasp episode of a policy file, step by step, next to the Markov teacher's label at each
//! state the policy visits (the policy acts and the teacher is only asked, until `--handover`). Runs
//! the policy as `task_failures` does (CAN quantisation, through the runtime, task features).
//!
//! ```text
//! cargo run --release -p dex-trainer --example grasp_failure_trace -- POLICY.dxpl --episode 145 \
//!     [--seed 1000000] [--from 0] [--to 1000] [--handover STEP] [--tuck-first]
//! ```
//!
//! Columns: step, teacher phase, teacher / policy finger actions (normalised, 1 = close), mean
//! finger angle (rad), pinch minus grasp point (xy distance and z, mm), brick 1 height (mm), yaw of
//! brick 1 (mod pi) minus the hand's (rad), brick 1 horizontal displacement from its start (mm),
//! |policy - teacher| over the six arm actions, and the contacts of arm or hand bodies with brick 1
//! (`1:`), brick 2 (`2:`) or the table (`T:`).

use anyhow::Context;
use clap::Parser;
use dex_runtime::Mlp;
use dex_trainer::env::kinematics::pinch_pose;
use dex_trainer::env::scene::{ARM_JOINTS, GRASP_DEPTH};
use dex_trainer::env::seeds::{EVAL_SEED, episode_seed};
use dex_trainer::env::{EnvConfig, JacoEnv, MarkovDemonstrator, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};
use mujoco_rs::prelude::MjtObjBase;
use std::f64::consts::PI;

#[derive(Parser)]
struct Args {
    /// Policy file (a Grasp policy).
    policy: std::path::PathBuf,
    /// Episode index from `--seed` (as `task_failures --verbose` numbers them).
    #[arg(long)]
    episode: u64,
    /// Start seed of the episodes.
    #[arg(long, default_value_t = EVAL_SEED)]
    seed: u64,
    /// First step printed.
    #[arg(long, default_value_t = 0)]
    from: u32,
    /// Last step printed.
    #[arg(long, default_value_t = u32::MAX)]
    to: u32,
    /// From this step on the teacher acts instead of the policy (does its label recover the state?).
    #[arg(long)]
    handover: Option<u32>,
    /// The teacher with `MarkovDemonstrator::with_tuck_first` (its labels and, after
    /// `--handover`, its actions).
    #[arg(long)]
    tuck_first: bool,
}

/// Wraps an angle into (-pi/2, pi/2] (a brick looks the same turned by pi).
fn wrap_half_pi(a: f64) -> f64 {
    let a = a.rem_euclid(PI);
    if a > PI / 2.0 { a - PI } else { a }
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let bytes = std::fs::read(&args.policy)
        .with_context(|| format!("cannot read {}", args.policy.display()))?;
    let aligned = dex_runtime::testkit::aligned_copy(&bytes);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    anyhow::ensure!(
        view.body().task == dex_policy::Task::Grasp,
        "not a Grasp policy"
    );
    let mut mlp = Mlp::<1024>::new(&view)?;
    let scene = Scene::load().context("cannot build the MuJoCo scene (scripts/setup-mujoco.sh)")?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Grasp));
    let teacher = MarkovDemonstrator::new(Task::Grasp).with_tuck_first(args.tuck_first);
    let mut obs = env.reset(episode_seed(args.seed, args.episode))?;
    let start = env.reward_state().brick1_pos;
    println!(
        "episode {} (seed {}): brick1 at {:.3?}",
        args.episode,
        episode_seed(args.seed, args.episode),
        start
    );
    println!(
        "   t phase    teacher fingers   policy fingers   q     dxy   dz    b1z  yaw    moved  arm|d|"
    );
    let out = loop {
        // The state, measured before the step, and the teacher's label for it.
        let ids = env.scene().ids();
        let data = env.data();
        let (pinch, rot) = pinch_pose(data, ids);
        let b1 = env.reward_state().brick1_pos;
        let m1 = data.xmat()[ids.brick1_body];
        let q = ids.joint_qpos[ARM_JOINTS..]
            .iter()
            .map(|&a| data.qpos()[a])
            .sum::<f64>()
            / 3.0;
        let dxy = (pinch[0] - b1[0]).hypot(pinch[1] - b1[1]);
        let dz = pinch[2] - (b1[2] + GRASP_DEPTH);
        let yaw = wrap_half_pi(m1[3].atan2(m1[0]) - rot[(1, 0)].atan2(rot[(0, 0)]));
        let moved = (b1[0] - start[0]).hypot(b1[1] - start[1]);
        let model = env.scene().model();
        let name = |b: usize| {
            let n = model.id_to_name(MjtObjBase::mjOBJ_BODY, b).unwrap_or("?");
            n.trim_start_matches("hand/").to_string()
        };
        let mut touching = Vec::new();
        for c in data.contact() {
            let [a, b] = c.geom.map(|g| model.geom_bodyid()[g as usize] as usize);
            for (x, y) in [(a, b), (b, a)] {
                let tag = if x == ids.brick1_body {
                    "1"
                } else if x == ids.brick2_body {
                    "2"
                } else if x == 0 {
                    "T"
                } else {
                    continue;
                };
                if y != 0 && y != ids.brick1_body && y != ids.brick2_body {
                    let t = format!("{tag}:{}", name(y));
                    if !touching.contains(&t) {
                        touching.push(t);
                    }
                }
            }
        }
        let phase = teacher.phase(&env);
        let label = teacher.act(&env);

        let policy_action =
            physical_to_env_action(&controller_command(&mut mlp, &obs, true, None)?);
        let t = env.steps_taken();
        let action = if args.handover.is_some_and(|h| t >= h) {
            label
        } else {
            policy_action
        };
        let arm = (0..ARM_JOINTS)
            .map(|k| (policy_action[k] - label[k]).powi(2))
            .sum::<f32>()
            .sqrt();
        if (args.from..=args.to).contains(&t) {
            println!(
                "{t:4} {:8} {:+.2?} {:+.2?} {q:.2} {:5.1} {:+5.1} {:4.1} {:+.2} {:5.1} {arm:.2} {}",
                format!("{phase:?}"),
                &label[ARM_JOINTS..],
                &policy_action[ARM_JOINTS..],
                dxy * 1e3,
                dz * 1e3,
                b1[2] * 1e3,
                yaw,
                moved * 1e3,
                touching.join(" "),
            );
        }
        let out = env.step(&action)?;
        obs = out.observation;
        if out.done {
            break out;
        }
    };
    let s = env.reward_state();
    println!(
        "end: success {}, brick1 z {:.3}, pinch-brick1 {:.3}",
        out.success,
        s.brick1_pos[2],
        s.brick1_pos
            .iter()
            .zip(&s.pinch)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt()
    );
    Ok(())
}
