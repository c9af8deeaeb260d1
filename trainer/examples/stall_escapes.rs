//! Where a policy's noise-free episodes stall before the grasp (`pipeline::stall_starts`), and
//! how often noisy continuations from the stalled state succeed (issue #26, session 31): the
//! signal a group of episodes from a stall gives `trainer pg --stall-groups`.
//!
//! ```text
//! cargo run --release -p dex-trainer --example stall_escapes -- POLICY SEED EPISODES REPLICATES \
//!     ARM_NOISE FINGER_NOISE
//! ```
//!
//! Starts `episode_seed(SEED, i)`, i < EPISODES, through the runtime with CAN quantisation; prints
//! each stalled start and its escapes, then the totals (stalled failures, failures without a
//! stall, stalls that still succeeded).
use anyhow::Context;
use dex_runtime::Mlp;
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};
use dex_trainer::learn::Rng;
use dex_trainer::pipeline::stall_starts::StallDetector;

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() != 6 {
        anyhow::bail!(
            "usage: stall_escapes POLICY SEED EPISODES REPLICATES ARM_NOISE FINGER_NOISE"
        );
    }
    let bytes = std::fs::read(&a[0]).context("policy")?;
    let (seed, n, reps): (u64, u64, u32) = (a[1].parse()?, a[2].parse()?, a[3].parse()?);
    let (arm_noise, finger_noise): (f32, f32) = (a[4].parse()?, a[5].parse()?);
    let aligned = dex_runtime::testkit::aligned_copy(&bytes);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    let task = Task::from(view.body().task);
    let mut mlp = Mlp::<1024>::new(&view)?;
    let scene = Scene::load()?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(task));
    let mut rng = Rng::seed_from_u64(12345);
    let (mut stalled_fail, mut stalled_ok, mut fail_free, mut escapes, mut tries) = (0, 0, 0, 0, 0);
    for i in 0..n {
        let mut obs = env.reset(episode_seed(seed, i))?;
        let mut detector = StallDetector::new();
        let mut stall = None;
        let success = loop {
            let action = physical_to_env_action(&controller_command(&mut mlp, &obs, true, None)?);
            let out = env.step(&action)?;
            if detector.observe(&env, &out) {
                stall = Some((env.snapshot(), env.steps_taken()));
            }
            obs = out.observation;
            if out.done {
                break out.success;
            }
        };
        match (&stall, success) {
            (None, false) => fail_free += 1,
            (Some(_), true) => stalled_ok += 1,
            _ => {}
        }
        let Some((snap, t)) = stall else {
            continue;
        };
        if success {
            println!("start {i}: stall detected at t {t} but succeeded");
            continue;
        }
        stalled_fail += 1;
        let mut ok = 0;
        for _ in 0..reps {
            let mut o = env.restore(&snap)?;
            let s = loop {
                let mut act =
                    physical_to_env_action(&controller_command(&mut mlp, &o, true, None)?);
                for (k, x) in act.iter_mut().enumerate() {
                    let sd = if k < 6 { arm_noise } else { finger_noise };
                    *x = (*x + rng.normal(0.0, sd)).clamp(-1.0, 1.0);
                }
                let out = env.step(&act)?;
                o = out.observation;
                if out.done {
                    break out.success;
                }
            };
            ok += u32::from(s);
        }
        escapes += ok;
        tries += reps;
        println!("start {i}: stall at t {t}, {ok}/{reps} noisy continuations succeed");
    }
    println!(
        "{n} starts: {stalled_fail} failed after a stall, {fail_free} failed without one, {stalled_ok} stalls that succeeded; escapes {escapes}/{tries}"
    );
    Ok(())
}
