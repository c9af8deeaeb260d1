//! How the Markov demonstrator fails: over `--episodes` starts from `--seed` (the `env-tool demo
//! --markov` seeds: seed + episode), every failed episode with its phase sequence (phase x steps),
//! where brick 1 ended (height, offset from the stacking site in brick 2's frame, distance to the
//! pinch site) and the finger angles; failures grouped by the last phase. `--trace SEED` prints every
//! step of one episode: phase, the pinch site and the three finger tips in brick 1's frame, the
//! finger angles and brick 1's height.
//!
//! ```text
//! cargo run --release -p dex-env --example markov_failures -- --task stack [--episodes 1000] \
//!     [--seed 0] [--threads 2] [--trace SEED] [--seeds 3,17,42] [--tuck-first] [--tuck-ramp]
//! ```

use std::collections::BTreeMap;

use dex_env::kinematics::{pinch_pose, xmat_rotation};
use dex_env::scene::ARM_JOINTS;
use dex_env::{EnvConfig, JacoEnv, MarkovDemonstrator, MarkovPhase, Scene, Task};
use mujoco_rs::prelude::*;
use nalgebra::Vector3;

/// Fingertip: this far along the distal phalanx's x axis from its body origin (mesh extent 0.044).
const TIP: f64 = 0.04;

type BoxError = Box<dyn std::error::Error + Send + Sync>;

fn flag<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> Result<T, BoxError>
where
    T::Err: std::fmt::Display,
{
    match args.iter().position(|a| a == name) {
        None => Ok(default),
        Some(i) => {
            let v = args.get(i + 1).ok_or(format!("{name} needs a value"))?;
            v.parse()
                .map_err(|e: T::Err| format!("{name} {v}: {e}").into())
        }
    }
}

struct Failure {
    seed: u64,
    phases: Vec<(MarkovPhase, u32)>,
    line: String,
}

fn main() -> Result<(), BoxError> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let task: Task = flag(args.as_slice(), "--task", Task::Stack)?;
    let episodes: u64 = flag(&args, "--episodes", 200)?;
    let seed: u64 = flag(&args, "--seed", 0)?;
    let threads: u64 = flag(&args, "--threads", 2)?;
    // The demonstrator with `MarkovDemonstrator::with_tuck_first`.
    let tuck_first = args.iter().any(|a| a == "--tuck-first");
    // The demonstrator with `MarkovDemonstrator::with_tuck_ramp`.
    let tuck_ramp = args.iter().any(|a| a == "--tuck-ramp");
    let switches = (tuck_first, tuck_ramp);
    let trace: Option<u64> =
        flag(&args, "--trace", u64::MAX).map(|t| (t != u64::MAX).then_some(t))?;
    let scene = Scene::load()?;
    if let Some(s) = trace {
        return trace_episode(&scene, task, s, switches);
    }
    let list: Vec<u64> = flag(&args, "--seeds", String::new())?
        .split(',')
        .filter(|x| !x.is_empty())
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    let (seed, episodes) = if list.is_empty() {
        (seed, episodes)
    } else {
        (0, list.len() as u64)
    };
    let list = &list;
    let start = std::time::Instant::now();
    let threads = threads.clamp(1, 16);
    let results: Vec<Result<(u64, Vec<Failure>), BoxError>> = std::thread::scope(|sc| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                let scene = &scene;
                sc.spawn(move || {
                    let seeds = (0..episodes)
                        .filter(|e| e % threads == t)
                        .map(|e| list.get(e as usize).copied().unwrap_or(seed + e));
                    run(scene, task, seeds, switches)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err("worker panicked".into())))
            .collect()
    });
    let mut successes = 0;
    let mut failures = Vec::new();
    for r in results {
        let (s, f) = r?;
        successes += s;
        failures.extend(f);
    }
    failures.sort_by_key(|f| f.seed);
    let mut groups = BTreeMap::<String, u32>::new();
    for f in &failures {
        let seq: Vec<String> = f.phases.iter().map(|(p, n)| format!("{p:?}x{n}")).collect();
        println!("seed {}: {} | {}", f.seed, f.line, seq.join(" "));
        let last = f
            .phases
            .last()
            .map(|p| format!("{:?}", p.0))
            .unwrap_or_default();
        *groups.entry(last).or_default() += 1;
    }
    println!(
        "task {task:?} (Markov demonstrator): {successes}/{episodes} successes ({:.1}%), seeds {seed}-{}, {:.1} s",
        100.0 * successes as f64 / episodes as f64,
        seed + episodes - 1,
        start.elapsed().as_secs_f64()
    );
    for (g, n) in groups {
        println!("  {n:4} failed in {g}");
    }
    Ok(())
}

fn run(
    scene: &Scene,
    task: Task,
    seeds: impl Iterator<Item = u64>,
    (tuck_first, tuck_ramp): (bool, bool),
) -> Result<(u64, Vec<Failure>), BoxError> {
    let mut env = JacoEnv::new(scene, EnvConfig::new(task));
    let demo = MarkovDemonstrator::new(task)
        .with_tuck_first(tuck_first)
        .with_tuck_ramp(tuck_ramp);
    let mut successes = 0;
    let mut failures = Vec::new();
    for seed in seeds {
        env.reset(seed)?;
        let mut phases: Vec<(MarkovPhase, u32)> = Vec::new();
        let mut max_z = 0.0f64;
        loop {
            let p = demo.phase(&env);
            match phases.last_mut() {
                Some((q, n)) if *q == p => *n += 1,
                _ => phases.push((p, 1)),
            }
            let out = env.step(&demo.act(&env))?;
            let s = env.reward_state();
            max_z = max_z.max(s.brick1_pos[2]);
            if out.done {
                if out.success {
                    successes += 1;
                } else {
                    let d = (Vector3::from(s.brick1_pos) - Vector3::from(s.pinch)).norm();
                    let line = format!(
                        "max z {max_z:.3} end z {:.3} stack offset {:+.3?} pinch dist {d:.3} fingers {:.2?} end phase {:?}",
                        s.brick1_pos[2],
                        s.stack_offset(),
                        fingers(&env),
                        demo.phase(&env)
                    );
                    failures.push(Failure { seed, phases, line });
                }
                break;
            }
        }
    }
    Ok((successes, failures))
}

fn fingers(env: &JacoEnv) -> [f64; 3] {
    let ids = env.scene().ids();
    core::array::from_fn(|k| {
        env.data()
            .qpos()
            .get(ids.joint_qpos[ARM_JOINTS + k])
            .copied()
            .unwrap_or(0.0)
    })
}

/// A point in brick 1's frame.
fn in_brick1(env: &JacoEnv, p: [f64; 3]) -> [f64; 3] {
    let ids = env.scene().ids();
    let b = env.data().xpos()[ids.brick1_body];
    let m = xmat_rotation(&env.data().xmat()[ids.brick1_body]);
    let v = m.inverse() * (Vector3::from(p) - Vector3::from(b));
    v.into()
}

fn trace_episode(
    scene: &Scene,
    task: Task,
    seed: u64,
    (tuck_first, tuck_ramp): (bool, bool),
) -> Result<(), BoxError> {
    let mut env = JacoEnv::new(scene, EnvConfig::new(task));
    let demo = MarkovDemonstrator::new(task)
        .with_tuck_first(tuck_first)
        .with_tuck_ramp(tuck_ramp);
    env.reset(seed)?;
    let tips: Vec<usize> = (1..=3)
        .map(|k| {
            scene
                .model()
                .name_to_id(MjtObjBase::mjOBJ_BODY, &format!("hand/b_finger_tip_{k}"))
                .ok_or("no finger tip body")
        })
        .collect::<Result<_, _>>()?;
    loop {
        let ids = scene.ids();
        let (pinch, _) = pinch_pose(env.data(), ids);
        let p = demo.phase(&env);
        let a = demo.act(&env);
        let tip_rel: Vec<String> = tips
            .iter()
            .map(|&b| {
                let m = xmat_rotation(&env.data().xmat()[b]);
                let tip = Vector3::from(env.data().xpos()[b]) + m * Vector3::new(TIP, 0.0, 0.0);
                let t = in_brick1(&env, tip.into());
                format!("[{:+.3} {:+.3} {:+.3}]", t[0], t[1], t[2])
            })
            .collect();
        let s = env.reward_state();
        let m1 = env.data().xmat()[ids.brick1_body];
        let m2 = env.data().xmat()[ids.brick2_body];
        let rel_yaw = wrap_half_pi(m1[3].atan2(m1[0]) - m2[3].atan2(m2[0]));
        let pr = in_brick1(&env, pinch.into());
        println!(
            "t {:3} {:8} pinch@b1 [{:+.3} {:+.3} {:+.3}] tips@b1 {} q {:.2?} b1z {:.3} tilt {:.3} relyaw {:+.2} off {:+.3?} fa {:+.2?}",
            env.steps_taken(),
            format!("{p:?}"),
            pr[0],
            pr[1],
            pr[2],
            tip_rel.join(" "),
            fingers(&env),
            s.brick1_pos[2],
            m1[8].clamp(-1.0, 1.0).acos(),
            rel_yaw,
            s.stack_offset(),
            &a[ARM_JOINTS..]
        );
        let out = env.step(&a)?;
        if out.done {
            println!("success {}", out.success);
            return Ok(());
        }
    }
}

/// An angle difference wrapped into (-pi/2, pi/2] (a brick looks the same turned by pi).
fn wrap_half_pi(a: f64) -> f64 {
    use std::f64::consts::PI;
    let a = a.rem_euclid(PI);
    if a > PI / 2.0 { a - PI } else { a }
}
