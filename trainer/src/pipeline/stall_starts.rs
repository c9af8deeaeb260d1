//! Stall states (issue #26, session 31): where a Stack or Grasp policy's episode gets stuck before
//! its grasp, kept as simulator snapshots that a fine-tune starts episodes from.
//!
//! Why: over 1000 development starts most of the Stack clones' failures are one mode (session 31,
//! docs/experiments.md): the hand comes down on brick 1 with the fingers half closed, stops about
//! a centimetre above the height at which a successful episode closes them, and every command
//! goes to zero for the rest of the episode, a fixed point of the closed loop. Noise-free, such an
//! episode cannot recover; with the recording noise a quarter of the continuations from the stalled
//! state still succeed. From such a state every episode of a group carries the signal that the
//! whole-episode groups of `group_pg` see in only a few percent of their starts: the paper's
//! instructive starts, taken where the policy itself fails.
//!
//! A stall: the reach predicate holds, brick 1 has not been grasped in the episode and lies on
//! the table (below [`TABLE_Z`]), and over the last [`WINDOW`] steps the pinch site moved less
//! than [`STILL_PINCH`] and the three finger angles less than [`STILL_FINGERS`] in all. The
//! first such state of an episode is its stall. A successful grasp never matches: the fingers
//! move fast while they close, and the grasp predicate ends the search.

use std::collections::VecDeque;

use dex_runtime::Mlp as RuntimeMlp;
use serde::{Deserialize, Serialize};

use crate::env::{EnvConfig, EnvSnapshot, JacoEnv, Scene, StepOutcome, Task};
use crate::evaluate::{EVAL_WIDTH, EvalError, controller_command, physical_to_env_action};

/// Steps the hand must have been still.
pub const WINDOW: usize = 10;
/// Most the pinch site may move over [`WINDOW`] steps, metres.
pub const STILL_PINCH: f64 = 0.002;
/// Most the three finger angles may move over [`WINDOW`] steps, summed, radians.
pub const STILL_FINGERS: f32 = 0.05;
/// Brick 1's origin below this height (metres) counts as on the table.
pub const TABLE_Z: f64 = 0.01;

/// Finger angles in the observation (the fingers' positions follow the arm's sines and cosines).
const FINGERS: std::ops::Range<usize> = 12..15;

/// Watches one episode for its stall.
#[derive(Debug, Clone, Default)]
pub struct StallDetector {
    recent: VecDeque<([f64; 3], [f32; 3])>,
    grasped: bool,
    stalled: bool,
}

impl StallDetector {
    /// A detector for a new episode.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feeds the outcome of one step of `env`; true at the episode's first stalled state (and
    /// only there).
    pub fn observe(&mut self, env: &JacoEnv, out: &StepOutcome) -> bool {
        let s = env.reward_state();
        let fingers: [f32; 3] = std::array::from_fn(|k| out.observation[FINGERS.start + k]);
        self.grasped |= out.predicates.grasp;
        self.recent.push_back((s.pinch, fingers));
        if self.recent.len() > WINDOW + 1 {
            self.recent.pop_front();
        }
        if self.stalled
            || self.grasped
            || !out.predicates.reach
            || s.brick1_pos[2] >= TABLE_Z
            || self.recent.len() <= WINDOW
        {
            return false;
        }
        let (p0, f0) = self.recent[0];
        let moved = (0..3)
            .map(|k| (s.pinch[k] - p0[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        let turned: f32 = (0..3).map(|k| (fingers[k] - f0[k]).abs()).sum();
        self.stalled = moved < STILL_PINCH && turned < STILL_FINGERS;
        self.stalled
    }
}

/// Watches one episode for its stall and keeps the state `back` steps before it: the state at
/// the stall's detection (`back` 0), or the one from which the hand was still descending (the
/// detector needs [`WINDOW`] still steps, so `back` above [`WINDOW`] reaches back into the
/// approach, where a policy can still avoid the stall rather than escape it).
#[derive(Debug, Clone)]
pub struct StallWatch {
    detector: StallDetector,
    back: usize,
    ring: VecDeque<EnvSnapshot>,
    found: Option<EnvSnapshot>,
}

impl StallWatch {
    /// A watch for a new episode.
    pub fn new(back: usize) -> Self {
        Self {
            detector: StallDetector::new(),
            back,
            ring: VecDeque::with_capacity(back),
            found: None,
        }
    }

    /// Call before each step with the state the step starts from.
    pub fn before_step(&mut self, env: &JacoEnv) {
        if self.back == 0 || self.found.is_some() {
            return;
        }
        if self.ring.len() == self.back {
            self.ring.pop_front();
        }
        self.ring.push_back(env.snapshot());
    }

    /// Call after each step with its outcome; true at the stall.
    pub fn after_step(&mut self, env: &JacoEnv, out: &StepOutcome) -> bool {
        if !self.detector.observe(env, out) {
            return false;
        }
        // `ring` holds the states before the last `back` steps (fewer near the episode's start;
        // none with `back` 0, when the kept state is the stalled one).
        self.found = Some(self.ring.front().cloned().unwrap_or_else(|| env.snapshot()));
        true
    }

    /// The kept state, if the episode stalled.
    pub fn into_found(self) -> Option<EnvSnapshot> {
        self.found
    }
}

/// A stalled state to start episodes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StallStart {
    /// The start seed of the episode that stalled (names the noise streams of the episodes run
    /// from it).
    pub seed: u64,
    /// The simulation at the stall, or some steps before it ([`StallWatch`]; its step counter
    /// included: episodes from it end at the task's last step, as the stalled one would have).
    pub snapshot: EnvSnapshot,
}

/// The stalls of a policy file's noise-free episodes from `seeds` (through the runtime with CAN
/// quantisation, as `trainer eval` runs it), in seed order: one per episode that stalled and then
/// failed, the state `back` steps before the stall ([`StallWatch`]); and the environment steps
/// run.
pub fn harvest(
    policy: &[u8],
    scene: &Scene,
    task: Task,
    seeds: &[u64],
    back: usize,
    threads: usize,
) -> Result<(Vec<StallStart>, u64), EvalError> {
    let aligned = dex_runtime::aligned::aligned_copy(policy);
    let found = crate::env::parallel::map_in_order(
        seeds.len(),
        threads,
        || -> Result<_, EvalError> {
            let view = crate::evaluate::decode_jaco_policy(aligned.as_bytes())?;
            let mlp = RuntimeMlp::<EVAL_WIDTH>::new(&view)?;
            Ok((mlp, JacoEnv::new(scene, EnvConfig::new(task))))
        },
        |(mlp, env), i| -> Result<(Option<StallStart>, u64), EvalError> {
            let mut o = env.reset(seeds[i])?;
            let mut watch = StallWatch::new(back);
            loop {
                let a = physical_to_env_action(&controller_command(mlp, &o, true, None)?);
                watch.before_step(env);
                let out = env.step(&a)?;
                watch.after_step(env, &out);
                o = out.observation;
                if out.done {
                    let stall = watch.into_found();
                    let found = stall.filter(|_| !out.success).map(|snapshot| StallStart {
                        seed: seeds[i],
                        snapshot,
                    });
                    return Ok((found, u64::from(env.steps_taken())));
                }
            }
        },
        &|| {},
    )?;
    let steps = found.iter().map(|(_, n)| n).sum();
    Ok((found.into_iter().filter_map(|(s, _)| s).collect(), steps))
}
