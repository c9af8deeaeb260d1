//! The Jaco environment seen through the learner's [`Env`] trait.

use dex_runtime::interface::{ACT_DIM, OBS_DIM};

use crate::env::{EnvConfig, EnvError, JacoEnv, Scene};
use crate::learn::{Env, Rng, Step};

/// A [`JacoEnv`] driven by the learner: episodes start from seeds drawn from the learner's generator and
/// end at the task's step budget (a time limit: the last state is still bootstrapped).
///
/// The learner's trait has no error channel, so a simulation error (a diverged state, which a
/// clipped, finite action should never cause) ends the episode with zero reward and is counted in
/// [`JacoLearnEnv::errors`]; the caller reports the count.
#[derive(Debug)]
pub struct JacoLearnEnv {
    env: JacoEnv,
    max_steps: u32,
    /// Simulation errors met so far (each ended its episode).
    pub errors: u64,
    /// The last error met, for reporting.
    pub last_error: Option<EnvError>,
}

impl JacoLearnEnv {
    /// An environment for `config` over the shared `scene`.
    pub fn new(scene: &Scene, config: EnvConfig) -> Self {
        JacoLearnEnv {
            max_steps: config.episode_steps,
            env: JacoEnv::new(scene, config),
            errors: 0,
            last_error: None,
        }
    }

    /// The wrapped environment.
    pub fn inner(&self) -> &JacoEnv {
        &self.env
    }

    fn fail(&mut self, e: EnvError) -> Step {
        self.errors += 1;
        self.last_error = Some(e);
        Step {
            reward: 0.0,
            terminal: true,
            truncated: false,
            success: false,
        }
    }
}

impl Env for JacoLearnEnv {
    fn obs_dim(&self) -> usize {
        OBS_DIM
    }

    fn act_dim(&self) -> usize {
        ACT_DIM
    }

    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        // A start state that cannot be made within the attempts is retried from fresh seeds.
        for _ in 0..8 {
            match self.env.reset(rng.next_u64()) {
                Ok(o) => {
                    let n = obs.len().min(OBS_DIM);
                    obs[..n].copy_from_slice(&o[..n]);
                    return;
                }
                Err(e) => {
                    self.errors += 1;
                    self.last_error = Some(e);
                }
            }
        }
        obs.fill(0.0);
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Step {
        let mut a = [0.0f32; ACT_DIM];
        let n = action.len().min(ACT_DIM);
        a[..n].copy_from_slice(&action[..n]);
        match self.env.step(&a) {
            Ok(out) => {
                let m = obs.len().min(OBS_DIM);
                obs[..m].copy_from_slice(&out.observation[..m]);
                Step {
                    reward: out.reward,
                    terminal: false,
                    truncated: out.done || self.env.steps_taken() >= self.max_steps,
                    success: out.success,
                }
            }
            Err(e) => self.fail(e),
        }
    }
}
