//! Spike (issue #26, session 32): do perturbations of a policy's parameters, run noise-free, escape
//! the stall before the grasp where the file's own noise-free episodes fail? Session 31 found that
//! action noise escapes (a quarter of continuations) but that what a gradient step on action-noise
//! episodes teaches does not survive without the noise. A perturbation of the parameters is a
//! noise-free policy: if some escape, an evolution-strategies step (Salimans et al. 2017) has a
//! signal on exactly the quantity that is flashed.
//!
//! ```text
//! cargo run --release -p dex-trainer --example param_noise_spike -- POLICY SEED EPISODES \
//!     PERTURBATIONS SIGMA BACK THREADS [tuck-first]
//! ```
//!
//! Noise-free episodes from `episode_seed(SEED, i)`; for each one that stalls and fails, the
//! state BACK + 1 steps before the stall was detected and the stalled state itself; from both, the
//! Markov teacher (with `tuck-first`: the teacher that holds the hand up until a finger over brick
//! 2 is tucked), and PERTURBATIONS copies of the file with N(0, SIGMA^2) added to every
//! parameter (of the network in its normalised coordinates), each run noise-free to the end. At
//! both states it first prints the teacher's phase and label beside the file's action, and the
//! MuJoCo contacts (as body pairs).
use anyhow::Context;
use dex_runtime::Mlp;
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, EnvSnapshot, JacoEnv, MarkovDemonstrator, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};
use dex_trainer::files::export::ExportInfo;
use dex_trainer::learn::Rng;
use dex_trainer::pipeline::file_actor::FileActor;
use dex_trainer::pipeline::stall_starts::StallWatch;

fn run_from(
    env: &mut JacoEnv,
    snap: &EnvSnapshot,
    policy: Option<&[u8]>,
    teacher: MarkovDemonstrator,
) -> anyhow::Result<bool> {
    let mut o = env.restore(snap)?;
    let aligned = policy.map(dex_runtime::testkit::aligned_copy);
    let view = match &aligned {
        Some(a) => Some(dex_trainer::evaluate::decode_jaco_policy(a.as_bytes())?),
        None => None,
    };
    let mut mlp = match &view {
        Some(v) => Some(Mlp::<1024>::new(v)?),
        None => None,
    };
    loop {
        let a = match mlp.as_mut() {
            Some(m) => physical_to_env_action(&controller_command(m, &o, true, None)?),
            None => teacher.act(env),
        };
        let out = env.step(&a)?;
        o = out.observation;
        if out.done {
            return Ok(out.success);
        }
    }
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if !(7..=8).contains(&a.len()) || a.get(7).is_some_and(|t| t != "tuck-first") {
        anyhow::bail!(
            "usage: param_noise_spike POLICY SEED EPISODES PERTURBATIONS SIGMA BACK THREADS [tuck-first]"
        );
    }
    let tuck_first = a.len() == 8;
    let file = std::fs::read(&a[0]).context("policy")?;
    let (seed, n, k): (u64, u64, usize) = (a[1].parse()?, a[2].parse()?, a[3].parse()?);
    let sigma: f32 = a[4].parse()?;
    let (back, threads): (usize, usize) = (a[5].parse()?, a[6].parse()?);
    let aligned = dex_runtime::testkit::aligned_copy(&file);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    let body = view.body();
    let task = Task::from(body.task);
    let teacher = MarkovDemonstrator::new(task).with_tuck_first(tuck_first);
    let actor = FileActor::from_file(&file, task)?;
    let scene = Scene::load()?;
    // 1. Stalled failures, with the state `back` steps earlier.
    let found = dex_trainer::env::parallel::map_in_order(
        n as usize,
        threads,
        || -> anyhow::Result<_> {
            let mlp = Mlp::<1024>::new(&view)?;
            Ok((mlp, JacoEnv::new(&scene, EnvConfig::new(task))))
        },
        |(mlp, env), i| -> anyhow::Result<Option<(u64, EnvSnapshot, EnvSnapshot, u32)>> {
            let mut o = env.reset(episode_seed(seed, i as u64))?;
            let mut watch = StallWatch::new(back + 1);
            let mut stall = None;
            loop {
                let act = physical_to_env_action(&controller_command(mlp, &o, true, None)?);
                watch.before_step(env);
                let out = env.step(&act)?;
                if watch.after_step(env, &out) {
                    stall = Some((env.snapshot(), env.steps_taken()));
                }
                o = out.observation;
                if out.done {
                    let before = watch.into_found();
                    return Ok(stall
                        .zip(before)
                        .filter(|_| !out.success)
                        .map(|((s, t), b)| (i as u64, b, s, t)));
                }
            }
        },
        &|| {},
    )?;
    let stalls: Vec<_> = found.into_iter().flatten().collect();
    println!("{n} starts: {} stalled failures", stalls.len());
    {
        let mut env = JacoEnv::new(&scene, EnvConfig::new(task));
        let mut mlp = Mlp::<1024>::new(&view)?;
        for (i, b, st, t) in &stalls {
            for (name, snap) in [("before", b), ("stall", st)] {
                let o = env.restore(snap)?;
                let mine = physical_to_env_action(&controller_command(&mut mlp, &o, true, None)?);
                let theirs = teacher.act(&env);
                let s = env.reward_state();
                let rel: Vec<String> = (0..3)
                    .map(|k| format!("{:+.3}", s.pinch[k] - s.brick1_pos[k]))
                    .collect();
                let f = |v: &[f32]| {
                    v.iter()
                        .map(|x| format!("{x:+.2}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                };
                let body_of = |g: i32| env.body_name_of_geom(g).unwrap_or("?").to_owned();
                let touching: Vec<String> = env
                    .data()
                    .contact()
                    .iter()
                    .map(|c| format!("{}|{}", body_of(c.geom[0]), body_of(c.geom[1])))
                    .collect();
                println!("  contacts: {}", touching.join(", "));
                println!(
                    "start {i} (stall t {t}) {name}: phase {:?}; pinch-brick1 [{}]; fingers {}; policy [{}]; teacher [{}]",
                    teacher.phase(&env),
                    rel.join(" "),
                    f(&o[12..15]),
                    f(&mine),
                    f(&theirs)
                );
            }
        }
    }
    // 2. The perturbed files.
    let mut rng = Rng::seed_from_u64(0x5e5);
    let files: Vec<Vec<u8>> = (0..k)
        .map(|_| {
            let p: Vec<f32> = actor
                .params
                .iter()
                .map(|&x| x + rng.normal(0.0, sigma))
                .collect();
            let info = ExportInfo::bare(task);
            actor.export_params(&p, &info)
        })
        .collect::<Result<_, _>>()?;
    // 3. Teacher (item j = 0) and perturbations (j >= 1), from both states of every stall.
    let per = k + 1;
    let results = dex_trainer::env::parallel::map_in_order(
        stalls.len() * per * 2,
        threads,
        || -> anyhow::Result<_> { Ok(JacoEnv::new(&scene, EnvConfig::new(task))) },
        |env, item| -> anyhow::Result<bool> {
            let (s, rest) = (item / (per * 2), item % (per * 2));
            let (j, from_stall) = (rest / 2, rest % 2 == 1);
            let (_, b, st, _) = &stalls[s];
            let snap = if from_stall { st } else { b };
            let policy = (j > 0).then(|| files[j - 1].as_slice());
            run_from(env, snap, policy, teacher)
        },
        &|| {},
    )?;
    let mut totals = [0u32; 4];
    for (s, (i, _, _, t)) in stalls.iter().enumerate() {
        let r = &results[s * per * 2..(s + 1) * per * 2];
        let teacher = (r[0], r[1]);
        let before: u32 = (1..per).map(|j| u32::from(r[2 * j])).sum();
        let at: u32 = (1..per).map(|j| u32::from(r[2 * j + 1])).sum();
        println!(
            "start {i}: stall at t {t}; teacher before {} at {}; perturbed before {before}/{k} at {at}/{k}",
            teacher.0, teacher.1
        );
        totals[0] += u32::from(teacher.0);
        totals[1] += u32::from(teacher.1);
        totals[2] += before;
        totals[3] += at;
    }
    let m = stalls.len();
    println!(
        "teacher: {}/{m} from {back} steps before, {}/{m} from the stall; perturbed (sigma {sigma}): {}/{} before, {}/{} at",
        totals[0],
        totals[1],
        totals[2],
        m * k,
        totals[3],
        m * k
    );
    Ok(())
}
