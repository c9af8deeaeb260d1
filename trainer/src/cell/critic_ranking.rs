//! Does a run's critic rank actions? At states along its actor's own episodes, a few candidate
//! actions (the actor's, and the actor's plus Gaussian noise) are each executed once from the
//! same simulator state (restored from a snapshot) and then followed by the actor for `horizon`
//! steps; the discounted sum of the run's rewards is the candidate's value under the actor,
//! `Q^mu(s, a)`, the quantity the critic's TD targets estimate (episodes end at a time limit that
//! the learner bootstraps over, so the rollout runs past the episode's length; the observation
//! holds no clock). The critic's order of the candidates is compared with that true order, pair
//! by pair and by the size of the true gap (`trainer critic-rank`).
//!
//! The actor follows the critic's action gradient, so a critic that cannot order actions a
//! noise's width apart moves the actor at random: this measures that directly, without training
//! an actor on it.

use std::path::Path;

use dex_runtime::features::{INPUT_MAX, policy_input};
use dex_runtime::interface::ACT_DIM;
use serde::Serialize;

use crate::cell::run_folder::{RunFolderError, load_run};
use crate::env::seeds::episode_seed;
use crate::env::{EnvConfig, EnvError, JacoEnv, Scene};
use crate::learn::{LearnError, Networks, Rng};

/// Why the ranking could not be measured.
#[derive(Debug, thiserror::Error)]
pub enum CriticRankingError {
    /// The run's folder could not be read back.
    #[error(transparent)]
    Run(#[from] RunFolderError),
    /// The run cannot be measured as it is.
    #[error("{0}")]
    Unsupported(&'static str),
    /// The settings are out of range.
    #[error("{field}: {why}")]
    Settings {
        /// The setting.
        field: &'static str,
        /// Why.
        why: &'static str,
    },
    /// The simulation failed.
    #[error(transparent)]
    Env(#[from] EnvError),
    /// A network could not be run.
    #[error(transparent)]
    Learn(#[from] LearnError),
    /// Values given to [`rate`] do not match the states: one slice per state, one value per
    /// candidate.
    #[error("rated values: {0}")]
    RatedShape(String),
}

/// What to measure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RankingSettings {
    /// States measured, one per start: state `i` is a uniformly drawn step of the actor's
    /// episode from [`episode_seed`]`(seed, i)`.
    pub states: u32,
    /// Candidates per state, the actor's own action first (at least 2).
    pub candidates: u32,
    /// Standard deviation of the Gaussian noise of the other candidates, in action units (the
    /// result is clipped to `[-1, 1]`).
    pub noise: f32,
    /// Steps of each candidate's rollout (the candidate, then the actor): `gamma^horizon` is
    /// the weight of what it leaves out.
    pub horizon: u32,
    /// Start seed of the states (and of the noise).
    pub seed: u64,
    /// Threads (states are split among them; the result does not depend on the count).
    pub threads: usize,
    /// Rollouts per candidate (at least 1). The first executes the candidate as drawn; each
    /// other adds Gaussian noise of `jitter` to its first action, a difference no critic can
    /// resolve. The true value is their mean, and the second's order of the candidates against
    /// the first's ([`RankingReport::rollout_agreement`]) is what one rollout predicts of
    /// another: the ceiling of any rater where contacts make the outcome chaotic.
    pub replicates: u32,
    /// Noise on the first action of the replicate rollouts, in action units.
    pub jitter: f32,
    /// Steps each candidate is held for before the actor takes over (1: one step, the critic's
    /// own question; more: the value of an action held that long, for critics of held actions).
    pub hold: u32,
}

impl RankingSettings {
    fn validate(&self) -> Result<(), CriticRankingError> {
        let bad = |field, why| Err(CriticRankingError::Settings { field, why });
        if self.states == 0 {
            return bad("states", "must be at least 1");
        }
        if self.candidates < 2 {
            return bad(
                "candidates",
                "must be at least 2 (the actor's and one other)",
            );
        }
        if !(self.noise > 0.0 && self.noise.is_finite()) {
            return bad("noise", "must be positive and finite");
        }
        if self.horizon == 0 {
            return bad("horizon", "must be at least 1");
        }
        if self.hold == 0 || self.hold > self.horizon {
            return bad("hold", "must be at least 1 and at most the horizon");
        }
        if self.replicates == 0 {
            return bad("replicates", "must be at least 1");
        }
        if !(self.jitter >= 0.0 && self.jitter.is_finite()) {
            return bad("jitter", "must be non-negative and finite");
        }
        Ok(())
    }
}

/// One measured state.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StateRanking {
    /// Start seed of the episode.
    pub start_seed: u64,
    /// Step of the episode the state is at.
    pub step: u32,
    /// Each candidate's discounted return over the horizon (the actor's action first); the mean
    /// of its rollouts with [`RankingSettings::replicates`].
    pub true_q: Vec<f64>,
    /// Each rollout's return, `replicates x candidates` (empty with one rollout per candidate).
    pub replicate_q: Vec<Vec<f64>>,
    /// Each rater's value of each candidate (raters in [`RankingReport::raters`] order).
    pub rated: Vec<Vec<f32>>,
    /// The networks' input at the state (the observation, with the task features when the run
    /// takes them): with [`StateRanking::candidates`], what another critic needs to be rated on
    /// the same states ([`rate`]).
    pub input: Vec<f32>,
    /// The candidate actions, the actor's first.
    pub candidates: Vec<[f32; ACT_DIM]>,
}

/// How one rater orders the candidates, against the true order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RaterStats {
    /// The rater.
    pub rater: String,
    /// Candidate pairs with a true gap (unequal true values).
    pub pairs: u64,
    /// Share of them the rater orders as the rollouts do (0.5: chance).
    pub agreement: f64,
    /// Agreement within each quarter of the pairs by the size of their true gap (smallest
    /// first; the bounds are in [`RankingReport::gap_quartiles`]).
    pub agreement_by_gap: [f64; 4],
    /// Of the states whose candidates' true values are not all equal, the share where the
    /// best-rated candidate is a truly best one (ties count).
    pub best_match: f64,
    /// What choosing a candidate at random gives on those states.
    pub best_chance: f64,
    /// Correlation of the rater's and the true values after each state's mean is taken out of
    /// both (how much of the within-state spread the rater sees).
    pub within_state_correlation: f64,
}

/// The measurement.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RankingReport {
    /// The settings' values, for the record.
    pub states: u32,
    /// Candidates per state.
    pub candidates: u32,
    /// Noise of the other candidates.
    pub noise: f32,
    /// Rollout steps.
    pub horizon: u32,
    /// Start seed.
    pub seed: u64,
    /// The run's discount.
    pub gamma: f32,
    /// The raters: `critic` (the one the actor follows), and with two critics `min of twin` (what
    /// the TD targets use) and `mean of twin` (what an ensemble's actor would follow).
    pub raters: Vec<String>,
    /// Share of candidate pairs whose true values are equal (the reward sequence did not change).
    pub tied_pairs: f64,
    /// States whose candidates' true values are not all equal.
    pub states_with_gap: u32,
    /// Bounds of the quarters of the pairs' true gaps (25th, 50th and 75th percentiles).
    pub gap_quartiles: [f64; 3],
    /// Mean true value of the actor's own action.
    pub mean_actor_q: f64,
    /// Share of states where a noisy candidate is truly better than the actor's action (what
    /// a critic that ranked perfectly could improve on).
    pub actor_beaten: f64,
    /// With replicates: of the candidate pairs the first rollouts order (unequal values), the
    /// share the second rollouts order the same way, ties counted as half (what a rater that
    /// knew one rollout's outcome would score against another's).
    pub rollout_agreement: Option<f64>,
    /// Rollouts per candidate and the jitter of the replicates.
    pub replicates: u32,
    /// Noise on the replicates' first action.
    pub jitter: f32,
    /// Steps each candidate was held for.
    pub hold: u32,
    /// Each rater's agreement with the true order.
    pub stats: Vec<RaterStats>,
    /// Every state, in order.
    pub per_state: Vec<StateRanking>,
}

/// The run's networks and environment, ready to measure.
#[derive(Debug, Clone)]
pub struct RankedRun {
    nets: Networks,
    actor: Vec<f32>,
    critics: Vec<Vec<f32>>,
    gamma: f32,
    env: EnvConfig,
}

impl RankedRun {
    /// The last checkpoint of the `trainer train` seed folder `seed_dir`. Runs that normalise
    /// their observations are refused (the networks are read on raw observations).
    pub fn from_run(seed_dir: &Path) -> Result<Self, CriticRankingError> {
        let (settings, t) = load_run(seed_dir)?;
        if t.config().obs_norm.enabled {
            return Err(CriticRankingError::Unsupported(
                "the run normalises its observations; the ranking reads raw ones",
            ));
        }
        let mut critics = vec![t.critic().1.to_vec()];
        critics.extend(t.twin_critic().map(<[f32]>::to_vec));
        Ok(RankedRun {
            nets: t.networks().clone(),
            actor: t.actor().1.to_vec(),
            critics,
            gamma: t.config().ddpg.gamma,
            env: settings.reward.env_config(settings.task.task()),
        })
    }

    /// The raters' names, in the order of [`StateRanking::rated`].
    pub fn raters(&self) -> Vec<String> {
        let mut r = vec!["critic".to_string()];
        if self.critics.len() > 1 {
            r.push("min of twin".to_string());
            r.push("mean of twin".to_string());
        }
        r
    }

    /// Measures the ranking on `scene`.
    pub fn measure(
        &self,
        scene: &Scene,
        s: &RankingSettings,
        on_state: &(dyn Fn() + Sync),
    ) -> Result<RankingReport, CriticRankingError> {
        s.validate()?;
        let per_state = crate::env::parallel::map_in_order(
            s.states as usize,
            s.threads,
            || Ok(JacoEnv::new(scene, self.env)),
            |env, i| self.one_state(env, s, i as u64),
            on_state,
        )?;
        Ok(self.report(s, per_state))
    }

    /// The actor's action for the environment's current observation.
    fn act(
        &self,
        env: &JacoEnv,
        scratch: &mut crate::learn::nets::MlpScratch,
    ) -> Result<[f32; ACT_DIM], LearnError> {
        let mut buf = [0.0f32; INPUT_MAX];
        let x = policy_input(env.observation(), self.nets.obs_dim, &mut buf);
        let mut a = [0.0f32; ACT_DIM];
        a.copy_from_slice(&self.nets.actor.forward(&self.actor, x, 1, scratch)?[..ACT_DIM]);
        Ok(a)
    }

    fn one_state(
        &self,
        env: &mut JacoEnv,
        s: &RankingSettings,
        i: u64,
    ) -> Result<StateRanking, CriticRankingError> {
        let k = s.candidates as usize;
        let start_seed = episode_seed(s.seed, i);
        let mut rng = Rng::derive(s.seed, i);
        let step = rng.below(env.config().episode_steps.max(1) as usize) as u32;
        let mut scratch = self.nets.actor.scratch(1);
        env.reset(start_seed)?;
        for _ in 0..step {
            let a = self.act(env, &mut scratch)?;
            env.step(&a)?;
        }
        let mut buf = [0.0f32; INPUT_MAX];
        let x = policy_input(env.observation(), self.nets.obs_dim, &mut buf).to_vec();
        let snapshot = env.snapshot();
        let own = self.act(env, &mut scratch)?;
        let mut candidates = vec![own];
        for _ in 1..k {
            let mut a = own;
            for v in &mut a {
                *v = (*v + rng.normal(0.0, s.noise)).clamp(-1.0, 1.0);
            }
            candidates.push(a);
        }
        let reps = s.replicates as usize;
        let mut replicate_q = vec![Vec::with_capacity(k); reps];
        for a in &candidates {
            for (r, values) in replicate_q.iter_mut().enumerate() {
                let mut first = *a;
                if r > 0 {
                    for v in &mut first {
                        *v = (*v + rng.normal(0.0, s.jitter)).clamp(-1.0, 1.0);
                    }
                }
                env.restore(&snapshot)?;
                let mut g = f64::from(env.step(&first)?.reward);
                let mut discount = f64::from(self.gamma);
                for t in 1..s.horizon {
                    let next = if t < s.hold {
                        first
                    } else {
                        self.act(env, &mut scratch)?
                    };
                    g += discount * f64::from(env.step(&next)?.reward);
                    discount *= f64::from(self.gamma);
                }
                values.push(g);
            }
        }
        let true_q: Vec<f64> = (0..k)
            .map(|j| replicate_q.iter().map(|v| v[j]).sum::<f64>() / reps as f64)
            .collect();
        if reps == 1 {
            replicate_q.clear();
        }
        let d = self.nets.obs_dim + ACT_DIM;
        let mut rows = vec![0.0f32; k * d];
        for (row, a) in rows.chunks_exact_mut(d).zip(&candidates) {
            row[..self.nets.obs_dim].copy_from_slice(&x);
            row[self.nets.obs_dim..].copy_from_slice(a);
        }
        let mut critic_scratch = self.nets.critic.scratch(k);
        let mut per_critic = Vec::with_capacity(self.critics.len());
        for c in &self.critics {
            per_critic
                .push(self.nets.critic.forward(c, &rows, k, &mut critic_scratch)?[..k].to_vec());
        }
        let mut rated = vec![per_critic[0].clone()];
        if per_critic.len() > 1 {
            rated.push(
                (0..k)
                    .map(|j| {
                        per_critic
                            .iter()
                            .map(|q| q[j])
                            .fold(f32::INFINITY, f32::min)
                    })
                    .collect(),
            );
            let n = per_critic.len() as f32;
            rated.push(
                (0..k)
                    .map(|j| per_critic.iter().map(|q| q[j]).sum::<f32>() / n)
                    .collect(),
            );
        }
        Ok(StateRanking {
            start_seed,
            step,
            true_q,
            replicate_q,
            rated,
            input: x,
            candidates,
        })
    }

    fn report(&self, s: &RankingSettings, per_state: Vec<StateRanking>) -> RankingReport {
        let raters = self.raters();
        let mut gaps: Vec<f64> = per_state
            .iter()
            .flat_map(|st| pairs(st.true_q.len()).map(|(i, j)| (st.true_q[i] - st.true_q[j]).abs()))
            .filter(|g| *g > 0.0)
            .collect();
        gaps.sort_by(f64::total_cmp);
        let q = |p: f64| {
            gaps.get(((gaps.len() as f64 - 1.0) * p).round().max(0.0) as usize)
                .copied()
                .unwrap_or(0.0)
        };
        let gap_quartiles = [q(0.25), q(0.5), q(0.75)];
        let all_pairs: usize = per_state
            .iter()
            .map(|st| st.true_q.len() * st.true_q.len().saturating_sub(1) / 2)
            .sum();
        let tied_pairs = 1.0 - gaps.len() as f64 / all_pairs.max(1) as f64;
        let states_with_gap = per_state.iter().filter(|st| has_gap(&st.true_q)).count() as u32;
        let n = per_state.len().max(1) as f64;
        let mean_actor_q = per_state.iter().map(|st| st.true_q[0]).sum::<f64>() / n;
        let actor_beaten = per_state
            .iter()
            .filter(|st| st.true_q[1..].iter().any(|&v| v > st.true_q[0]))
            .count() as f64
            / n;
        let rollout_agreement = (s.replicates > 1).then(|| rollout_agreement(&per_state));
        let stats = raters
            .iter()
            .enumerate()
            .map(|(r, name)| rater_stats(name, r, &per_state, &gap_quartiles))
            .collect();
        RankingReport {
            states: s.states,
            candidates: s.candidates,
            noise: s.noise,
            horizon: s.horizon,
            seed: s.seed,
            gamma: self.gamma,
            raters,
            tied_pairs,
            states_with_gap,
            gap_quartiles,
            mean_actor_q,
            actor_beaten,
            rollout_agreement,
            replicates: s.replicates,
            jitter: s.jitter,
            hold: s.hold,
            stats,
            per_state,
        }
    }
}

/// Every pair `(i, j)`, `i < j`, of `k` candidates.
fn pairs(k: usize) -> impl Iterator<Item = (usize, usize)> {
    (0..k).flat_map(move |i| (i + 1..k).map(move |j| (i, j)))
}

/// Of the candidate pairs the first replicate orders, the share the second orders the same way
/// (ties in the second count as half).
fn rollout_agreement(states: &[StateRanking]) -> f64 {
    let (mut n, mut agree) = (0u64, 0.0f64);
    for st in states {
        let [first, second, ..] = &st.replicate_q[..] else {
            continue;
        };
        for (i, j) in pairs(first.len()) {
            let d = first[i] - first[j];
            if d == 0.0 {
                continue;
            }
            let e = second[i] - second[j];
            n += 1;
            agree += if e == 0.0 {
                0.5
            } else if d * e > 0.0 {
                1.0
            } else {
                0.0
            };
        }
    }
    if n == 0 { 0.0 } else { agree / n as f64 }
}

/// Whether some of `v` differ.
fn has_gap(v: &[f64]) -> bool {
    v.iter().any(|&x| x != v[0])
}

/// The index of the largest value (the first of equals).
fn argmax<T: PartialOrd + Copy>(v: &[T]) -> usize {
    let mut best = 0;
    for (i, &x) in v.iter().enumerate() {
        if x > v[best] {
            best = i;
        }
    }
    best
}

fn rater_stats(name: &str, r: usize, states: &[StateRanking], quartiles: &[f64; 3]) -> RaterStats {
    let rated: Vec<&[f32]> = states.iter().map(|st| &st.rated[r][..]).collect();
    rate_matched(name, states, &rated, quartiles)
}

/// How the values `rated[i]` (one per candidate of `states[i]`) order the candidates, against the
/// true order: the statistics of [`RankingReport::stats`] for a rater that is not the run's own
/// (a critic trained apart and rated on a report's states; `quartiles` from
/// [`RankingReport::gap_quartiles`]). `rated` holds one slice per state, as long as its
/// candidates; other shapes are refused.
pub fn rate(
    name: &str,
    states: &[StateRanking],
    rated: &[&[f32]],
    quartiles: &[f64; 3],
) -> Result<RaterStats, CriticRankingError> {
    if rated.len() != states.len() {
        return Err(CriticRankingError::RatedShape(format!(
            "{} slices for {} states",
            rated.len(),
            states.len()
        )));
    }
    if let Some((i, (st, r))) = states
        .iter()
        .zip(rated)
        .enumerate()
        .find(|(_, (st, r))| r.len() != st.true_q.len())
    {
        return Err(CriticRankingError::RatedShape(format!(
            "state {i} has {} candidates and {} values",
            st.true_q.len(),
            r.len()
        )));
    }
    Ok(rate_matched(name, states, rated, quartiles))
}

/// [`rate`] on values whose shape matches the states.
fn rate_matched(
    name: &str,
    states: &[StateRanking],
    rated: &[&[f32]],
    quartiles: &[f64; 3],
) -> RaterStats {
    let (mut pairs_n, mut agree) = (0u64, 0u64);
    let mut by_gap = [(0u64, 0u64); 4];
    let (mut best, mut chance, mut gapped) = (0usize, 0.0f64, 0usize);
    let (mut sxy, mut sxx, mut syy) = (0.0f64, 0.0f64, 0.0f64);
    for (st, &rated) in states.iter().zip(rated) {
        for (i, j) in pairs(st.true_q.len()) {
            let d = st.true_q[i] - st.true_q[j];
            if d == 0.0 {
                continue;
            }
            let c = f64::from(rated[i]) - f64::from(rated[j]);
            let ok = u64::from(d * c > 0.0);
            let bin = quartiles.iter().filter(|&&b| d.abs() > b).count();
            pairs_n += 1;
            agree += ok;
            by_gap[bin].0 += 1;
            by_gap[bin].1 += ok;
        }
        if has_gap(&st.true_q) {
            let top = st.true_q[argmax(&st.true_q)];
            gapped += 1;
            best += usize::from(st.true_q[argmax(rated)] == top);
            let ties = st.true_q.iter().filter(|&&v| v == top).count();
            chance += ties as f64 / st.true_q.len() as f64;
        }
        let k = st.true_q.len() as f64;
        let mt = st.true_q.iter().sum::<f64>() / k;
        let mr = rated.iter().map(|&v| f64::from(v)).sum::<f64>() / k;
        for (&t, &v) in st.true_q.iter().zip(rated) {
            let (x, y) = (t - mt, f64::from(v) - mr);
            sxy += x * y;
            sxx += x * x;
            syy += y * y;
        }
    }
    let share = |a: u64, n: u64| if n == 0 { 0.0 } else { a as f64 / n as f64 };
    RaterStats {
        rater: name.to_string(),
        pairs: pairs_n,
        agreement: share(agree, pairs_n),
        agreement_by_gap: by_gap.map(|(n, a)| share(a, n)),
        best_match: best as f64 / gapped.max(1) as f64,
        best_chance: chance / gapped.max(1) as f64,
        within_state_correlation: if sxx > 0.0 && syy > 0.0 {
            sxy / (sxx * syy).sqrt()
        } else {
            0.0
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(true_q: Vec<f64>, rated: Vec<f32>) -> StateRanking {
        let k = true_q.len();
        StateRanking {
            start_seed: 0,
            step: 0,
            true_q,
            replicate_q: Vec::new(),
            rated: vec![rated],
            input: Vec::new(),
            candidates: vec![[0.0; ACT_DIM]; k],
        }
    }

    #[test]
    fn a_rater_that_orders_as_the_rollouts_agrees_fully_and_a_reversed_one_not_at_all() {
        let states = vec![
            state(vec![1.0, 2.0, 4.0], vec![10.0, 20.0, 40.0]),
            state(vec![3.0, 1.0, 2.0], vec![35.0, 15.0, 25.0]),
        ];
        let s = rater_stats("same", 0, &states, &[0.5, 1.0, 2.0]);
        assert_eq!(s.pairs, 6);
        assert_eq!(s.agreement, 1.0);
        assert_eq!(s.best_match, 1.0);
        assert!((s.best_chance - 1.0 / 3.0).abs() < 1e-12);
        assert!((s.within_state_correlation - 1.0).abs() < 1e-9);
        let reversed: Vec<_> = states
            .iter()
            .map(|st| state(st.true_q.clone(), st.rated[0].iter().map(|v| -v).collect()))
            .collect();
        let s = rater_stats("reversed", 0, &reversed, &[0.5, 1.0, 2.0]);
        assert_eq!(s.agreement, 0.0);
        assert_eq!(s.best_match, 0.0);
        assert!((s.within_state_correlation + 1.0).abs() < 1e-9);
    }

    #[test]
    fn pairs_fall_in_the_quarter_of_their_gap_and_ties_do_not_count() {
        // Gaps: 1 (agree), 3 (disagree), 2 (agree); and a tie.
        let states = vec![
            state(vec![0.0, 1.0, 3.0], vec![0.0, 1.0, -1.0]),
            state(vec![5.0, 5.0], vec![1.0, 0.0]),
        ];
        let s = rater_stats("r", 0, &states, &[1.5, 2.5, 10.0]);
        assert_eq!(s.pairs, 3);
        // (0,1) gap 1 agrees -> bin 0; (0,2) gap 3 disagrees -> bin 2; (1,2) gap 2 disagrees -> bin 1.
        assert_eq!(s.agreement_by_gap, [1.0, 0.0, 0.0, 0.0]);
        assert!((s.agreement - 1.0 / 3.0).abs() < 1e-12);
        // Only the first state has a gap; its best-rated candidate (1) is not its best (2).
        assert_eq!(s.best_match, 0.0);
        assert!((s.best_chance - 1.0 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn rate_refuses_values_that_do_not_match_the_states() {
        let states = [state(vec![0.0, 1.0], vec![0.0, 1.0])];
        let q = [0.1, 0.2, 0.3];
        let ok = rate("x", &states, &[&[0.0, 1.0]], &q).unwrap();
        assert_eq!(ok.agreement, 1.0);
        for bad in [
            &[][..],
            &[&[0.0f32][..]][..],
            &[&[0.0, 1.0][..], &[0.0, 1.0][..]][..],
        ] {
            assert!(matches!(
                rate("x", &states, bad, &q),
                Err(CriticRankingError::RatedShape(_))
            ));
        }
    }

    #[test]
    fn replicates_agree_where_they_order_alike_and_ties_count_half() {
        let mut st = state(vec![0.0; 3], vec![0.0; 3]);
        // First: 0 < 1 < 2. Second: 0 < 1 (agrees), 0 = 2 (tie: half), 2 < 1 (disagrees).
        st.replicate_q = vec![vec![0.0, 1.0, 2.0], vec![0.0, 2.0, 0.0]];
        assert!((rollout_agreement(&[st]) - 1.5 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn settings_out_of_range_are_refused() {
        let ok = RankingSettings {
            states: 2,
            candidates: 3,
            noise: 0.1,
            horizon: 10,
            seed: 0,
            threads: 1,
            replicates: 1,
            jitter: 0.01,
            hold: 1,
        };
        assert!(ok.validate().is_ok());
        for bad in [
            RankingSettings { states: 0, ..ok },
            RankingSettings {
                candidates: 1,
                ..ok
            },
            RankingSettings { noise: 0.0, ..ok },
            RankingSettings {
                noise: f32::NAN,
                ..ok
            },
            RankingSettings { horizon: 0, ..ok },
            RankingSettings {
                replicates: 0,
                ..ok
            },
            RankingSettings { hold: 0, ..ok },
            RankingSettings { hold: 11, ..ok },
            RankingSettings { jitter: -1.0, ..ok },
        ] {
            assert!(matches!(
                bad.validate(),
                Err(CriticRankingError::Settings { .. })
            ));
        }
    }
}
