//! Quantisation-aware training of the actor, so that the policy the trainer exports is the one the
//! controller runs with int8 weights.
//!
//! From [`QuantiseConfig::aware_from`] transitions on, every use of the actor (acting, evaluation,
//! the target actor in the critic's target, and the forward and backward pass of the policy
//! gradient) sees [`fake_quantise`]d weights: each layer's weights rounded to the int8 grid of the
//! exporter, one symmetric scale per output channel (`dex_policy::int8::quantise_layer`), biases in
//! f32. The gradient with respect to the quantised weights is applied to the f32 ("shadow")
//! weights unchanged: the straight-through estimator of Bengio et al. (2013), as in the
//! quantisation-aware training of Jacob et al. (2018). The exported policy is the quantised one, so
//! its f32 file already lies on the int8 grid and the int8 file differs from it only by the
//! runtime's 16-bit activations (see `export::quantise_policy_file_calibrated`).

use serde::{Deserialize, Serialize};

use super::LearnError;
use super::nets::Mlp;

/// When the actor becomes quantisation-aware.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct QuantiseConfig {
    /// Transitions (all workers) after which the actor is used with int8-grid weights; `None`
    /// (the default) trains a plain f32 actor. Training a good f32 policy first and then
    /// fine-tuning it quantised (e.g. the last third of the run) works better than quantising
    /// from the start, when weights move by less than one grid step per update.
    pub aware_from: Option<u64>,
}

impl QuantiseConfig {
    /// Whether the actor is quantisation-aware after `transitions` transitions.
    pub fn active(&self, transitions: u64) -> bool {
        self.aware_from.is_some_and(|t| transitions >= t)
    }
}

/// Writes `params` into `out` with every layer's weights rounded to the int8 grid of the exporter:
/// `w = q * scale[j]`, `scale[j] = max_i |w[i][j]| / 127`, `q = round(w / scale[j])` (exactly
/// `dex_policy::int8::quantise_layer`); biases and layer-norm parameters are copied.
pub fn fake_quantise(net: &Mlp, params: &[f32], out: &mut [f32]) -> Result<(), LearnError> {
    let n = net.num_params();
    for (what, len) in [("parameter vector", params.len()), ("output", out.len())] {
        if len != n {
            return Err(LearnError::Shape {
                what,
                expected: n,
                got: len,
            });
        }
    }
    out.copy_from_slice(params);
    for (start, fan_in, fan_out) in net.weight_spans() {
        let span = start..start + fan_in * fan_out;
        let q = dex_policy::int8::quantise_layer(fan_in, fan_out, &params[span.clone()]);
        for (k, w) in out[span].iter_mut().enumerate() {
            let (i, j) = (k / fan_out, k % fan_out);
            *w = f32::from(q.weights[j * fan_in + i]) * q.scales[j];
        }
    }
    Ok(())
}

/// A cached [`fake_quantise`] of a parameter vector that changes rarely: recomputed only when the
/// source's version moved on.
#[derive(Debug, Clone, Default)]
pub struct QuantisedCopy {
    params: Vec<f32>,
    version: Option<u64>,
}

impl QuantisedCopy {
    /// `params` (whose version is `version`) as the learner uses it now: its quantised copy when
    /// `aware`, else `params` itself.
    pub fn select<'a>(
        &'a mut self,
        aware: bool,
        net: &Mlp,
        params: &'a [f32],
        version: u64,
    ) -> Result<&'a [f32], LearnError> {
        if aware {
            self.get(net, params, version)
        } else {
            Ok(params)
        }
    }

    /// The quantised `params` (whose version is `version`), recomputed if stale.
    pub fn get(&mut self, net: &Mlp, params: &[f32], version: u64) -> Result<&[f32], LearnError> {
        if self.version != Some(version) || self.params.len() != params.len() {
            self.params.resize(params.len(), 0.0);
            fake_quantise(net, params, &mut self.params)?;
            self.version = Some(version);
        }
        Ok(&self.params)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::kernel::Engine;
    use crate::learn::nets::{Activation, MlpSpec};
    use crate::learn::rng::Rng;

    fn net() -> Mlp {
        Mlp::new(
            MlpSpec::stack(5, &[7, 6], Activation::Relu, false, 3, Activation::Tanh),
            Engine::default(),
        )
        .unwrap()
    }

    #[test]
    fn weights_land_on_the_exporters_grid_and_stay_there() {
        let net = net();
        let p = net.init_params(&mut Rng::seed_from_u64(3), 0.3);
        let mut q = vec![0.0; p.len()];
        fake_quantise(&net, &p, &mut q).unwrap();
        let mut again = vec![0.0; p.len()];
        fake_quantise(&net, &q, &mut again).unwrap();
        let mut changed = 0;
        for (start, fan_in, fan_out) in net.weight_spans() {
            for j in 0..fan_out {
                let col = |v: &[f32]| -> Vec<f32> {
                    (0..fan_in).map(|i| v[start + i * fan_out + j]).collect()
                };
                let (w, wq) = (col(&p), col(&q));
                let max = w.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                let s = max / 127.0;
                for (a, b) in w.iter().zip(&wq) {
                    // Rounded to the nearest of 255 levels of the column's scale.
                    assert!((a - b).abs() <= 0.5 * s * 1.0001, "{a} -> {b}, step {s}");
                    let level = b / s;
                    assert!((level - level.round()).abs() < 1e-3, "{b} off the grid {s}");
                    changed += usize::from(a != b);
                }
                // The largest weight keeps its magnitude (to f32 rounding), so the scale stays.
                let max_q = wq.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                assert!((max_q - max).abs() <= 1e-6 * max, "{max_q} vs {max}");
            }
        }
        assert!(changed > 0);
        // Idempotent up to f32 rounding of the scale: a second pass moves nothing visibly.
        for (a, b) in q.iter().zip(&again) {
            assert!((a - b).abs() <= 1e-6 * a.abs().max(1e-6), "{a} vs {b}");
        }
        // Biases are untouched.
        let last = net.num_params() - 3;
        assert_eq!(&p[last..], &q[last..]);
    }

    #[test]
    fn matches_the_policy_formats_quantiser() {
        let net = net();
        let p = net.init_params(&mut Rng::seed_from_u64(4), 0.5);
        let mut q = vec![0.0; p.len()];
        fake_quantise(&net, &p, &mut q).unwrap();
        for (start, fan_in, fan_out) in net.weight_spans() {
            let span = start..start + fan_in * fan_out;
            let ql = dex_policy::int8::quantise_layer(fan_in, fan_out, &p[span.clone()]);
            for i in 0..fan_in {
                for j in 0..fan_out {
                    let want = f32::from(ql.weights[j * fan_in + i]) * ql.scales[j];
                    assert_eq!(q[start + i * fan_out + j].to_bits(), want.to_bits());
                }
            }
        }
    }

    #[test]
    fn cache_recomputes_only_for_a_new_version() {
        let net = net();
        let mut p = net.init_params(&mut Rng::seed_from_u64(5), 0.5);
        let mut cache = QuantisedCopy::default();
        let first = cache.get(&net, &p, 1).unwrap().to_vec();
        p[0] += 1.0;
        assert_eq!(cache.get(&net, &p, 1).unwrap(), &first[..]);
        assert_ne!(cache.get(&net, &p, 2).unwrap(), &first[..]);
        assert!(fake_quantise(&net, &p[1..], &mut vec![0.0; p.len()]).is_err());
        // Not quantisation-aware: the parameters themselves.
        assert_eq!(cache.select(false, &net, &p, 3).unwrap(), &p[..]);
        assert_ne!(cache.select(true, &net, &p, 3).unwrap(), &p[..]);
    }

    #[test]
    fn active_from_the_given_transition() {
        let c = QuantiseConfig {
            aware_from: Some(10),
        };
        assert!(!c.active(9) && c.active(10) && c.active(11));
        assert!(!QuantiseConfig::default().active(u64::MAX));
    }
}
