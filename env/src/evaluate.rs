//! Success rate of an exported policy file, run through the `dex-runtime` evaluator: what is measured
//! is exactly what a controller runs (optionally with the CAN bus's quantisation on both sides).
//! f32 (format version 1) and int8 (version 2) files alike: the file picks the kernel.
//!
//! Also the int8-versus-f32 comparison: held-out observations recorded from episodes of the
//! environment ([`heldout_observations`]) and the largest action difference per joint between two
//! policy files on them ([`action_error`]); `cargo run --release -p dex-trainer --example
//! int8_compare` runs the whole comparison.

use dex_policy::PolicyView;
use dex_runtime::Mlp;
use dex_runtime::can::messages::{quantise_action, quantise_observation};
use dex_runtime::envelope::{Envelope, EnvelopeConfig};
use dex_runtime::features::{INPUT_MAX, policy_input};
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, CONTROL_PERIOD_US, OBS_DIM};

use crate::{Demonstration, EnvConfig, EnvError, JacoEnv, MarkovDemonstrator, Scene};

// Each episode's start seed (shared by `trainer eval`, `hil-sim run` and dexstack) and the
// held-out range, defined in `crate::seeds`, under their old paths here.
pub use crate::seeds::{HELDOUT_SEED, episode_seed};

/// Widest layer `trainer eval` accepts.
pub const EVAL_WIDTH: usize = 1024;

/// Why an evaluation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EvalError {
    /// The file is not a valid policy or does not fit the evaluator.
    #[error("policy file: {0}")]
    Format(#[from] dex_policy::FormatError),
    /// The policy's layout is not the cell's.
    #[error("policy does not match the Jaco cell: {0}")]
    Layout(dex_policy::FormatError),
    /// The runtime refused to evaluate an observation.
    #[error("runtime evaluation: {0}")]
    Runtime(#[from] dex_runtime::EvalError),
    /// The simulation failed.
    #[error("environment: {0}")]
    Env(#[from] EnvError),
    /// No episodes were asked for.
    #[error("at least one episode is needed")]
    NoEpisodes,
    /// An ensemble of policies was empty or mixed tasks.
    #[error("an ensemble needs at least one policy file, all of one task")]
    EnsembleTasks,
}

/// Result of evaluating a policy over several episodes.
#[derive(Debug, Clone, PartialEq)]
pub struct PolicyEval {
    /// Episodes run.
    pub episodes: u32,
    /// Episodes ending in success.
    pub successes: u32,
    /// Mean undiscounted return.
    pub mean_return: f64,
    /// 95% Wilson score interval of the success rate.
    pub ci95: (f64, f64),
}

impl PolicyEval {
    /// The summary of (return, success) episode outcomes.
    pub fn from_outcomes(outcomes: &[(f64, bool)]) -> Self {
        let n = outcomes.len() as u32;
        let successes = outcomes.iter().map(|&(_, ok)| u32::from(ok)).sum();
        let total: f64 = outcomes.iter().map(|&(ret, _)| ret).sum();
        PolicyEval {
            episodes: n,
            successes,
            mean_return: total / f64::from(n.max(1)),
            ci95: wilson_interval(successes, n),
        }
    }

    /// Fraction of successful episodes.
    pub fn success_rate(&self) -> f64 {
        f64::from(self.successes) / f64::from(self.episodes.max(1))
    }
}

impl std::fmt::Display for PolicyEval {
    /// `successes/episodes = rate% (95% CI lo-hi%), mean return r`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}/{} = {:.1}% (95% CI {:.1}-{:.1}%), mean return {:.2}",
            self.successes,
            self.episodes,
            self.success_rate() * 100.0,
            self.ci95.0 * 100.0,
            self.ci95.1 * 100.0,
            self.mean_return
        )
    }
}

/// 95% Wilson score interval for `successes` out of `n` (z = 1.96).
pub fn wilson_interval(successes: u32, n: u32) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let n = f64::from(n);
    let p = f64::from(successes) / n;
    let z = 1.96f64;
    let denom = 1.0 + z * z / n;
    let centre = (p + z * z / (2.0 * n)) / denom;
    let half = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / denom;
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// A controller's physical joint command turned into the environment's normalised action.
pub fn physical_to_env_action(physical: &[f32; ACT_DIM]) -> [f32; ACT_DIM] {
    core::array::from_fn(|i| physical[i] / ACTION_JOINTS[i].scale)
}

/// How an evaluation runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalSettings {
    /// Environment (task, reward, episode length).
    pub env: EnvConfig,
    /// Episodes to run.
    pub episodes: u32,
    /// Seed of the start states (episode `i` starts from [`episode_seed`]`(seed, i)`).
    pub seed: u64,
    /// Worker threads.
    pub threads: usize,
    /// Quantise observations and actions exactly as the CAN bus does (the SIL loop's view).
    pub can_quantisation: bool,
    /// Apply the controller's safety envelope (`dex_runtime::envelope`, the Jaco defaults) to
    /// every action, after the policy and before the CAN quantisation, as the controller does.
    pub envelope: bool,
}

/// One episode through the runtime evaluator; returns (return, success).
pub fn run_episode(
    mlp: &mut Mlp<'_, EVAL_WIDTH>,
    env: &mut JacoEnv,
    seed: u64,
    can_quantisation: bool,
    envelope: Option<&mut Envelope>,
) -> Result<(f64, bool), EvalError> {
    run_episode_recorded(mlp, env, seed, can_quantisation, envelope, None)
}

/// [`run_episode`], pushing every applied physical command (after the CAN quantisation when on)
/// into `record`.
pub fn run_episode_recorded(
    mlp: &mut Mlp<'_, EVAL_WIDTH>,
    env: &mut JacoEnv,
    seed: u64,
    can_quantisation: bool,
    envelope: Option<&mut Envelope>,
    record: Option<&mut Vec<[f32; ACT_DIM]>>,
) -> Result<(f64, bool), EvalError> {
    ensemble_episode(
        core::slice::from_mut(mlp),
        env,
        seed,
        can_quantisation,
        envelope,
        record,
    )
}

/// One episode driven by [`ensemble_command`] (with one policy: [`run_episode_recorded`]).
fn ensemble_episode(
    mlps: &mut [Mlp<'_, EVAL_WIDTH>],
    env: &mut JacoEnv,
    seed: u64,
    can_quantisation: bool,
    mut envelope: Option<&mut Envelope>,
    mut record: Option<&mut Vec<[f32; ACT_DIM]>>,
) -> Result<(f64, bool), EvalError> {
    let mut obs = env.reset(seed)?;
    let mut total = 0.0f64;
    loop {
        let physical = ensemble_command(mlps, &obs, can_quantisation, envelope.as_deref_mut())?;
        if let Some(r) = record.as_deref_mut() {
            r.push(physical);
        }
        let out = env.step(&physical_to_env_action(&physical))?;
        total += f64::from(out.reward);
        obs = out.observation;
        if out.done {
            return Ok((total, out.success));
        }
    }
}

/// The physical command the plant receives for observation `obs`, as the controller node computes
/// it: the observation as it arrives over CAN (quantised when `can_quantisation`), the task
/// features after it for a policy that takes them, the policy, the safety envelope when given,
/// and the command as it arrives back over CAN. Every episode loop that runs a policy file as the
/// controller would (`trainer eval`, the diagnostics examples, tests) steps through this.
pub fn controller_command<const W: usize>(
    mlp: &mut Mlp<'_, W>,
    obs: &[f32; OBS_DIM],
    can_quantisation: bool,
    envelope: Option<&mut Envelope>,
) -> Result<[f32; ACT_DIM], EvalError> {
    ensemble_command(core::slice::from_mut(mlp), obs, can_quantisation, envelope)
}

/// [`controller_command`] with the mean of several policies' commands in place of one policy's
/// (each takes its own inputs, with or without the task features; the envelope and the CAN
/// quantisation apply to the mean). With one policy it is [`controller_command`] exactly. The
/// controller runs one network: an ensemble is measured here to be distilled into one
/// (`trainer imitate --teacher-policies`), not to be flashed.
pub fn ensemble_command<const W: usize>(
    mlps: &mut [Mlp<'_, W>],
    obs: &[f32; OBS_DIM],
    can_quantisation: bool,
    envelope: Option<&mut Envelope>,
) -> Result<[f32; ACT_DIM], EvalError> {
    let input: [f32; OBS_DIM] = if can_quantisation {
        core::array::from_fn(|i| quantise_observation(i, obs[i]))
    } else {
        *obs
    };
    let mut physical = [0.0f32; ACT_DIM];
    let mut one = [0.0f32; ACT_DIM];
    let mut buf = [0.0f32; INPUT_MAX];
    for (k, mlp) in mlps.iter_mut().enumerate() {
        let out = if k == 0 { &mut physical } else { &mut one };
        mlp.act(policy_input(&input, mlp.obs_dim(), &mut buf), out)?;
        if k > 0 {
            for (p, x) in physical.iter_mut().zip(one) {
                *p += x;
            }
        }
    }
    if mlps.len() > 1 {
        let n = mlps.len() as f32;
        physical = physical.map(|p| p / n);
    }
    if let Some(e) = envelope {
        e.apply(&input, &mut physical);
    }
    if can_quantisation {
        physical = physical.map(quantise_action);
    }
    Ok(physical)
}

/// The envelope `trainer eval --envelope` applies: the controller's default.
pub fn eval_envelope() -> Envelope {
    Envelope::new(EnvelopeConfig::jaco(), CONTROL_PERIOD_US)
}

/// Decodes a policy file (4-byte aligned) and checks that its observation and action layout is the
/// Jaco cell's.
pub fn decode_jaco_policy(aligned: &[u8]) -> Result<PolicyView<'_>, EvalError> {
    let view = PolicyView::decode(aligned)?;
    dex_runtime::features::check_layout(&view).map_err(EvalError::Layout)?;
    Ok(view)
}

/// Evaluates a policy file on `settings.episodes` start states, calling `on_episode` after each.
pub fn evaluate_policy_file(
    file: &[u8],
    scene: &Scene,
    settings: &EvalSettings,
    on_episode: &(dyn Fn() + Sync),
) -> Result<PolicyEval, EvalError> {
    Ok(PolicyEval::from_outcomes(&episode_outcomes(
        file, scene, settings, on_episode,
    )?))
}

/// One evaluated episode with every command applied: (return, success, commands).
pub type EpisodeTrace = (f64, bool, Vec<[f32; ACT_DIM]>);

/// The [`EpisodeTrace`] of each of `settings.episodes` episodes, one thread, in episode order: what
/// `trainer eval --actions` writes, to compare with a run over the bus.
pub fn episode_traces(
    file: &[u8],
    scene: &Scene,
    settings: &EvalSettings,
) -> Result<Vec<EpisodeTrace>, EvalError> {
    if settings.episodes == 0 {
        return Err(EvalError::NoEpisodes);
    }
    let aligned = dex_runtime::aligned::aligned_copy(file);
    let view = decode_jaco_policy(aligned.as_bytes())?;
    let mut mlp = Mlp::<EVAL_WIDTH>::new(&view)?;
    let mut env = JacoEnv::new(scene, settings.env);
    let mut envelope = settings.envelope.then(eval_envelope);
    (0..settings.episodes)
        .map(|i| {
            let mut actions = Vec::new();
            let seed = episode_seed(settings.seed, u64::from(i));
            let (ret, ok) = run_episode_recorded(
                &mut mlp,
                &mut env,
                seed,
                settings.can_quantisation,
                envelope.as_mut(),
                Some(&mut actions),
            )?;
            Ok((ret, ok, actions))
        })
        .collect()
}

/// (return, success) of each of `settings.episodes` episodes of a policy file, in episode order
/// (episode `i` starts from [`episode_seed`]`(settings.seed, i)`), so that two policies can be
/// compared start by start. Calls `on_episode` after each.
pub fn episode_outcomes(
    file: &[u8],
    scene: &Scene,
    settings: &EvalSettings,
    on_episode: &(dyn Fn() + Sync),
) -> Result<Vec<(f64, bool)>, EvalError> {
    ensemble_outcomes(&[file], scene, settings, on_episode)
}

/// [`episode_outcomes`] of the mean of several policy files' commands ([`ensemble_command`]),
/// all of the Jaco cell's layout and of one task (one file: [`episode_outcomes`]).
pub fn ensemble_outcomes(
    files: &[&[u8]],
    scene: &Scene,
    settings: &EvalSettings,
    on_episode: &(dyn Fn() + Sync),
) -> Result<Vec<(f64, bool)>, EvalError> {
    if files.is_empty() {
        return Err(EvalError::EnsembleTasks);
    }
    let aligned: Vec<_> = files
        .iter()
        .map(|f| dex_runtime::aligned::aligned_copy(f))
        .collect();
    let views = aligned
        .iter()
        .map(|a| decode_jaco_policy(a.as_bytes()))
        .collect::<Result<Vec<_>, _>>()?;
    if views.iter().any(|v| v.body().task != views[0].body().task) {
        return Err(EvalError::EnsembleTasks);
    }
    outcomes_in_order(
        settings,
        || {
            let mlps = views
                .iter()
                .map(Mlp::<EVAL_WIDTH>::new)
                .collect::<Result<Vec<_>, _>>()?;
            Ok((
                mlps,
                JacoEnv::new(scene, settings.env),
                settings.envelope.then(eval_envelope),
            ))
        },
        |(mlps, env, envelope), seed| {
            ensemble_episode(
                mlps,
                env,
                seed,
                settings.can_quantisation,
                envelope.as_mut(),
                None,
            )
        },
        on_episode,
    )
}

/// (return, success) of the task's Markov demonstrator (the teacher of the clones and of teacher
/// labels; it reads the simulation's state, so neither the CAN quantisation nor the envelope
/// applies) on the starts of [`episode_outcomes`] with the same settings, in episode order.
pub fn teacher_outcomes(
    scene: &Scene,
    settings: &EvalSettings,
    on_episode: &(dyn Fn() + Sync),
) -> Result<Vec<(f64, bool)>, EvalError> {
    let teacher = MarkovDemonstrator::new(settings.env.task);
    demonstration_outcomes(scene, settings, &|| Ok(teacher), on_episode)
}

/// (return, success) of a [`Demonstration`] (one copy per thread from `make`, restarted before
/// each episode; it reads the simulation's state, so neither the CAN quantisation nor the
/// envelope applies) on the starts of [`episode_outcomes`] with the same settings, in episode
/// order.
pub fn demonstration_outcomes<D: Demonstration>(
    scene: &Scene,
    settings: &EvalSettings,
    make: &(dyn Fn() -> Result<D, EvalError> + Sync),
    on_episode: &(dyn Fn() + Sync),
) -> Result<Vec<(f64, bool)>, EvalError> {
    outcomes_in_order(
        settings,
        || Ok((JacoEnv::new(scene, settings.env), make()?)),
        |(env, teacher), seed| {
            env.reset(seed)?;
            teacher.restart();
            let mut total = 0.0f64;
            loop {
                let out = env.step(&teacher.act(env)?)?;
                total += f64::from(out.reward);
                if out.done {
                    return Ok((total, out.success));
                }
            }
        },
        on_episode,
    )
}

/// Runs episode `i` of `settings.episodes` (from [`episode_seed`]`(settings.seed, i)`) with `run`
/// on `settings.threads` threads, each with its own state from `init`; the outcomes in episode
/// order. No episodes is an error.
fn outcomes_in_order<S>(
    settings: &EvalSettings,
    init: impl Fn() -> Result<S, EvalError> + Sync,
    run: impl Fn(&mut S, u64) -> Result<(f64, bool), EvalError> + Sync,
    on_episode: &(dyn Fn() + Sync),
) -> Result<Vec<(f64, bool)>, EvalError> {
    if settings.episodes == 0 {
        return Err(EvalError::NoEpisodes);
    }
    crate::parallel::map_in_order(
        settings.episodes as usize,
        settings.threads,
        init,
        |state, i| run(state, episode_seed(settings.seed, i as u64)),
        on_episode,
    )
}

/// Every observation of `episodes` episodes driven by the policy `file` through the runtime (no CAN
/// quantisation), episode `i` starting from [`episode_seed`]`(seed, i)`.
pub fn heldout_observations(
    file: &[u8],
    scene: &Scene,
    env: EnvConfig,
    episodes: u32,
    seed: u64,
) -> Result<Vec<[f32; OBS_DIM]>, EvalError> {
    let aligned = dex_runtime::aligned::aligned_copy(file);
    let view = PolicyView::decode(aligned.as_bytes())?;
    let mut mlp = Mlp::<EVAL_WIDTH>::new(&view)?;
    let mut env = JacoEnv::new(scene, env);
    let mut out = Vec::new();
    for i in 0..episodes {
        let mut obs = env.reset(episode_seed(seed, u64::from(i)))?;
        loop {
            out.push(obs);
            let mut physical = [0.0f32; ACT_DIM];
            let mut buf = [0.0f32; INPUT_MAX];
            mlp.act(policy_input(&obs, mlp.obs_dim(), &mut buf), &mut physical)?;
            let step = env.step(&physical_to_env_action(&physical))?;
            obs = step.observation;
            if step.done {
                break;
            }
        }
    }
    Ok(out)
}

/// The held-out set on which an int8 policy is compared with its f32 source: every observation of
/// `episodes` episodes driven by each of the two policies from [`HELDOUT_SEED`] (the states either
/// policy visits).
pub fn heldout_observations_of_both(
    f32_file: &[u8],
    int8_file: &[u8],
    scene: &Scene,
    env: EnvConfig,
    episodes: u32,
) -> Result<Vec<[f32; OBS_DIM]>, EvalError> {
    let mut observations = heldout_observations(f32_file, scene, env, episodes, HELDOUT_SEED)?;
    observations.extend(heldout_observations(
        int8_file,
        scene,
        env,
        episodes,
        HELDOUT_SEED,
    )?);
    Ok(observations)
}

/// Every `|a(x) - b(x)| / (max - min)` over `observations` and joints (observation-major): the
/// distribution behind [`action_error`]'s maxima.
pub fn action_errors(
    a: &[u8],
    b: &[u8],
    observations: &[[f32; OBS_DIM]],
) -> Result<Vec<f64>, EvalError> {
    let (fa, fb) = (
        dex_runtime::aligned::aligned_copy(a),
        dex_runtime::aligned::aligned_copy(b),
    );
    let (va, vb) = (
        PolicyView::decode(fa.as_bytes())?,
        PolicyView::decode(fb.as_bytes())?,
    );
    let mut ma = Mlp::<EVAL_WIDTH>::new(&va)?;
    let mut mb = Mlp::<EVAL_WIDTH>::new(&vb)?;
    let mut out = Vec::with_capacity(observations.len() * ACT_DIM);
    for obs in observations {
        let (mut ya, mut yb) = ([0.0f32; ACT_DIM], [0.0f32; ACT_DIM]);
        let mut buf = [0.0f32; INPUT_MAX];
        ma.act(policy_input(obs, ma.obs_dim(), &mut buf), &mut ya)?;
        mb.act(policy_input(obs, mb.obs_dim(), &mut buf), &mut yb)?;
        for (k, joint) in ACTION_JOINTS.iter().enumerate() {
            let range = f64::from(joint.max) - f64::from(joint.min);
            out.push((f64::from(ya[k]) - f64::from(yb[k])).abs() / range);
        }
    }
    Ok(out)
}

/// Largest `|a(x) - b(x)| / (max - min)` per joint over `observations`: the action difference of
/// two policy files (e.g. int8 against f32) as a fraction of each joint's command range.
pub fn action_error(
    a: &[u8],
    b: &[u8],
    observations: &[[f32; OBS_DIM]],
) -> Result<[f64; ACT_DIM], EvalError> {
    let errors = action_errors(a, b, observations)?;
    let mut worst = [0.0f64; ACT_DIM];
    for row in errors.chunks_exact(ACT_DIM) {
        for (w, &e) in worst.iter_mut().zip(row) {
            *w = w.max(e);
        }
    }
    Ok(worst)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_interval_matches_known_values() {
        // Reference values (statsmodels proportion_confint method="wilson"):
        // 95/100 -> (0.8882, 0.9785); 0/10 -> (0, 0.2775); 10/10 -> (0.7225, 1).
        let (lo, hi) = wilson_interval(95, 100);
        assert!(
            (lo - 0.8882).abs() < 1e-3 && (hi - 0.9785).abs() < 1e-3,
            "{lo} {hi}"
        );
        let (lo, hi) = wilson_interval(0, 10);
        assert!(lo == 0.0 && (hi - 0.2775).abs() < 1e-3);
        let (lo, hi) = wilson_interval(10, 10);
        assert!((lo - 0.7225).abs() < 1e-3 && hi == 1.0);
    }
}
