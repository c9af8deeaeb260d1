//! The learner's view of an environment, and a toy point-mass task used by the tests.
//!
//! The Jaco stacking environment plugs in through a thin adapter implementing [`Env`]. Observations are
//! written into caller-owned slices so a step allocates nothing.

use super::rng::Rng;

/// What one environment step reports besides the observation.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Step {
    /// Reward for this transition.
    pub reward: f32,
    /// The episode ended in a terminal state: the value of the next state is zero (no bootstrap).
    pub terminal: bool,
    /// The episode was cut by a time limit: it ends, but the next state is still bootstrapped.
    pub truncated: bool,
    /// The task's success predicate holds after this step. An episode counts as a success if this is
    /// true at its last step.
    pub success: bool,
}

impl Step {
    /// True when the episode ends after this step.
    pub fn done(&self) -> bool {
        self.terminal || self.truncated
    }
}

/// A continuous-control environment with actions in `[-1, 1]^act_dim`.
pub trait Env {
    /// Length of the observation vector.
    fn obs_dim(&self) -> usize;
    /// Length of the action vector.
    fn act_dim(&self) -> usize;
    /// Starts a new episode from a random initial state drawn from `rng`; writes the first observation.
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]);
    /// Applies `action` (each component in `[-1, 1]`); writes the next observation.
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Step;
    /// Writes the teacher's action at the current state into `action` and returns true; false
    /// (the default) for an environment without a teacher. Used by runs with
    /// [`crate::learn::RunConfig::teacher_labels`].
    fn expert_action(&mut self, action: &mut [f32]) -> bool {
        let _ = action;
        false
    }

    /// Starts an evaluation episode. Environments whose training episodes start elsewhere (instructive
    /// start states) or run shorter override this so that evaluation keeps the task's own starts and
    /// length; by default it is [`Env::reset`].
    fn reset_eval(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        self.reset(rng, obs);
    }
}

impl<E: Env + ?Sized> Env for Box<E> {
    fn obs_dim(&self) -> usize {
        (**self).obs_dim()
    }
    fn act_dim(&self) -> usize {
        (**self).act_dim()
    }
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        (**self).reset(rng, obs)
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Step {
        (**self).step(action, obs)
    }
    fn expert_action(&mut self, action: &mut [f32]) -> bool {
        (**self).expert_action(action)
    }
    fn reset_eval(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        (**self).reset_eval(rng, obs)
    }
}

/// Settings of [`PointMass`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointMassConfig {
    /// Steps per episode (then the episode is truncated).
    pub episode_steps: usize,
    /// Distance to the goal that counts as success.
    pub success_radius: f32,
    /// Largest displacement per step along each axis (the action scales it).
    pub max_speed: f32,
}

impl Default for PointMassConfig {
    fn default() -> Self {
        PointMassConfig {
            episode_steps: 25,
            success_radius: 0.1,
            max_speed: 0.1,
        }
    }
}

/// A point in the unit square that must move to a random goal and stay there.
///
/// Observation (6): position, goal, goal minus position. Action (2): velocity command. Reward:
/// minus the distance to the goal, plus 1 inside the success radius. Success: inside the radius at the
/// episode's last step. A random policy succeeds in about 3% of episodes.
#[derive(Debug, Clone)]
pub struct PointMass {
    cfg: PointMassConfig,
    pos: [f32; 2],
    goal: [f32; 2],
    t: usize,
}

impl PointMass {
    /// A new environment (call [`Env::reset`] before stepping).
    pub fn new(cfg: PointMassConfig) -> Self {
        PointMass {
            cfg,
            pos: [0.0; 2],
            goal: [0.0; 2],
            t: 0,
        }
    }

    fn write_obs(&self, obs: &mut [f32]) {
        let v = [
            self.pos[0],
            self.pos[1],
            self.goal[0],
            self.goal[1],
            self.goal[0] - self.pos[0],
            self.goal[1] - self.pos[1],
        ];
        let n = obs.len().min(6);
        obs[..n].copy_from_slice(&v[..n]);
    }

    fn distance(&self) -> f32 {
        ((self.goal[0] - self.pos[0]).powi(2) + (self.goal[1] - self.pos[1]).powi(2)).sqrt()
    }
}

impl Env for PointMass {
    fn obs_dim(&self) -> usize {
        6
    }

    fn act_dim(&self) -> usize {
        2
    }

    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        self.pos = [rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)];
        self.goal = [rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)];
        self.t = 0;
        self.write_obs(obs);
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Step {
        for (k, p) in self.pos.iter_mut().enumerate() {
            let a = action.get(k).copied().unwrap_or(0.0);
            let a = if a.is_finite() {
                a.clamp(-1.0, 1.0)
            } else {
                0.0
            };
            *p = (*p + self.cfg.max_speed * a).clamp(-1.0, 1.0);
        }
        self.t += 1;
        self.write_obs(obs);
        let d = self.distance();
        let inside = d < self.cfg.success_radius;
        Step {
            reward: -d + if inside { 1.0 } else { 0.0 },
            terminal: false,
            truncated: self.t >= self.cfg.episode_steps,
            success: inside,
        }
    }

    /// The teacher: straight at the goal, as fast as the action allows.
    fn expert_action(&mut self, action: &mut [f32]) -> bool {
        for (k, a) in action.iter_mut().take(2).enumerate() {
            *a = ((self.goal[k] - self.pos[k]) / self.cfg.max_speed).clamp(-1.0, 1.0);
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_mass_moves_toward_commanded_direction_and_truncates() {
        let mut env = PointMass::new(PointMassConfig::default());
        let mut obs = [0.0; 6];
        env.reset(&mut Rng::seed_from_u64(2), &mut obs);
        let d0 = env.distance();
        let mut last = Step::default();
        for _ in 0..25 {
            let dir = [
                (obs[4] / 0.1).clamp(-1.0, 1.0),
                (obs[5] / 0.1).clamp(-1.0, 1.0),
            ];
            last = env.step(&dir, &mut obs);
        }
        assert!(last.truncated && !last.terminal);
        assert!(env.distance() < d0.max(0.15));
        assert!(last.success);
    }
}
