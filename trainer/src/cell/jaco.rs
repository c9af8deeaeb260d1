//! The Jaco environment seen through the learner's [`Env`] trait.

use dex_runtime::features::{INPUT_MAX, policy_input};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};

use crate::cell::policy_demo::DemoSource;
use crate::env::{
    Demonstrator, EnvConfig, EnvError, JacoEnv, MarkovDemonstrator, Observation, Scene,
    StartScheme, StartStates,
};
use crate::learn::{Env, Rng, Step};

/// A [`JacoEnv`] driven by the learner: episodes start from seeds drawn from the learner's generator and
/// end at the step budget (a time limit: the last state is still bootstrapped).
///
/// Training episodes start as the [`StartScheme`] says (and run its training length); evaluation
/// episodes ([`Env::reset_eval`]) always start from the task's original starts and run the task's full
/// length, so curves of different schemes compare.
///
/// The learner's trait has no error channel, so a simulation error (a diverged state, which a
/// clipped, finite action should never cause) ends the episode with zero reward and is counted in
/// [`JacoLearnEnv::errors`]; the caller reports the count.
#[derive(Debug)]
pub struct JacoLearnEnv {
    env: JacoEnv,
    starts: StartStates<DemoSource>,
    train_steps: u32,
    eval_steps: u32,
    max_steps: u32,
    /// Simulation errors met so far (each ended its episode).
    pub errors: u64,
    /// The last error met, for reporting.
    pub last_error: Option<EnvError>,
    /// The teacher of a run with teacher labels: the Markov demonstrator of the task.
    teacher: MarkovDemonstrator,
    /// Observations carry the task features after them (`dex_runtime::features`).
    features: bool,
}

impl JacoLearnEnv {
    /// An environment for `config` over the shared `scene`, training from the original starts.
    pub fn new(scene: &Scene, config: EnvConfig) -> Self {
        JacoLearnEnv {
            max_steps: config.episode_steps,
            train_steps: config.episode_steps,
            eval_steps: config.episode_steps,
            starts: StartStates::original(DemoSource::Scripted(Demonstrator::new(config.task))),
            env: JacoEnv::new(scene, config),
            errors: 0,
            last_error: None,
            teacher: MarkovDemonstrator::new(config.task),
            features: false,
        }
    }

    /// The same environment, its observations followed by the controller's task features
    /// (`dex_runtime::features`) when `features`: what a policy that takes them sees.
    pub fn with_features(mut self, features: bool) -> Self {
        self.features = features;
        self
    }

    /// Writes `o` (and its task features, when on) into the learner's observation buffer.
    fn write_obs(&self, o: &Observation, obs: &mut [f32]) {
        let mut buf = [0.0f32; INPUT_MAX];
        let x = policy_input(o, self.obs_dim(), &mut buf);
        let n = obs.len().min(x.len());
        obs[..n].copy_from_slice(&x[..n]);
    }

    /// An environment whose training episodes start under `scheme` (scripted demonstrations).
    pub fn with_starts(
        scene: &Scene,
        config: EnvConfig,
        scheme: StartScheme,
    ) -> Result<Self, EnvError> {
        Ok(Self::with_start_states(
            scene,
            config,
            StartStates::new(scheme, DemoSource::Scripted(Demonstrator::new(config.task)))?,
        ))
    }

    /// An environment whose training episodes start from `starts` (already validated; clone one
    /// per worker).
    pub fn with_start_states(
        scene: &Scene,
        config: EnvConfig,
        starts: StartStates<DemoSource>,
    ) -> Self {
        let mut env = Self::new(scene, config);
        env.train_steps = starts.scheme().train_episode_steps(config.episode_steps);
        env.max_steps = env.train_steps;
        env.starts = starts;
        env
    }

    /// The wrapped environment.
    pub fn inner(&self) -> &JacoEnv {
        &self.env
    }

    /// Runs `make` from fresh seeds until it gives a start (at most 8 tries; each failure is counted).
    fn start(
        &mut self,
        rng: &mut Rng,
        obs: &mut [f32],
        make: impl Fn(&mut JacoEnv, &mut StartStates<DemoSource>, u64) -> Result<Observation, EnvError>,
    ) {
        for _ in 0..8 {
            match make(&mut self.env, &mut self.starts, rng.next_u64()) {
                Ok(o) => {
                    self.write_obs(&o, obs);
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
        if self.features { INPUT_MAX } else { OBS_DIM }
    }

    fn act_dim(&self) -> usize {
        ACT_DIM
    }

    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        self.max_steps = self.train_steps;
        self.start(rng, obs, |env, starts, seed| {
            starts.reset(env, seed).map(|h| h.observation)
        });
    }

    /// The task's Markov demonstrator (its action is a function of the state alone: a label for
    /// any state the learner visits).
    fn expert_action(&mut self, action: &mut [f32]) -> bool {
        let a = self.teacher.act(&self.env);
        let n = action.len().min(ACT_DIM);
        action[..n].copy_from_slice(&a[..n]);
        true
    }

    fn reset_eval(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        self.max_steps = self.eval_steps;
        self.start(rng, obs, |env, _, seed| env.reset(seed));
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Step {
        let mut a = [0.0f32; ACT_DIM];
        let n = action.len().min(ACT_DIM);
        a[..n].copy_from_slice(&action[..n]);
        match self.env.step(&a) {
            Ok(out) => {
                self.write_obs(&out.observation, obs);
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
