//! Spike (issue #26, session 32): evolution strategies (Salimans et al. 2017) from the states
//! just before a policy's stalls. Every candidate is a noise-free policy (the file's parameters
//! plus a Gaussian perturbation, antithetic pairs), so what the update rewards is what the
//! flashed file does, where session 31's action-noise groups taught an escape the noise-free
//! policy did not continue.
//!
//! ```text
//! cargo run --release -p dex-trainer --example es_spike -- POLICY TRAIN_SEED TRAIN_N HELD_SEED \
//!     HELD_N PAIRS SIGMA LR ITERATIONS BACK L2 THREADS OUT_DIR ANCHOR ANCHOR_EPISODES
//! ```
//!
//! States: `BACK + 1` steps before each detected stall of a stalled failure among the noise-free episodes from
//! `episode_seed(TRAIN_SEED, i)` (training) and `episode_seed(HELD_SEED, i)` (held out), cached in
//! OUT_DIR. Each iteration: PAIRS antithetic perturbations, each run noise-free from every
//! training state to the episode's end; fitness its success rate; gradient `sum_k (F_k - mean F)
//! eps_k / (2 PAIRS SIGMA)`, minus `L2 (theta - theta_0)`, one Adam step of LR. Every 5
//! iterations the centre is run from both sets and exported to OUT_DIR/es-NNNN.dxpl. With a
//! positive ANCHOR, the gradient also holds the actions on the states of ANCHOR_EPISODES noise-free episodes
//! of the file (from `episode_seed(HELD_SEED + 5000, i)`): `ANCHOR / 2 * mean_rows sum_j (mu_j -
//! clone_j)^2 / sigma_j^2`, sigma 0.1 (arm) and 0.05 (fingers), the KL anchor of `trainer pg`.
use anyhow::Context;
use dex_runtime::Mlp;
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, EnvSnapshot, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};
use dex_trainer::files::export::ExportInfo;
use dex_trainer::learn::Rng;
use dex_trainer::learn::adam::{AdamConfig, AdamLocal, AdamShared, adam_step};
use dex_trainer::pipeline::file_actor::FileActor;
use dex_trainer::pipeline::stall_starts::harvest;
use std::path::Path;

type States = Vec<(u64, EnvSnapshot)>;

/// The states `back + 1` steps before the detected stalls of the noise-free episodes of `file`
/// that stall and fail (`stall_starts::harvest`).
fn stalled_states(
    scene: &Scene,
    task: Task,
    file: &[u8],
    seed: u64,
    n: u64,
    back: usize,
    threads: usize,
) -> anyhow::Result<States> {
    let seeds: Vec<u64> = (0..n).map(|i| episode_seed(seed, i)).collect();
    let (found, _) = harvest(file, scene, task, &seeds, back + 1, threads)?;
    Ok(found.into_iter().map(|s| (s.seed, s.snapshot)).collect())
}

/// The network inputs (normalised, clipped) of the CAN-quantised observations of `episodes`
/// noise-free episodes of `file`.
#[allow(clippy::too_many_arguments)]
fn anchor_inputs(
    scene: &Scene,
    task: Task,
    file: &[u8],
    seed: u64,
    episodes: u64,
    threads: usize,
    actor: &FileActor,
) -> anyhow::Result<Vec<f32>> {
    let aligned = dex_runtime::testkit::aligned_copy(file);
    let d = actor.net.input_dim();
    let per = dex_trainer::env::parallel::map_in_order(
        episodes as usize,
        threads,
        || -> anyhow::Result<_> {
            let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
            let mlp = Mlp::<1024>::new(&view)?;
            Ok((mlp, JacoEnv::new(scene, EnvConfig::new(task))))
        },
        |(mlp, env), i| -> anyhow::Result<Vec<f32>> {
            let mut o = env.reset(episode_seed(seed, i as u64))?;
            let mut rows = Vec::new();
            loop {
                let q: [f32; 44] = std::array::from_fn(|k| {
                    dex_runtime::can::messages::quantise_observation(k, o[k])
                });
                let start = rows.len();
                rows.resize(start + d, 0.0);
                actor.input(&q, &mut rows[start..]);
                let act = physical_to_env_action(&controller_command(mlp, &o, true, None)?);
                let out = env.step(&act)?;
                o = out.observation;
                if out.done {
                    return Ok(rows);
                }
            }
        },
        &|| {},
    )?;
    Ok(per.concat())
}

fn cached(path: &Path, make: impl FnOnce() -> anyhow::Result<States>) -> anyhow::Result<States> {
    if let Ok(bytes) = std::fs::read(path) {
        return Ok(postcard::from_bytes(&bytes)?);
    }
    let s = make()?;
    std::fs::write(path, postcard::to_allocvec(&s)?)?;
    Ok(s)
}

/// Successes of each policy from each state: `out[p * states.len() + s]`.
fn run_all(
    scene: &Scene,
    task: Task,
    policies: &[Vec<u8>],
    states: &States,
    threads: usize,
) -> anyhow::Result<Vec<bool>> {
    let aligned: Vec<_> = policies
        .iter()
        .map(|p| dex_runtime::testkit::aligned_copy(p))
        .collect();
    dex_trainer::env::parallel::map_in_order(
        policies.len() * states.len(),
        threads,
        || -> anyhow::Result<_> { Ok(JacoEnv::new(scene, EnvConfig::new(task))) },
        |env, item| -> anyhow::Result<bool> {
            let (p, s) = (item / states.len(), item % states.len());
            let view = dex_trainer::evaluate::decode_jaco_policy(aligned[p].as_bytes())?;
            let mut mlp = Mlp::<1024>::new(&view)?;
            let mut o = env.restore(&states[s].1)?;
            loop {
                let a = physical_to_env_action(&controller_command(&mut mlp, &o, true, None)?);
                let out = env.step(&a)?;
                o = out.observation;
                if out.done {
                    return Ok(out.success);
                }
            }
        },
        &|| {},
    )
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.len() != 15 {
        anyhow::bail!(
            "usage: es_spike POLICY TRAIN_SEED TRAIN_N HELD_SEED HELD_N PAIRS SIGMA LR ITERATIONS BACK L2 THREADS OUT_DIR ANCHOR ANCHOR_EPISODES"
        );
    }
    let anchor: f32 = a[13].parse()?;
    let anchor_episodes: u64 = a[14].parse()?;
    let file = std::fs::read(&a[0]).context("policy")?;
    let (train_seed, train_n, held_seed, held_n): (u64, u64, u64, u64) =
        (a[1].parse()?, a[2].parse()?, a[3].parse()?, a[4].parse()?);
    let pairs: usize = a[5].parse()?;
    let (sigma, lr): (f32, f32) = (a[6].parse()?, a[7].parse()?);
    let iterations: u32 = a[8].parse()?;
    let back: usize = a[9].parse()?;
    let l2: f32 = a[10].parse()?;
    let threads: usize = a[11].parse()?;
    let out = Path::new(&a[12]);
    std::fs::create_dir_all(out)?;
    let aligned = dex_runtime::testkit::aligned_copy(&file);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    let body = view.body();
    let task = Task::from(body.task);
    let actor = FileActor::from_file(&file, task)?;
    let info = ExportInfo::bare(task);
    let export = |p: &[f32]| actor.export_params(p, &info);
    let scene = Scene::load()?;
    let train = cached(&out.join("train.bin"), || {
        stalled_states(&scene, task, &file, train_seed, train_n, back, threads)
    })?;
    let held = cached(&out.join("held.bin"), || {
        stalled_states(&scene, task, &file, held_seed, held_n, back, threads)
    })?;
    println!("{} training states, {} held out", train.len(), held.len());
    let rows = anchor_inputs(
        &scene,
        task,
        &file,
        held_seed + 5000,
        anchor_episodes,
        threads,
        &actor,
    )?;
    let d = actor.net.input_dim();
    let n_rows = rows.len() / d;
    const CHUNK: usize = 1024;
    let mut scratch = actor.net.scratch(CHUNK);
    let mut clone_out = Vec::with_capacity(n_rows * 9);
    for c in rows.chunks(CHUNK * d) {
        clone_out.extend_from_slice(actor.net.forward(
            &actor.clone,
            c,
            c.len() / d,
            &mut scratch,
        )?);
    }
    println!("{n_rows} anchor states");
    let theta0 = actor.clone.clone();
    let mut theta = theta0.clone();
    let n = theta.len();
    let adam = AdamConfig {
        lr,
        ..AdamConfig::default()
    };
    let (mut local, mut shared) = (AdamLocal::new(n), AdamShared::new(n));
    let mut rng = Rng::seed_from_u64(0xe5);
    let t0 = std::time::Instant::now();
    for it in 0..=iterations {
        if it % 5 == 0 {
            let centre = export(&theta)?;
            std::fs::write(out.join(format!("es-{it:04}.dxpl")), &centre)?;
            let tr = run_all(&scene, task, std::slice::from_ref(&centre), &train, threads)?;
            let he = run_all(&scene, task, std::slice::from_ref(&centre), &held, threads)?;
            println!(
                "iteration {it}: centre {}/{} training, {}/{} held out; |theta - theta0| {:.4}; {:.0} s",
                tr.iter().filter(|&&x| x).count(),
                train.len(),
                he.iter().filter(|&&x| x).count(),
                held.len(),
                theta
                    .iter()
                    .zip(&theta0)
                    .map(|(x, y)| (x - y) * (x - y))
                    .sum::<f32>()
                    .sqrt(),
                t0.elapsed().as_secs_f64()
            );
        }
        if it == iterations {
            break;
        }
        let eps: Vec<Vec<f32>> = (0..pairs)
            .map(|_| (0..n).map(|_| rng.normal(0.0, 1.0)).collect())
            .collect();
        let mut policies = Vec::with_capacity(2 * pairs);
        for e in &eps {
            for sign in [1.0f32, -1.0] {
                let p: Vec<f32> = theta
                    .iter()
                    .zip(e)
                    .map(|(t, x)| t + sign * sigma * x)
                    .collect();
                policies.push(export(&p)?);
            }
        }
        let ok = run_all(&scene, task, &policies, &train, threads)?;
        let m = train.len();
        let fit: Vec<f32> = (0..2 * pairs)
            .map(|p| ok[p * m..(p + 1) * m].iter().filter(|&&x| x).count() as f32 / m as f32)
            .collect();
        let mut grad = vec![0.0f32; n];
        for (k, e) in eps.iter().enumerate() {
            let d = fit[2 * k] - fit[2 * k + 1];
            if d != 0.0 {
                for (g, x) in grad.iter_mut().zip(e) {
                    // Adam minimises: the negative of the ascent direction.
                    *g -= d * x / (2.0 * pairs as f32 * sigma);
                }
            }
        }
        for ((g, t), t0) in grad.iter_mut().zip(&theta).zip(&theta0) {
            *g += l2 * (t - t0);
        }
        let mut sq = 0.0f64;
        if anchor > 0.0 && n_rows > 0 {
            let mut part = vec![0.0f32; n];
            for (ci, c) in rows.chunks(CHUNK * d).enumerate() {
                let r = c.len() / d;
                let mu = actor.net.forward(&theta, c, r, &mut scratch)?.to_vec();
                let mut dout = vec![0.0f32; r * 9];
                for i in 0..r {
                    for j in 0..9 {
                        let sd = if j < 6 { 0.1f32 } else { 0.05 };
                        let diff = mu[i * 9 + j] - clone_out[(ci * CHUNK + i) * 9 + j];
                        sq += f64::from(diff / sd).powi(2);
                        dout[i * 9 + j] = anchor * diff / (sd * sd) / n_rows as f32;
                    }
                }
                actor
                    .net
                    .backward(&theta, c, &mut scratch, &dout, Some(&mut part), None)?;
                for (g, p) in grad.iter_mut().zip(&part) {
                    *g += p;
                }
            }
        }
        adam_step(&adam, &mut theta, &grad, &mut local, &mut shared);
        let mean = fit.iter().sum::<f32>() / fit.len() as f32;
        let best = fit.iter().cloned().fold(0.0, f32::max);
        println!(
            "iteration {it}: perturbed fitness mean {mean:.3} best {best:.3}; anchor drift {:.3}",
            (sq / (n_rows.max(1) * 9) as f64).sqrt()
        );
    }
    Ok(())
}
