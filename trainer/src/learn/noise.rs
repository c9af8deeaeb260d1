//! Exploration noise on the actor's output: white Gaussian (the paper's), or temporally correlated
//! (a first-order autoregressive process, the discrete Ornstein-Uhlenbeck), with a per-joint scale.
//!
//! Why correlated: at 20 Hz, white noise of 0.1 on a finger's velocity command flips the grip every
//! step (the finger action is nearly binary against a brick), while the same variance held for a few
//! steps moves the arm somewhere new. The process is `x_t = rho x_{t-1} + sqrt(1 - rho^2) e_t`,
//! `e_t ~ N(0, 1)`, so every `x_t` has unit variance whatever `rho`; the executed action is
//! `clip(mu(s) + std * scale_j * x_t, -1, 1)`. With `correlation` 0 the draws (and so a seeded run)
//! are exactly the white noise's.

use super::LearnError;
use super::rng::Rng;
use serde::{Deserialize, Serialize};

/// Exploration noise settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseConfig {
    /// Standard deviation per action component (before `scale`).
    pub std: f32,
    /// Autoregressive coefficient `rho` in `[0, 1)`: 0 is white noise; 0.9 keeps a draw for about
    /// ten steps (half a second at 20 Hz).
    pub correlation: f32,
    /// Per-component multipliers of `std` (empty: 1 for every component), e.g. smaller for the
    /// fingers than for the arm joints.
    pub scale: Vec<f32>,
}

impl Default for NoiseConfig {
    fn default() -> Self {
        NoiseConfig {
            std: 0.2,
            correlation: 0.0,
            scale: Vec::new(),
        }
    }
}

impl NoiseConfig {
    /// Checks the ranges, and with `act_dim` known that `scale` has one entry per component.
    pub fn validate(&self, act_dim: Option<usize>) -> Result<(), LearnError> {
        let bad = |field, why| Err(LearnError::Config { field, why });
        if !(self.std >= 0.0 && self.std.is_finite()) {
            return bad("noise.std", "must be finite and non-negative");
        }
        if !(0.0..1.0).contains(&self.correlation) {
            return bad("noise.correlation", "must be in [0, 1)");
        }
        if act_dim.is_some_and(|d| !self.scale.is_empty() && self.scale.len() != d) {
            return bad(
                "noise.scale",
                "needs one multiplier per action component (or none)",
            );
        }
        if self.scale.iter().any(|s| !(*s >= 0.0 && s.is_finite())) {
            return bad("noise.scale", "multipliers must be finite and non-negative");
        }
        Ok(())
    }
}

/// One worker's noise process (its state is the last `x` per component).
#[derive(Debug, Clone)]
pub struct ExplorationNoise {
    cfg: NoiseConfig,
    x: Vec<f32>,
}

impl ExplorationNoise {
    /// A process for `act_dim` components (call [`ExplorationNoise::reset`] at each episode start).
    pub fn new(cfg: &NoiseConfig, act_dim: usize) -> Self {
        ExplorationNoise {
            cfg: cfg.clone(),
            x: vec![0.0; act_dim],
        }
    }

    /// Starts a new episode: a correlated process draws its state from the stationary distribution;
    /// white noise draws nothing (so its random stream is the plain Gaussian one).
    pub fn reset(&mut self, rng: &mut Rng) {
        if self.cfg.correlation > 0.0 {
            for x in &mut self.x {
                *x = rng.normal(0.0, 1.0);
            }
        }
    }

    fn scale(&self, j: usize) -> f32 {
        self.cfg.std * self.cfg.scale.get(j).copied().unwrap_or(1.0)
    }

    /// Writes the next noise vector (`std * scale_j * x_j`, before any clipping) into `noise`,
    /// advancing the process one step. White noise draws `N(0, (std * scale_j)^2)` per
    /// component, the plain Gaussian stream.
    pub fn draw(&mut self, rng: &mut Rng, noise: &mut [f32]) {
        let rho = self.cfg.correlation;
        if rho == 0.0 {
            for (j, n) in noise.iter_mut().enumerate() {
                *n = rng.normal(0.0, self.scale(j));
            }
            return;
        }
        let innovation = (1.0 - rho * rho).sqrt();
        for j in 0..noise.len().min(self.x.len()) {
            self.x[j] = rho * self.x[j] + innovation * rng.normal(0.0, 1.0);
            noise[j] = self.scale(j) * self.x[j];
        }
    }

    /// Writes `clip(mean + noise, -1, 1)` into `action`, advancing the process one step
    /// ([`ExplorationNoise::draw`]).
    pub fn perturb(&mut self, rng: &mut Rng, mean: &[f32], action: &mut [f32]) {
        let n = action.len().min(mean.len());
        self.draw(rng, &mut action[..n]);
        for (a, &m) in action[..n].iter_mut().zip(mean) {
            *a = (m + *a).clamp(-1.0, 1.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn draws(cfg: &NoiseConfig, steps: usize, seed: u64) -> Vec<Vec<f32>> {
        let mut rng = Rng::seed_from_u64(seed);
        let mut n = ExplorationNoise::new(cfg, 2);
        n.reset(&mut rng);
        (0..steps)
            .map(|_| {
                let mut a = [0.0f32; 2];
                n.perturb(&mut rng, &[0.0, 0.0], &mut a);
                a.to_vec()
            })
            .collect()
    }

    fn lag1(v: &[f32]) -> f64 {
        let m = v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|&x| (f64::from(x) - m).powi(2)).sum::<f64>();
        let cov = v
            .windows(2)
            .map(|w| (f64::from(w[0]) - m) * (f64::from(w[1]) - m))
            .sum::<f64>();
        cov / var
    }

    #[test]
    fn white_noise_matches_plain_gaussian_draws() {
        let cfg = NoiseConfig {
            std: 0.1,
            ..NoiseConfig::default()
        };
        let got = draws(&cfg, 50, 3);
        let mut rng = Rng::seed_from_u64(3);
        for row in &got {
            for &a in row {
                assert_eq!(a, rng.normal(0.0, 0.1).clamp(-1.0, 1.0));
            }
        }
    }

    #[test]
    fn correlated_noise_keeps_its_variance_and_has_the_lag_one_correlation() {
        let cfg = NoiseConfig {
            std: 0.1,
            correlation: 0.9,
            scale: vec![1.0, 0.5],
        };
        let got = draws(&cfg, 20_000, 1);
        let first: Vec<f32> = got.iter().map(|r| r[0]).collect();
        let second: Vec<f32> = got.iter().map(|r| r[1]).collect();
        let sd = |v: &[f32]| {
            (v.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
        };
        assert!((sd(&first) - 0.1).abs() < 0.01, "std {}", sd(&first));
        assert!((sd(&second) - 0.05).abs() < 0.005, "std {}", sd(&second));
        let r = lag1(&first);
        assert!((r - 0.9).abs() < 0.03, "lag-1 correlation {r}");
        let white = draws(
            &NoiseConfig {
                std: 0.1,
                ..NoiseConfig::default()
            },
            20_000,
            1,
        );
        let w: Vec<f32> = white.iter().map(|r| r[0]).collect();
        assert!(lag1(&w).abs() < 0.03);
    }

    #[test]
    fn bad_settings_are_refused() {
        let ok = NoiseConfig::default();
        assert!(ok.validate(Some(9)).is_ok());
        for bad in [
            NoiseConfig {
                correlation: 1.0,
                ..ok.clone()
            },
            NoiseConfig {
                std: f32::NAN,
                ..ok.clone()
            },
            NoiseConfig {
                scale: vec![1.0; 3],
                ..ok.clone()
            },
            NoiseConfig {
                scale: vec![-1.0; 9],
                ..ok.clone()
            },
        ] {
            assert!(bad.validate(Some(9)).is_err(), "{bad:?}");
        }
    }
}
