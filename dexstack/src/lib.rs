//! `dexstack._core`: the Rust side of the `dexstack` Python package (PyO3, abi3).
//!
//! The Gymnasium classes are Python (`python/dexstack/`); they call these:
//! - [`Env`]: one Jaco environment ([`episode::Episode`]): `reset(seed)`, `step(action_bytes)`.
//! - [`VecEnv`]: N environments stepped on Rust threads with the GIL released ([`vector::Batch`]).
//! - [`Demonstrator`]: the scripted (or Markov) demonstrator acting on an [`Env`].
//! - [`Policy`]: a `.dxpl` file run through the runtime's evaluator ([`policy::LoadedPolicy`]).
//! - For the renderer ([`render`]): `scene_mjb()` (the compiled scene as MuJoCo's binary model),
//!   `camera_names()`, and `render_state()` of an [`Env`] or of one environment of a [`VecEnv`]
//!   (its MuJoCo state, copied only when Python draws a frame).
//!
//! Arrays cross the boundary as native-endian float32 bytes (the Python side checks dtype and
//! shape with numpy first; the Rust side checks sizes and finiteness again and refuses before
//! anything changes). Errors are [`error::Error`]s: bad input becomes `ValueError`, a failing
//! simulation `RuntimeError`, a missing file `OSError`.

pub mod episode;
pub mod error;
pub mod onnx;
pub mod policy;
pub mod render;
pub mod vector;

use dex_env::{MarkovDemonstrator, Reward, StartKind, Task};
use dex_runtime::interface::{
    ACT_DIM, ACTION_JOINTS, CONTROL_PERIOD_US, OBS_DIM, OBSERVATION_FIELDS,
};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::episode::{Episode, Options, Outcome};
use crate::error::Error;
use crate::vector::{Batch, Command};

/// Native-endian float32 values from bytes; `what` names them in the error.
fn floats(bytes: &[u8], what: &'static str, expected: usize) -> Result<Vec<f32>, Error> {
    if bytes.len() != expected * 4 {
        return Err(Error::Shape {
            what,
            got: bytes.len() / 4,
            expected,
        });
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|c| f32::from_ne_bytes([c[0], c[1], c[2], c[3]]))
        .collect())
}

fn action(bytes: &[u8]) -> Result<[f32; ACT_DIM], Error> {
    let v = floats(bytes, "action", ACT_DIM)?;
    let mut a = [0.0f32; ACT_DIM];
    a.copy_from_slice(&v);
    Ok(a)
}

fn to_bytes<'py>(py: Python<'py>, values: &[f32]) -> Bound<'py, PyBytes> {
    let raw: Vec<u8> = values.iter().flat_map(|v| v.to_ne_bytes()).collect();
    PyBytes::new(py, &raw)
}

/// What `Env.reset` hands to Python: observation bytes, the start info dict, and success, reach,
/// grasp and stack of the start state.
type ResetTuple<'py> = (
    Bound<'py, PyBytes>,
    Bound<'py, PyDict>,
    bool,
    bool,
    bool,
    bool,
);

/// (observation bytes, reward, truncated, success, reach, grasp, stack).
type StepTuple<'py> = (Bound<'py, PyBytes>, f32, bool, bool, bool, bool, bool);

fn step_tuple<'py>(py: Python<'py>, o: &Outcome) -> StepTuple<'py> {
    (
        to_bytes(py, &o.observation),
        o.reward,
        o.truncated,
        o.success,
        o.predicates.reach,
        o.predicates.grasp,
        o.predicates.stack,
    )
}

fn start_dict<'py>(py: Python<'py>, kind: StartKind) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("start", episode::start_kind_name(kind))?;
    if let StartKind::Demonstration { k, n, solved } = kind {
        d.set_item("demonstration_steps", (k, n))?;
        d.set_item("demonstration_solved", solved)?;
    }
    Ok(d)
}

/// One Jaco environment (the Rust `JacoEnv` with its start scheme and time limit).
#[pyclass(module = "dexstack._core")]
pub struct Env {
    episode: Episode,
}

#[pymethods]
impl Env {
    /// `Env(task, reward=None, start="original", episode_steps=None, in_hand_probability=0.5)`.
    #[new]
    #[pyo3(signature = (task, reward=None, start="original", episode_steps=None, in_hand_probability=0.5))]
    fn new(
        task: &str,
        reward: Option<&str>,
        start: &str,
        episode_steps: Option<u32>,
        in_hand_probability: f64,
    ) -> PyResult<Self> {
        let options = Options::parse(task, reward, start, episode_steps, in_hand_probability)?;
        Ok(Env {
            episode: Episode::new(options)?,
        })
    }

    /// Starts an episode from the 64-bit `seed`; returns (observation bytes, start info dict,
    /// success, reach, grasp, stack of the start state).
    fn reset<'py>(&mut self, py: Python<'py>, seed: u64) -> PyResult<ResetTuple<'py>> {
        let episode = &mut self.episode;
        let obs = py.detach(|| episode.reset(seed))?;
        let p = self.episode.env().predicates();
        let success = self.episode.options().task.is_success(p);
        Ok((
            to_bytes(py, &obs),
            start_dict(py, self.episode.start_kind())?,
            success,
            p.reach,
            p.grasp,
            p.stack,
        ))
    }

    /// One control step with 9 float32 values (bytes); returns (observation bytes, reward,
    /// truncated, success, reach, grasp, stack).
    fn step<'py>(&mut self, py: Python<'py>, action_bytes: &[u8]) -> PyResult<StepTuple<'py>> {
        let a = action(action_bytes)?;
        let episode = &mut self.episode;
        let out = py.detach(|| episode.step(&a))?;
        Ok(step_tuple(py, &out))
    }

    /// The current observation (bytes).
    fn observation<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        to_bytes(py, self.episode.env().observation())
    }

    /// The MuJoCo state (float64 bytes in the `STATE_SPEC` layout) for the renderer.
    fn render_state<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &render::state_bytes(self.episode.env()))
    }

    /// Control steps taken in the episode.
    #[getter]
    fn steps_taken(&self) -> u32 {
        self.episode.env().steps_taken()
    }

    /// The time limit.
    #[getter]
    fn episode_steps(&self) -> u32 {
        self.episode.options().episode_steps
    }

    /// The task (kebab-case).
    #[getter]
    fn task(&self) -> String {
        episode::task_name(self.episode.options().task)
    }

    /// The reward function (kebab-case).
    #[getter]
    fn reward(&self) -> String {
        episode::reward_name(self.episode.options().reward)
    }
}

/// N environments of one configuration, stepped on Rust threads with the GIL released.
#[pyclass(module = "dexstack._core")]
pub struct VecEnv {
    batch: Batch,
}

/// (observations, rewards, truncated, success, reach, grasp, stack) of a batch.
type BatchTuple<'py> = (
    Bound<'py, PyBytes>,
    Bound<'py, PyBytes>,
    Vec<bool>,
    Vec<bool>,
    Vec<bool>,
    Vec<bool>,
    Vec<bool>,
);

#[pymethods]
impl VecEnv {
    /// `VecEnv(num_envs, task, reward=None, start="original", episode_steps=None,
    /// in_hand_probability=0.5, threads=0)`; `threads=0`: one per core, at most `num_envs`.
    #[new]
    #[pyo3(signature = (num_envs, task, reward=None, start="original", episode_steps=None, in_hand_probability=0.5, threads=0))]
    fn new(
        num_envs: usize,
        task: &str,
        reward: Option<&str>,
        start: &str,
        episode_steps: Option<u32>,
        in_hand_probability: f64,
        threads: usize,
    ) -> PyResult<Self> {
        let options = Options::parse(task, reward, start, episode_steps, in_hand_probability)?;
        Ok(VecEnv {
            batch: Batch::new(options, num_envs, threads)?,
        })
    }

    /// Runs one batch step: environment `k` is reset from `seeds[k]` where that is not `None`
    /// (its action ignored), else stepped with its 9 values of `actions_bytes` (N*9 float32).
    fn step<'py>(
        &mut self,
        py: Python<'py>,
        actions_bytes: &[u8],
        seeds: Vec<Option<u64>>,
    ) -> PyResult<(BatchTuple<'py>, Vec<Py<PyDict>>)> {
        let n = self.batch.len();
        let actions = floats(actions_bytes, "actions", n * ACT_DIM)?;
        let commands: Vec<Command> = seeds
            .iter()
            .map(|s| s.map_or(Command::Step, Command::Reset))
            .collect();
        let batch = &mut self.batch;
        let out = py.detach(|| batch.step(&actions, &commands))?;
        let mut starts = Vec::with_capacity(n);
        for (env, s) in self.batch.envs().iter().zip(&seeds) {
            let d = PyDict::new(py);
            if s.is_some() {
                d.update(start_dict(py, env.start_kind())?.as_mapping())?;
            }
            starts.push(d.unbind());
        }
        Ok((
            (
                to_bytes(py, &out.observations),
                to_bytes(py, &out.rewards),
                out.truncated,
                out.success,
                out.reach,
                out.grasp,
                out.stack,
            ),
            starts,
        ))
    }

    /// Number of environments.
    #[getter]
    fn num_envs(&self) -> usize {
        self.batch.len()
    }

    /// Threads a step uses.
    #[getter]
    fn threads(&self) -> usize {
        self.batch.threads()
    }

    /// The MuJoCo state of environment `index` (float64 bytes in the `STATE_SPEC` layout) for the
    /// renderer.
    fn render_state<'py>(&self, py: Python<'py>, index: usize) -> PyResult<Bound<'py, PyBytes>> {
        let envs = self.batch.envs();
        let episode = envs.get(index).ok_or_else(|| {
            Error::BadOption(format!(
                "environment index {index} is out of range (num_envs = {})",
                envs.len()
            ))
        })?;
        Ok(PyBytes::new(py, &render::state_bytes(episode.env())))
    }
}

/// The scripted demonstrator of a task (or the Markov one), acting on an [`Env`]. It restarts its
/// script by itself when the environment starts a new episode.
#[pyclass(module = "dexstack._core")]
pub struct Demonstrator {
    task: Task,
    kind: DemoKind,
    episode: Option<(u64, u64)>,
}

enum DemoKind {
    Scripted(dex_env::Demonstrator),
    Markov(MarkovDemonstrator),
}

#[pymethods]
impl Demonstrator {
    /// `Demonstrator(task, kind="scripted")`; kind `markov` is the demonstrator whose action is a
    /// function of the state alone.
    #[new]
    #[pyo3(signature = (task, kind="scripted"))]
    fn new(task: &str, kind: &str) -> PyResult<Self> {
        let task = episode::parse_task(task)?;
        let kind = match kind {
            "scripted" => DemoKind::Scripted(dex_env::Demonstrator::new(task)),
            "markov" => DemoKind::Markov(MarkovDemonstrator::new(task)),
            other => return Err(Error::UnknownDemonstrator(other.to_owned()).into()),
        };
        Ok(Demonstrator {
            task,
            kind,
            episode: None,
        })
    }

    /// The normalised action (9 float32 bytes) for the environment's current state.
    fn act<'py>(&mut self, py: Python<'py>, env: PyRef<'_, Env>) -> Bound<'py, PyBytes> {
        let ep = &env.episode;
        let key = ep.episode_key();
        let a = match &mut self.kind {
            DemoKind::Scripted(d) => {
                if self.episode != Some(key) {
                    if ep.start_kind() == StartKind::Original {
                        d.restart();
                    } else {
                        d.restart_from_state(ep.env());
                    }
                }
                d.act(ep.env())
            }
            DemoKind::Markov(d) => d.act(ep.env()),
        };
        self.episode = Some(key);
        to_bytes(py, &a)
    }

    /// Back to the start of the script (done by itself at each new episode of the environment).
    fn restart(&mut self) {
        if let DemoKind::Scripted(d) = &mut self.kind {
            d.restart();
        }
        self.episode = None;
    }

    /// The task (kebab-case).
    #[getter]
    fn task(&self) -> String {
        episode::task_name(self.task)
    }
}

/// A policy file run through the runtime's evaluator.
#[pyclass(module = "dexstack._core")]
pub struct Policy {
    policy: policy::LoadedPolicy,
}

#[pymethods]
impl Policy {
    /// Decodes and checks the file's bytes (format, CRC, the Jaco cell's layout).
    #[new]
    fn new(file: &[u8]) -> PyResult<Self> {
        Ok(Policy {
            policy: policy::LoadedPolicy::from_bytes(file)?,
        })
    }

    /// The normalised action (9 float32 bytes) for an observation (44 float32 bytes).
    fn act<'py>(
        &mut self,
        py: Python<'py>,
        obs_bytes: &[u8],
        can_quantisation: bool,
    ) -> PyResult<Bound<'py, PyBytes>> {
        let obs = floats(obs_bytes, "observation", OBS_DIM)?;
        let a = self.policy.act(&obs, can_quantisation)?;
        Ok(to_bytes(py, &a))
    }

    /// The task the file was trained for (kebab-case).
    #[getter]
    fn task(&self) -> String {
        episode::task_name(self.policy.task())
    }

    /// Header, layout and provenance as a dict.
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let i = self.policy.info();
        let d = PyDict::new(py);
        d.set_item("version", i.version)?;
        d.set_item("flags", i.flags)?;
        d.set_item("layout_hash", i.layout_hash)?;
        d.set_item("crc", i.crc)?;
        d.set_item("bytes", i.bytes)?;
        d.set_item("task", &i.task)?;
        d.set_item("observation", i.observation.clone())?;
        d.set_item("obs_clip", i.obs_clip)?;
        d.set_item("action", i.action.clone())?;
        d.set_item("control_period_us", i.control_period_us)?;
        d.set_item("layers", i.layers.clone())?;
        let p = PyDict::new(py);
        p.set_item("trainer_version", &i.trainer_version)?;
        p.set_item("seed", i.seed)?;
        p.set_item("transitions", i.transitions)?;
        p.set_item("success_rate", i.success_rate)?;
        p.set_item("eval_episodes", i.eval_episodes)?;
        d.set_item("provenance", p)?;
        Ok(d)
    }
}

/// Seed of episode `index` of an evaluation seeded with `seed`, as `trainer eval` and `hil-sim run`
/// draw them (the one definition, `dex_env::seeds::episode_seed`).
#[pyfunction]
fn episode_seed(seed: u64, index: u64) -> u64 {
    dex_env::seeds::episode_seed(seed, index)
}

/// The controller's task features of one observation (44 float32 values as bytes), as float32
/// bytes (14 values): what a policy that takes them sees after the observation, computed by the
/// runtime's own function (`dex_runtime::features`), so an ONNX export of such a policy gets its
/// input bit for bit.
#[pyfunction]
fn task_features(obs: &[u8]) -> PyResult<Vec<u8>> {
    let v = floats(obs, "observation", OBS_DIM)?;
    let mut o = [0.0f32; OBS_DIM];
    o.copy_from_slice(&v);
    Ok(dex_runtime::features::task_features(&o)
        .iter()
        .flat_map(|x| x.to_ne_bytes())
        .collect())
}

/// The task feature fields: (name, size), in order.
#[pyfunction]
fn task_feature_fields() -> Vec<(String, u16)> {
    dex_runtime::features::FEATURE_FIELDS
        .iter()
        .map(|f| (f.name.to_owned(), f.size))
        .collect()
}

/// The reward names (kebab-case), as `trainer train --reward` takes them.
#[pyfunction]
fn reward_names() -> Vec<String> {
    Reward::ALL.map(episode::reward_name).to_vec()
}

/// The default reward of a task.
#[pyfunction]
fn default_reward(task: &str) -> PyResult<String> {
    Ok(episode::reward_name(
        episode::parse_task(task)?.default_reward(),
    ))
}

/// The default episode length of a task.
#[pyfunction]
fn default_episode_steps(task: &str) -> PyResult<u32> {
    Ok(episode::parse_task(task)?.episode_steps())
}

/// Observation fields: (name, size, lower bound, upper bound) with the bounds of the values
/// (sines, cosines and quaternion components in [-1, 1], everything else unbounded).
#[pyfunction]
fn observation_fields() -> Vec<(String, usize, f32, f32)> {
    OBSERVATION_FIELDS
        .iter()
        .map(|f| {
            let (lo, hi) = match f.quantity {
                dex_runtime::interface::Quantity::Unit => (-1.0, 1.0),
                _ => (f32::NEG_INFINITY, f32::INFINITY),
            };
            (f.name.to_owned(), f.size, lo, hi)
        })
        .collect()
}

/// Action joints: (name, scale) - action component `i` is clipped to [-1, 1] and times `scale`.
#[pyfunction]
fn action_joints() -> Vec<(String, f32)> {
    ACTION_JOINTS
        .iter()
        .map(|j| (j.name.to_owned(), j.scale))
        .collect()
}

/// The scene's compiled model as MuJoCo's binary model file (MJB bytes), for the renderer.
#[pyfunction]
fn scene_mjb<'py>(py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
    let bytes = py.detach(render::scene_mjb)?;
    Ok(PyBytes::new(py, &bytes))
}

/// The names of the scene's cameras, in id order.
#[pyfunction]
fn camera_names() -> PyResult<Vec<String>> {
    Ok(render::camera_names()?)
}

/// The extension module.
#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Env>()?;
    m.add_class::<VecEnv>()?;
    m.add_class::<Demonstrator>()?;
    m.add_class::<Policy>()?;
    m.add_function(wrap_pyfunction!(onnx::onnx_to_policy, m)?)?;
    m.add_function(wrap_pyfunction!(onnx::policy_to_onnx, m)?)?;
    m.add_function(wrap_pyfunction!(episode_seed, m)?)?;
    m.add_function(wrap_pyfunction!(task_features, m)?)?;
    m.add_function(wrap_pyfunction!(task_feature_fields, m)?)?;
    m.add_function(wrap_pyfunction!(reward_names, m)?)?;
    m.add_function(wrap_pyfunction!(default_reward, m)?)?;
    m.add_function(wrap_pyfunction!(default_episode_steps, m)?)?;
    m.add_function(wrap_pyfunction!(observation_fields, m)?)?;
    m.add_function(wrap_pyfunction!(action_joints, m)?)?;
    m.add_function(wrap_pyfunction!(scene_mjb, m)?)?;
    m.add_function(wrap_pyfunction!(camera_names, m)?)?;
    m.add("OBS_DIM", OBS_DIM)?;
    m.add("ACT_DIM", ACT_DIM)?;
    m.add("CONTROL_PERIOD_US", CONTROL_PERIOD_US)?;
    m.add("STATE_SPEC", render::STATE_SPEC)?;
    m.add("EVAL_SEED", dex_env::seeds::EVAL_SEED)?;
    m.add("MUJOCO_VERSION", render::mujoco_version())?;
    Ok(())
}
