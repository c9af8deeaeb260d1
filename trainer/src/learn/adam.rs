//! Adam with the ADPG-R split: each worker keeps its own first moment, all workers share one second
//! moment (Popov et al. 2017). DPG-R is the one-worker case, where this is plain Adam.
//!
//! The shared half ([`AdamShared`]) lives next to the shared parameters and is only touched under the same
//! lock; the local half ([`AdamLocal`]) belongs to a worker thread. Each half counts its own steps for its
//! bias correction.

use serde::{Deserialize, Serialize};

/// Adam hyper-parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdamConfig {
    /// Step size.
    pub lr: f32,
    /// First-moment decay.
    pub beta1: f32,
    /// Second-moment decay.
    pub beta2: f32,
    /// Added to the root of the second moment.
    pub eps: f32,
}

impl Default for AdamConfig {
    fn default() -> Self {
        AdamConfig {
            lr: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

/// The shared second moment and its step count.
#[derive(Debug, Clone, PartialEq)]
pub struct AdamShared {
    /// Running mean of squared gradients, one per parameter.
    pub v: Vec<f32>,
    /// Number of updates applied by all workers.
    pub t: u64,
}

impl AdamShared {
    /// Zeroed state for `n` parameters.
    pub fn new(n: usize) -> Self {
        AdamShared {
            v: vec![0.0; n],
            t: 0,
        }
    }
}

/// One worker's first moment and its step count.
#[derive(Debug, Clone, PartialEq)]
pub struct AdamLocal {
    /// Running mean of gradients, one per parameter.
    pub m: Vec<f32>,
    /// Number of updates applied by this worker.
    pub t: u64,
}

impl AdamLocal {
    /// Zeroed state for `n` parameters.
    pub fn new(n: usize) -> Self {
        AdamLocal {
            m: vec![0.0; n],
            t: 0,
        }
    }
}

/// Moments below this magnitude are set to zero.
const FLUSH: f32 = 1e-30;

/// Applies one Adam step to `params` with gradient `grads` (same lengths; extra elements are ignored).
pub fn adam_step(
    cfg: &AdamConfig,
    params: &mut [f32],
    grads: &[f32],
    local: &mut AdamLocal,
    shared: &mut AdamShared,
) {
    local.t += 1;
    shared.t += 1;
    let c1 = 1.0 - f64::from(cfg.beta1).powf(local.t as f64);
    let c2 = 1.0 - f64::from(cfg.beta2).powf(shared.t as f64);
    // lr * m_hat / (sqrt(v_hat) + eps) = (lr / c1) * m / (sqrt(v / c2) + eps)
    let step = (f64::from(cfg.lr) / c1) as f32;
    let inv_c2 = (1.0 / c2) as f32;
    let (b1, b2) = (cfg.beta1, cfg.beta2);
    for (((p, &g), m), v) in params
        .iter_mut()
        .zip(grads)
        .zip(local.m.iter_mut())
        .zip(shared.v.iter_mut())
    {
        // Moments of parameters whose gradient stays zero (dead ReLU units) decay geometrically into
        // subnormal floats, which cost ~100x on x86; flush them to zero (no effect on the step taken).
        let mm = b1 * *m + (1.0 - b1) * g;
        let vv = b2 * *v + (1.0 - b2) * g * g;
        *m = if mm.abs() < FLUSH { 0.0 } else { mm };
        *v = if vv < FLUSH { 0.0 } else { vv };
        *p -= step * *m / ((*v * inv_c2).sqrt() + cfg.eps);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_textbook_adam_for_one_worker() {
        // Reference (PyTorch's torch.optim.Adam semantics), in f64:
        //   m = b1 m + (1-b1) g; v = b2 v + (1-b2) g^2; p -= lr m/(1-b1^t) / (sqrt(v/(1-b2^t)) + eps)
        let cfg = AdamConfig::default();
        let mut p = vec![0.5f32, -1.0];
        let mut local = AdamLocal::new(2);
        let mut shared = AdamShared::new(2);
        let (mut rp, mut rm, mut rv) = ([0.5f64, -1.0], [0.0f64; 2], [0.0f64; 2]);
        for t in 1..=5 {
            let g = [p[0] * 2.0, p[1] * 2.0 + 0.1];
            adam_step(&cfg, &mut p, &g, &mut local, &mut shared);
            let g64 = [rp[0] * 2.0, rp[1] * 2.0 + 0.1];
            for i in 0..2 {
                rm[i] = 0.9 * rm[i] + 0.1 * g64[i];
                rv[i] = 0.999 * rv[i] + 0.001 * g64[i] * g64[i];
                let mh = rm[i] / (1.0 - 0.9f64.powi(t));
                let vh = rv[i] / (1.0 - 0.999f64.powi(t));
                rp[i] -= 1e-3 * mh / (vh.sqrt() + 1e-8);
            }
        }
        for i in 0..2 {
            assert!((f64::from(p[i]) - rp[i]).abs() < 1e-6);
        }
    }

    #[test]
    fn second_moment_is_shared_first_is_not() {
        let cfg = AdamConfig::default();
        let mut p = vec![0.0f32; 1];
        let mut shared = AdamShared::new(1);
        let mut a = AdamLocal::new(1);
        let mut b = AdamLocal::new(1);
        adam_step(&cfg, &mut p, &[1.0], &mut a, &mut shared);
        adam_step(&cfg, &mut p, &[-1.0], &mut b, &mut shared);
        assert_eq!(shared.t, 2);
        assert_eq!((a.t, b.t), (1, 1));
        assert!(a.m[0] > 0.0 && b.m[0] < 0.0);
        assert!((shared.v[0] - (0.999 * 0.001 + 0.001)).abs() < 1e-7);
    }
}
