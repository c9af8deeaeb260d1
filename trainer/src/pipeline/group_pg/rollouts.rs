//! The noisy episodes of an iteration, and what the run remembers of them (hard starts, stalls).

use dex_runtime::Mlp as RuntimeMlp;
use dex_runtime::can::messages::quantise_observation;
use dex_runtime::interface::{ACT_DIM, OBS_DIM};

use crate::env::{EnvConfig, JacoEnv, Scene, Task};
use crate::evaluate::{EVAL_WIDTH, EvalError, controller_command, physical_to_env_action};
use crate::learn::Rng;
use crate::pipeline::stall_starts::{StallStart, StallWatch};

use super::{GroupPg, GroupPgError, STALL_POOL};

/// One noisy episode: the observations the controller saw (CAN-quantised) and the noise added to
/// the action at each noisy step, the steps it ran, the outcome, and (from a start seed) the
/// state where it stalled before failing.
pub(super) struct Episode {
    pub(super) obs: Vec<[f32; OBS_DIM]>,
    pub(super) noise: Vec<[f32; ACT_DIM]>,
    pub(super) steps: u64,
    pub(super) success: bool,
    /// Whether the robot touched brick 2 before it first grasped brick 1.
    pub(super) touched: bool,
    /// The nearest a fingertip came to brick 2 before the grasp, metres (measured only with a
    /// [`GroupPg::contact_margin`]; infinite otherwise).
    pub(super) clearance: f32,
    pub(super) stall: Option<StallStart>,
}

/// Where a group's episodes begin.
pub(super) enum Start<'a> {
    /// A start seed and the noise stream tag of its episodes.
    Seed(u64, u64),
    /// A start seed whose start is drawn with the bricks close
    /// ([`GroupPg::close_spacing`]), and the noise stream tag of its episodes.
    Close(u64, u64),
    /// A start seed the starting file fails without noise ([`GroupPg::failed_starts`]), and
    /// the noise stream tag of its episodes.
    Failed(u64, u64),
    /// A stalled state and the noise stream tag of its episodes.
    Stall(&'a StallStart, u64),
}

/// Starts kept for revisits.
pub(super) const HARD_STARTS: usize = 256;

/// Updates the hard starts after an iteration: a start whose group failed at least once is kept
/// (the most recent [`HARD_STARTS`]), one whose group succeeded every time is dropped.
pub(super) fn remember_hard(
    hard: &mut Vec<u64>,
    starts: &[u64],
    episodes: &[Episode],
    reps: usize,
) {
    for (seed, group) in starts.iter().zip(episodes.chunks(reps)) {
        hard.retain(|h| h != seed);
        if group.iter().any(|e| !e.success) {
            hard.push(*seed);
        }
    }
    if hard.len() > HARD_STARTS {
        let extra = hard.len() - HARD_STARTS;
        hard.drain(..extra);
    }
}

/// Adds newly found stalls to the pool, keeping the newest [`STALL_POOL`].
///
/// A stall of a start seed at a step the pool already holds is not added: with revisits a start
/// can stall again at the same step, and the stall groups' noise streams are named by the seed,
/// the step and the iteration, so two such entries picked in one iteration would draw the same
/// noise.
pub(super) fn remember_stalls(pool: &mut Vec<StallStart>, found: Vec<StallStart>) {
    for f in found {
        let same = |p: &StallStart| p.seed == f.seed && p.snapshot.steps() == f.snapshot.steps();
        if !pool.iter().any(same) {
            pool.push(f);
        }
    }
    if pool.len() > STALL_POOL {
        let extra = pool.len() - STALL_POOL;
        pool.drain(..extra);
    }
}

/// The noisy episodes of `policy`, `replicates` from each start, in (start, replicate) order;
/// episode `k` of a start draws its noise from the stream `tag + k` of the start's seed.
pub(super) fn rollouts(
    s: &GroupPg,
    scene: &Scene,
    task: Task,
    policy: &[u8],
    starts: &[Start<'_>],
    threads: usize,
) -> Result<Vec<Episode>, GroupPgError> {
    let aligned = dex_runtime::aligned::aligned_copy(policy);
    let reps = s.replicates as usize;
    crate::env::parallel::map_in_order(
        starts.len() * reps,
        threads,
        || -> Result<_, GroupPgError> {
            let view = crate::evaluate::decode_jaco_policy(aligned.as_bytes())?;
            let mlp = RuntimeMlp::<EVAL_WIDTH>::new(&view).map_err(EvalError::from)?;
            Ok((mlp, JacoEnv::new(scene, EnvConfig::new(task))))
        },
        |(mlp, env), i| {
            let k = (i % reps) as u64;
            // The state the episode starts from, the seed that names its noise streams, and
            // what it does besides its noisy steps.
            let (o, noise_seed, origin) = match &starts[i / reps] {
                Start::Seed(seed, tag) => (env.reset(*seed), (*seed, tag), Origin::Seed(*seed)),
                Start::Close(seed, tag) => (
                    env.reset_close(*seed, f64::from(s.close_spacing)),
                    (*seed, tag),
                    Origin::Window(s.close_noise_steps),
                ),
                Start::Failed(seed, tag) => (
                    env.reset(*seed),
                    (*seed, tag),
                    Origin::Window(s.failed_noise_steps),
                ),
                Start::Stall(stall, tag) => (
                    env.restore(&stall.snapshot),
                    (stall.seed, tag),
                    Origin::Window(s.stall_noise_steps),
                ),
            };
            let o = o.map_err(EvalError::from)?;
            let mut rng = Rng::derive(noise_seed.0, noise_seed.1 + k);
            episode(s, env, mlp, o, origin, &mut rng)
        },
        &|| {},
    )
}

/// Where an episode began, for what it does besides its noisy steps.
#[derive(Clone, Copy)]
pub(super) enum Origin {
    /// A start seed: every step carries noise, and the episode watches for the stall that feeds
    /// the pool.
    Seed(u64),
    /// A close start, a failed start or a stalled state: not watched; only the first steps
    /// carry noise (the group kind's `*_noise_steps`: [`GroupPg::close_noise_steps`],
    /// [`GroupPg::failed_noise_steps`], [`GroupPg::stall_noise_steps`]; 0: every step).
    Window(u32),
}

/// One noisy episode from the environment's current state `o` to the task's last step. From a
/// start seed it also watches for the stall; from a stalled state only its first
/// [`GroupPg::stall_noise_steps`] steps carry noise (all of them when that is 0), from a close
/// start only its first [`GroupPg::close_noise_steps`], from a failed start its first
/// [`GroupPg::failed_noise_steps`], and only those are kept for the update.
pub(super) fn episode(
    s: &GroupPg,
    env: &mut JacoEnv,
    mlp: &mut RuntimeMlp<'_, EVAL_WIDTH>,
    mut o: [f32; OBS_DIM],
    origin: Origin,
    rng: &mut Rng,
) -> Result<Episode, GroupPgError> {
    let (mut obs, mut noise) = (Vec::with_capacity(160), Vec::with_capacity(160));
    // Only the start-seed episodes feed the pool.
    let (seed, window) = match origin {
        Origin::Seed(seed) => (Some(seed), 0),
        Origin::Window(n) => (None, n),
    };
    let watching = seed.is_some() && s.stall_groups > 0;
    let mut watch = StallWatch::new(s.stall_back as usize);
    let noisy_steps = match window {
        0 => u64::MAX,
        n => u64::from(n),
    };
    let mut steps = 0u64;
    let (mut grasped, mut touched) = (false, false);
    let mut clearance = f32::INFINITY;
    let mut drift = s.exploration_noise(rng);
    loop {
        let mut a = physical_to_env_action(&controller_command(mlp, &o, true, None)?);
        if steps < noisy_steps {
            let mut e = [0.0f32; ACT_DIM];
            drift.draw(rng, &mut e);
            for (x, n) in a.iter_mut().zip(&e) {
                *x = (*x + n).clamp(-1.0, 1.0);
            }
            obs.push(std::array::from_fn(|i| quantise_observation(i, o[i])));
            noise.push(e);
        }
        steps += 1;
        if watching {
            watch.before_step(env);
        }
        let out = env.step(&a).map_err(EvalError::from)?;
        if watching {
            watch.after_step(env, &out);
        }
        grasped |= out.predicates.grasp;
        touched = touched || (!grasped && env.robot_touches_brick2());
        if !grasped && s.contact_margin > 0.0 {
            clearance =
                clearance.min(env.finger_clearance_to_brick2(f64::from(s.contact_margin)) as f32);
        }
        o = out.observation;
        if out.done {
            let stall = seed
                .zip(watch.into_found())
                .filter(|_| !out.success)
                .map(|(seed, snapshot)| StallStart { seed, snapshot });
            return Ok(Episode {
                obs,
                noise,
                steps,
                success: out.success,
                touched,
                clearance,
                stall,
            });
        }
    }
}
