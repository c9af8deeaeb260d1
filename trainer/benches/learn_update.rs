//! Updates per second of one DDPG update for the paper's network sizes, both GEMM engines side by side.
//!
//! `cargo bench -p dex-trainer --bench learn_update [-- ROUNDS SECONDS [HIDDEN]]` (defaults 5 rounds
//! of 1 s, hidden layers 256-256; `HIDDEN` = 128 gives the 128-128 networks of the paper-protocol
//! runs in experiments/paper/).
//! Rounds interleave engines and batch sizes; the best round of each is reported (other load on the
//! machine only ever slows a round down). Two figures per configuration:
//! - `kernel`: the bare update (target actor + target critic forward, critic forward/backward + Adam,
//!   actor forward, critic forward/backward into the actor, actor backward + Adam, Polyak target update),
//!   the same work as the PyTorch side by side measures (`scripts/bench-torch.py`, docs/benchmarks.md);
//! - `trainer`: [`Trainer::run`] with one worker, R = 40 updates per step on a free environment, so it
//!   adds replay sampling, the shared-parameter locking and copies, and acting.
//!
//! Then total updates/s of ADPG-R with W = 1 and W = 2 workers (gemm, batch 64), same environment.

use dex_trainer::learn::adam::{AdamLocal, AdamShared, adam_step};
use dex_trainer::learn::ddpg::{ActorLoss, UpdateBuffers, actor_gradient, critic_gradient};
use dex_trainer::learn::{
    AdamConfig, DdpgConfig, Engine, Env, EvalConfig, Networks, ReplayConfig, Rng, RunConfig, Step,
    TargetUpdate, Trainer,
};
use std::hint::black_box;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

const OBS: usize = 44;
const ACT: usize = 9;

/// An environment that costs nothing: random observations, 10-step episodes (short run chunks).
struct Free {
    rng: Rng,
    t: usize,
}

impl Env for Free {
    fn obs_dim(&self) -> usize {
        OBS
    }
    fn act_dim(&self) -> usize {
        ACT
    }
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        self.t = 0;
        obs.iter_mut().for_each(|o| *o = rng.uniform(-1.0, 1.0));
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Step {
        self.t += 1;
        obs.iter_mut()
            .for_each(|o| *o = self.rng.uniform(-1.0, 1.0));
        Step {
            reward: action[0],
            terminal: false,
            truncated: self.t >= 10,
            success: false,
        }
    }
}

/// Hidden width of both networks (two layers), from the command line.
static HIDDEN: std::sync::OnceLock<usize> = std::sync::OnceLock::new();

fn ddpg(engine: Engine, batch: usize) -> DdpgConfig {
    let h = *HIDDEN.get().unwrap_or(&256);
    DdpgConfig {
        actor_hidden: vec![h, h],
        critic_hidden: vec![h, h],
        batch_size: batch,
        engine,
        target: TargetUpdate::Polyak { tau: 0.005 },
        ..DdpgConfig::default()
    }
}

fn kernel_rate(engine: Engine, batch: usize, seconds: f64) -> f64 {
    let cfg = ddpg(engine, batch);
    let Ok(nets) = Networks::new(&cfg, OBS, ACT) else {
        return 0.0;
    };
    let mut rng = Rng::seed_from_u64(1);
    let mut actor = nets.actor.init_params(&mut rng, 3e-3);
    let mut critic = nets.critic.init_params(&mut rng, 3e-3);
    let mut t_actor = actor.clone();
    let mut t_critic = critic.clone();
    let (mut am, mut cm) = (AdamLocal::new(actor.len()), AdamLocal::new(critic.len()));
    let (mut av, mut cv) = (AdamShared::new(actor.len()), AdamShared::new(critic.len()));
    let mut bufs = UpdateBuffers::new(&nets, batch);
    let b = &mut bufs.batch;
    b.len = batch;
    for v in b
        .obs
        .iter_mut()
        .chain(b.next_obs.iter_mut())
        .chain(b.act.iter_mut())
    {
        *v = rng.uniform(-1.0, 1.0);
    }
    b.reward.iter_mut().for_each(|r| *r = rng.uniform(0.0, 1.0));
    b.not_done.fill(1.0);
    let adam = AdamConfig::default();
    let start = Instant::now();
    let mut n = 0u64;
    while start.elapsed().as_secs_f64() < seconds {
        let loss = critic_gradient(&nets, 0.99, &critic, &t_actor, &t_critic, &mut bufs);
        black_box(loss.ok());
        adam_step(&adam, &mut critic, &bufs.critic_grads, &mut cm, &mut cv);
        black_box(actor_gradient(&nets, &actor, &critic, &ActorLoss::default(), &mut bufs).ok());
        adam_step(&adam, &mut actor, &bufs.actor_grads, &mut am, &mut av);
        n += 1;
        cfg.target.apply(n, &actor, &mut t_actor);
        cfg.target.apply(n, &critic, &mut t_critic);
    }
    n as f64 / start.elapsed().as_secs_f64()
}

fn trainer_rate(engine: Engine, batch: usize, seconds: f64, workers: usize) -> f64 {
    let cfg = RunConfig {
        ddpg: ddpg(engine, batch),
        updates_per_step: 40,
        workers,
        learning_starts: 300,
        replay: ReplayConfig {
            capacity: 100_000,
            shared: true,
        },
        eval: EvalConfig {
            every_episodes: 0,
            ..EvalConfig::default()
        },
        ..RunConfig::default()
    };
    let Ok(mut t) = Trainer::new(cfg, OBS, ACT) else {
        return 0.0;
    };
    let stop = AtomicBool::new(false);
    let env = |w: usize| Free {
        rng: Rng::seed_from_u64(w as u64),
        t: 0,
    };
    // Warm up (fills the buffer past learning_starts), then time whole episodes.
    if t.run(env, 300, &stop, &mut |_| {}).is_err() {
        return 0.0;
    }
    let start = Instant::now();
    let u0 = t.progress().updates;
    let mut until = t.progress().transitions;
    while start.elapsed().as_secs_f64() < seconds {
        until += 10 * workers as u64;
        if t.run(env, until, &stop, &mut |_| {}).is_err() {
            return 0.0;
        }
    }
    (t.progress().updates - u0) as f64 / start.elapsed().as_secs_f64()
}

fn main() {
    let args: Vec<String> = std::env::args()
        .skip(1)
        .filter(|a| !a.starts_with('-'))
        .collect();
    let rounds: usize = args.first().and_then(|a| a.parse().ok()).unwrap_or(5);
    let seconds: f64 = args.get(1).and_then(|a| a.parse().ok()).unwrap_or(1.0);
    let hidden: usize = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(256);
    let _ = HIDDEN.set(hidden);
    println!("hidden layers {hidden}-{hidden}");
    let engines = [Engine::Gemm, Engine::MatrixMultiply];
    let batches = [64usize, 256];
    let mut best = vec![[0.0f64; 2]; engines.len() * batches.len()];
    for round in 0..rounds {
        for (ei, &e) in engines.iter().enumerate() {
            for (bi, &b) in batches.iter().enumerate() {
                let k = kernel_rate(e, b, seconds);
                let t = trainer_rate(e, b, seconds, 1);
                let slot = &mut best[ei * batches.len() + bi];
                slot[0] = slot[0].max(k);
                slot[1] = slot[1].max(t);
                eprintln!("round {round} {e:?} batch {b}: kernel {k:.0}/s trainer {t:.0}/s");
            }
        }
    }
    let mut w2 = [0.0f64; 2];
    for round in 0..rounds {
        for (i, w) in [1usize, 2].into_iter().enumerate() {
            let r = trainer_rate(Engine::Gemm, 64, seconds, w);
            w2[i] = w2[i].max(r);
            eprintln!("round {round} Gemm batch 64 trainer W={w}: {r:.0}/s");
        }
    }
    println!("| engine | batch | kernel updates/s | trainer updates/s (R=40, W=1) |");
    println!("|---|---|---|---|");
    for (ei, e) in engines.iter().enumerate() {
        for (bi, b) in batches.iter().enumerate() {
            let [k, t] = best[ei * batches.len() + bi];
            println!("| {e:?} | {b} | {k:.0} | {t:.0} |");
        }
    }
    println!(
        "ADPG-R, Gemm, batch 64, R=40, free env: W=1 {:.0} updates/s, W=2 {:.0} updates/s ({:.2}x)",
        w2[0],
        w2[1],
        w2[1] / w2[0].max(1e-9)
    );
}
