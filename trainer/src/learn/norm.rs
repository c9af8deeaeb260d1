//! Optional observation normalisation: running mean and standard deviation of every observation the
//! workers see, applied as `(obs - mean) / std` in front of the actor and the critic.
//!
//! Off by default ([`ObsNormConfig::enabled`]). When on, the replay keeps raw observations and each use
//! normalises with the statistics of that moment. There is no clipping, so the normalisation is affine
//! and [`Normalizer::fold_into_actor`] can fold it into the actor's first layer: the exported policy
//! then takes raw observations, and the controller needs no extra step.

use super::LearnError;
use super::nets::Mlp;
use serde::{Deserialize, Serialize};

/// Settings of observation normalisation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObsNormConfig {
    /// Normalise observations (false: networks see raw observations).
    pub enabled: bool,
    /// Floor on the standard deviation, so constant components do not blow up.
    pub min_std: f32,
    /// Measure the statistics once on the run's demonstration buffer and keep them fixed (no
    /// running update): the networks then see the same scale from the first update on, the
    /// pretraining on demonstrations included, and a state the demonstrations never visited cannot
    /// move the scale under a trained critic. Needs `enabled` and demonstrations in the batches.
    pub frozen_from_demos: bool,
    /// Take the statistics from the policy file that starts the actor (`init_policy`: its mean
    /// and scale, `Trainer::set_initial_actor_normalised`) and keep them fixed: the actor keeps the
    /// input coordinates it was trained in, and the critic sees the same. Needs `enabled`.
    pub frozen_from_init: bool,
}

impl ObsNormConfig {
    /// Whether the statistics stay fixed during the run.
    pub fn frozen(&self) -> bool {
        self.frozen_from_demos || self.frozen_from_init
    }
}

impl Default for ObsNormConfig {
    fn default() -> Self {
        ObsNormConfig {
            enabled: false,
            min_std: 1e-2,
            frozen_from_demos: false,
            frozen_from_init: false,
        }
    }
}

/// Running statistics (Welford's algorithm, f64).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ObsStats {
    /// Observations seen.
    pub count: u64,
    /// Running mean per component.
    pub mean: Vec<f64>,
    /// Running sum of squared deviations per component.
    pub m2: Vec<f64>,
}

impl ObsStats {
    /// Empty statistics for `dim` components.
    pub fn new(dim: usize) -> Self {
        ObsStats {
            count: 0,
            mean: vec![0.0; dim],
            m2: vec![0.0; dim],
        }
    }

    /// Adds one observation (extra components are ignored).
    pub fn push(&mut self, obs: &[f32]) {
        self.count += 1;
        let n = self.count as f64;
        for ((m, s), &x) in self.mean.iter_mut().zip(self.m2.iter_mut()).zip(obs) {
            let x = f64::from(x);
            let d = x - *m;
            *m += d / n;
            *s += d * (x - *m);
        }
    }

    /// The normaliser for the current statistics (identity before any observation).
    pub fn normalizer(&self, min_std: f32) -> Normalizer {
        let dim = self.mean.len();
        let mut out = Normalizer {
            mean: vec![0.0; dim],
            inv_std: vec![1.0; dim],
        };
        self.write_normalizer(min_std, &mut out);
        out
    }

    /// Writes the current normaliser into `out` without allocating (when dimensions match).
    pub fn write_normalizer(&self, min_std: f32, out: &mut Normalizer) {
        let dim = self.mean.len();
        out.mean.resize(dim, 0.0);
        out.inv_std.resize(dim, 1.0);
        if self.count == 0 {
            out.mean.fill(0.0);
            out.inv_std.fill(1.0);
            return;
        }
        let n = self.count as f64;
        for (((m, s), om), os) in self
            .mean
            .iter()
            .zip(&self.m2)
            .zip(out.mean.iter_mut())
            .zip(out.inv_std.iter_mut())
        {
            *om = *m as f32;
            *os = (1.0 / (s / n).sqrt().max(f64::from(min_std))) as f32;
        }
    }
}

/// A frozen affine normalisation `(x - mean) * inv_std`.
#[derive(Debug, Clone, PartialEq)]
pub struct Normalizer {
    /// Subtracted per component.
    pub mean: Vec<f32>,
    /// Multiplied per component after the subtraction.
    pub inv_std: Vec<f32>,
}

impl Normalizer {
    /// Normalises every row of a row-major matrix of `mean.len()` columns in place.
    pub fn apply_rows(&self, data: &mut [f32]) {
        let d = self.mean.len();
        if d == 0 {
            return;
        }
        for row in data.chunks_exact_mut(d) {
            for ((x, &m), &s) in row.iter_mut().zip(&self.mean).zip(&self.inv_std) {
                *x = (*x - m) * s;
            }
        }
    }

    /// The actor's parameters with the normalisation folded into its first layer, so that
    /// `actor(params_folded, obs) == actor(params, normalise(obs))` up to float rounding.
    pub fn fold_into_actor(&self, actor: &Mlp, params: &[f32]) -> Result<Vec<f32>, LearnError> {
        let layers = actor.layers(params)?;
        let first = layers
            .first()
            .ok_or(LearnError::BadNetwork("empty actor"))?;
        if first.fan_in != self.mean.len() {
            return Err(LearnError::Shape {
                what: "normaliser",
                expected: first.fan_in,
                got: self.mean.len(),
            });
        }
        let (fan_in, fan_out) = (first.fan_in, first.fan_out);
        // Layout: the first layer's weights start at 0, its bias follows them (see `nets`).
        let mut out = params.to_vec();
        let (w, rest) = out.split_at_mut(fan_in * fan_out);
        let bias = &mut rest[..fan_out];
        for i in 0..fan_in {
            let (m, s) = (self.mean[i], self.inv_std[i]);
            let row = &mut w[i * fan_out..(i + 1) * fan_out];
            for (wv, b) in row.iter_mut().zip(bias.iter_mut()) {
                let scaled = *wv * s;
                *b -= m * scaled;
                *wv = scaled;
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::kernel::Engine;
    use crate::learn::nets::{Activation, MlpSpec};
    use crate::learn::rng::Rng;

    #[test]
    fn welford_matches_two_pass_and_folding_is_exact_enough() {
        let mut rng = Rng::seed_from_u64(4);
        let rows: Vec<[f32; 3]> = (0..500)
            .map(|_| {
                [
                    rng.normal(2.0, 3.0),
                    rng.normal(-1.0, 0.1),
                    0.5, // constant: hits the std floor
                ]
            })
            .collect();
        let mut st = ObsStats::new(3);
        rows.iter().for_each(|r| st.push(r));
        let n = rows.len() as f64;
        let mean0 = rows.iter().map(|r| f64::from(r[0])).sum::<f64>() / n;
        let var0 = rows
            .iter()
            .map(|r| (f64::from(r[0]) - mean0).powi(2))
            .sum::<f64>()
            / n;
        assert!((st.mean[0] - mean0).abs() < 1e-9);
        assert!((st.m2[0] / n - var0).abs() < 1e-9);
        let norm = st.normalizer(1e-2);
        assert!((norm.inv_std[2] - 100.0).abs() < 1e-3);

        let actor = Mlp::new(
            MlpSpec::stack(3, &[8], Activation::Relu, false, 2, Activation::Tanh),
            Engine::default(),
        )
        .expect("actor");
        let params = actor.init_params(&mut rng, 0.5);
        let folded = norm.fold_into_actor(&actor, &params).expect("fold");
        let mut s = actor.scratch(1);
        for r in rows.iter().take(20) {
            let mut x = r.to_vec();
            let raw = actor.forward(&folded, &x, 1, &mut s).expect("fwd").to_vec();
            norm.apply_rows(&mut x);
            let want = actor.forward(&params, &x, 1, &mut s).expect("fwd").to_vec();
            for (a, b) in raw.iter().zip(&want) {
                assert!((a - b).abs() < 1e-4, "{a} vs {b}");
            }
        }
    }
}
