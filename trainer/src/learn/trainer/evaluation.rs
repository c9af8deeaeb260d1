//! Noise-free evaluation episodes of an actor.

use super::*;

/// Runs `cfg.episodes` noise-free episodes; returns (mean return, success rate).
pub(super) fn evaluate<E: Env>(
    actor: &Mlp,
    params: &[f32],
    env: &mut E,
    cfg: &EvalConfig,
    rng: &mut Rng,
    scratch: &mut MlpScratch,
    norm: Option<&Normalizer>,
) -> Result<(f64, f64), LearnError> {
    let (od, ad) = (env.obs_dim(), env.act_dim());
    let mut obs = vec![0.0f32; od];
    let mut obs_n = vec![0.0f32; od];
    let mut action = vec![0.0f32; ad];
    let mut total = 0.0f64;
    let mut successes = 0usize;
    for _ in 0..cfg.episodes {
        env.reset_eval(rng, &mut obs);
        let mut last_success = false;
        for _ in 0..cfg.max_steps.max(1) {
            obs_n.copy_from_slice(&obs);
            if let Some(n) = norm {
                n.apply_rows(&mut obs_n);
            }
            let out = actor.forward(params, &obs_n, 1, scratch)?;
            action.copy_from_slice(out);
            let step = env.step(&action, &mut obs);
            total += f64::from(step.reward);
            last_success = step.success;
            if step.done() {
                break;
            }
        }
        successes += usize::from(last_success);
    }
    let n = cfg.episodes.max(1) as f64;
    Ok((total / n, successes as f64 / n))
}

/// Evaluates an actor on `episodes` noise-free episodes with a generator seeded from `seed`; returns
/// (mean return, success rate). For final evaluations outside training.
pub fn evaluate_actor<E: Env>(
    actor: &Mlp,
    params: &[f32],
    env: &mut E,
    episodes: usize,
    max_steps: usize,
    seed: u64,
) -> Result<(f64, f64), LearnError> {
    let cfg = EvalConfig {
        every_episodes: 0,
        episodes,
        max_steps,
        fixed_starts: true,
    };
    let mut scratch = actor.scratch(1);
    evaluate(
        actor,
        params,
        env,
        &cfg,
        &mut Rng::seed_from_u64(seed),
        &mut scratch,
        None,
    )
}
