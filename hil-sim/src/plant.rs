//! The plant node: a simulated cell that sends observation frames every 50 ms and applies the newest
//! valid (E2E-checked, complete) action it received.
//!
//! [`Plant`] is the simulation: [`SyntheticPlant`] (a kinematic stand-in with no physics, always
//! available) or, with the `mujoco` feature, [`MujocoPlant`] (`dex-env`'s MuJoCo Jaco
//! environment). [`PlantNode`] puts a plant on the bus and runs episodes in lockstep or in real time,
//! in the classic frame layout or, on a CAN FD bus, the FD layout ([`PlantNode::with_layout`]).

use std::time::{Duration, Instant};

use dex_runtime::can::e2e::{E2eReceiver, E2eSender, E2eStatus};
use dex_runtime::can::fd_messages::{
    FD_OBS_FRAMES, decode_action_fd, encode_observation_fd, fd_action_frame_index,
};
use dex_runtime::can::messages::{
    ACTION_FRAMES, EMCY_BASE_ID, HEARTBEAT_BASE_ID, NmtCommand, OBS_FRAMES, action_frame_index,
    decode_action_frame, encode_observation, nmt_frame,
};
use dex_runtime::can::{CanFrame, FdFrame, FrameLayout};
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, CONTROL_PERIOD_US, OBS_DIM};
use embedded_can::Frame;

use crate::bus::Bus;
use crate::client::{BusClient, ClientError, Received};
use crate::node::SYNC_ID;

/// Errors of a plant or the plant node.
#[derive(Debug, thiserror::Error)]
pub enum PlantError {
    /// The bus connection failed.
    #[error(transparent)]
    Bus(#[from] ClientError),
    /// The simulation failed.
    #[error("simulation: {0}")]
    Sim(String),
    /// The controller did not reach the expected state.
    #[error("controller did not become {state} within {waited:?}")]
    Controller {
        /// State waited for.
        state: &'static str,
        /// How long.
        waited: Duration,
    },
}

/// One control step's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantStep {
    /// Observation after the step.
    pub observation: [f32; OBS_DIM],
    /// Reward of the step.
    pub reward: f32,
    /// Episode over.
    pub done: bool,
    /// Task success now.
    pub success: bool,
}

/// A simulated cell behind the interface layout.
pub trait Plant {
    /// Starts an episode from `seed`; returns the first observation.
    fn reset(&mut self, seed: u64) -> Result<[f32; OBS_DIM], PlantError>;
    /// Applies joint velocity commands (physical units, as decoded from the action frames) for one
    /// 50 ms step.
    fn step(&mut self, command: &[f32; ACT_DIM]) -> Result<PlantStep, PlantError>;
}

/// A kinematic stand-in: joint angles integrate the commanded velocities, the bricks stay put.
/// Reward is `-|pinch - brick1|`; success is the pinch site within 5 cm of brick 1 at the end.
#[derive(Debug, Clone)]
pub struct SyntheticPlant {
    q: [f32; ACT_DIM],
    qd: [f32; ACT_DIM],
    brick1: [f32; 3],
    brick2: [f32; 3],
    steps: u32,
    /// Steps per episode.
    pub episode_steps: u32,
}

impl SyntheticPlant {
    /// A plant with `episode_steps` steps per episode.
    pub fn new(episode_steps: u32) -> Self {
        SyntheticPlant {
            q: [0.0; ACT_DIM],
            qd: [0.0; ACT_DIM],
            brick1: [0.0; 3],
            brick2: [0.0; 3],
            steps: 0,
            episode_steps,
        }
    }

    fn pinch(&self) -> [f32; 3] {
        let q = &self.q;
        [
            0.3 * q[0].cos() * q[1].cos(),
            0.3 * q[0].sin() * q[1].cos(),
            0.2 + 0.3 * q[1].sin(),
        ]
    }

    fn observation(&self) -> [f32; OBS_DIM] {
        let mut o = [0.0f32; OBS_DIM];
        for j in 0..6 {
            o[j] = self.q[j].sin();
            o[6 + j] = self.q[j].cos();
        }
        for j in 0..3 {
            o[12 + j] = self.q[6 + j].clamp(-3.0, 3.0);
        }
        o[15..24].copy_from_slice(&self.qd);
        o[24..27].copy_from_slice(&self.brick1);
        o[27..31].copy_from_slice(&[1.0, 0.0, 0.0, 0.0]);
        o[31..34].copy_from_slice(&self.brick2);
        o[34..38].copy_from_slice(&[1.0, 0.0, 0.0, 0.0]);
        let p = self.pinch();
        for i in 0..3 {
            o[38 + i] = self.brick1[i] - p[i];
            o[41 + i] = self.brick2[i] - p[i];
        }
        o
    }

    fn distance(&self) -> f32 {
        let p = self.pinch();
        (0..3)
            .map(|i| (self.brick1[i] - p[i]).powi(2))
            .sum::<f32>()
            .sqrt()
    }
}

impl Plant for SyntheticPlant {
    fn reset(&mut self, seed: u64) -> Result<[f32; OBS_DIM], PlantError> {
        let mut rng = dex_policy::synth::SplitMix64::new(seed);
        self.q = core::array::from_fn(|_| rng.uniform(-0.5, 0.5));
        self.qd = [0.0; ACT_DIM];
        self.brick1 = [rng.uniform(-0.1, 0.1), rng.uniform(0.3, 0.5), 0.02];
        self.brick2 = [rng.uniform(-0.1, 0.1), rng.uniform(0.3, 0.5), 0.02];
        self.steps = 0;
        Ok(self.observation())
    }

    fn step(&mut self, command: &[f32; ACT_DIM]) -> Result<PlantStep, PlantError> {
        let dt = CONTROL_PERIOD_US as f32 * 1e-6;
        for (j, c) in command.iter().enumerate() {
            let c = if c.is_finite() { *c } else { 0.0 };
            self.qd[j] = c.clamp(ACTION_JOINTS[j].min, ACTION_JOINTS[j].max);
            self.q[j] = (self.q[j] + self.qd[j] * dt).clamp(-3.0, 3.0);
        }
        self.steps += 1;
        let d = self.distance();
        Ok(PlantStep {
            observation: self.observation(),
            reward: -d,
            done: self.steps >= self.episode_steps,
            success: d < 0.05,
        })
    }
}

/// The MuJoCo Jaco environment of `dex-env` as a plant (feature `mujoco`).
#[cfg(feature = "mujoco")]
pub struct MujocoPlant {
    env: dex_env::JacoEnv,
}

#[cfg(feature = "mujoco")]
impl MujocoPlant {
    /// Loads the scene (assets from `scripts/setup-mujoco.sh`) for `task`.
    pub fn new(task: dex_env::Task) -> Result<Self, PlantError> {
        let scene = dex_env::Scene::load().map_err(|e| PlantError::Sim(e.to_string()))?;
        let env = dex_env::JacoEnv::new(&scene, dex_env::EnvConfig::new(task));
        Ok(MujocoPlant { env })
    }
}

#[cfg(feature = "mujoco")]
impl Plant for MujocoPlant {
    fn reset(&mut self, seed: u64) -> Result<[f32; OBS_DIM], PlantError> {
        self.env
            .reset(seed)
            .map_err(|e| PlantError::Sim(e.to_string()))
    }

    fn step(&mut self, command: &[f32; ACT_DIM]) -> Result<PlantStep, PlantError> {
        // The environment takes normalised actions and multiplies by each joint's scale.
        let action: [f32; ACT_DIM] = core::array::from_fn(|j| {
            let c = command[j];
            if c.is_finite() {
                c / ACTION_JOINTS[j].scale
            } else {
                0.0
            }
        });
        let s = self
            .env
            .step(&action)
            .map_err(|e| PlantError::Sim(e.to_string()))?;
        Ok(PlantStep {
            observation: s.observation,
            reward: s.reward,
            done: s.done,
            success: s.success,
        })
    }
}

/// Whether an emergency error code reports a fault (the controller leaves operational), not the
/// safety envelope's warnings (0xFF10 sustained limiting, 0x0000 when it ends), after which the
/// controller keeps answering.
fn is_fault_emcy(code: u16) -> bool {
    code != 0x0000 && code != dex_runtime::FaultCode::EnvelopeSustained.emcy_code()
}

/// Seed of episode `index` of a run seeded with `seed`: the function `trainer eval` draws its
/// starts with (`dex_env::evaluate::episode_seed` is the same item), so `hil-sim run` and
/// `trainer eval` see the same start states for the same `--seed`. Also without the `mujoco`
/// feature, for the synthetic plant.
pub use dex_runtime::seeds::episode_seed;

/// Outcome of one episode over the bus.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeReport {
    /// Seed of the episode.
    pub seed: u64,
    /// Sum of rewards.
    pub episode_return: f64,
    /// Success at the end.
    pub success: bool,
    /// Steps taken.
    pub steps: u32,
    /// Steps without an answer to their own observation (the newest older action, at most
    /// [`ACTION_HOLD_STEPS`] steps old, or zero velocity was applied).
    pub steps_without_action: u32,
}

/// Outcome of a series of episodes over the bus ([`PlantNode::episodes`]).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EpisodesReport {
    /// Episodes that ended in success.
    pub successes: u32,
    /// Sum of the episodes' returns.
    pub total_return: f64,
    /// Every applied command, per episode (empty unless recording was asked for).
    pub actions: Vec<Vec<[f32; ACT_DIM]>>,
}

/// Assembles complete actions from E2E-checked action frames (the TPDOs of one controller).
#[derive(Debug, Clone)]
pub struct ActionAssembler {
    node: u8,
    layout: FrameLayout,
    rx: [E2eReceiver; ACTION_FRAMES],
    sample: u8,
    mask: u8,
    values: [f32; ACT_DIM],
    /// Newest complete action and its sample nibble.
    pub newest: Option<([f32; ACT_DIM], u8)>,
    /// Frames rejected by E2E.
    pub rejected: u64,
}

impl ActionAssembler {
    /// An assembler for the classic action frames of controller `node`.
    pub fn new(node: u8) -> Self {
        Self::with_layout(node, FrameLayout::Classic)
    }

    /// An assembler for the action frames of controller `node` in `layout`.
    pub fn with_layout(node: u8, layout: FrameLayout) -> Self {
        ActionAssembler {
            node,
            layout,
            rx: [E2eReceiver::new(3); ACTION_FRAMES],
            sample: 0xFF,
            mask: 0,
            values: [0.0; ACT_DIM],
            newest: None,
            rejected: 0,
        }
    }

    /// Feeds one FD frame (the FD layout's action frame); returns its sample nibble when it is
    /// a valid action. Rejected (counted): a bad E2E check, another length, a non-finite value.
    pub fn push_fd(&mut self, frame: &FdFrame) -> Option<u8> {
        if self.layout != FrameLayout::Fd {
            return None;
        }
        let id = frame.standard_id()?;
        let k = fd_action_frame_index(self.node, id)?;
        let rx = self.rx.get_mut(k)?;
        let mut values = [0.0; ACT_DIM];
        if rx.check(id, frame.data()) != E2eStatus::Ok {
            self.rejected += 1;
            return None;
        }
        let Some(sample) = decode_action_fd(frame.data(), &mut values) else {
            self.rejected += 1;
            return None;
        };
        if !values.iter().all(|v| v.is_finite()) {
            self.rejected += 1;
            return None;
        }
        self.newest = Some((values, sample));
        Some(sample)
    }

    /// Feeds one classic frame; returns the sample nibble when it completed an action.
    pub fn push(&mut self, frame: &CanFrame) -> Option<u8> {
        if self.layout != FrameLayout::Classic {
            return None;
        }
        let id = frame.standard_id()?;
        let k = action_frame_index(self.node, id)?;
        let rx = self.rx.get_mut(k)?;
        if rx.check(id, frame.data()) != E2eStatus::Ok {
            self.rejected += 1;
            return None;
        }
        let sample = frame.data().get(1).map(|b| b >> 4)?;
        if sample != self.sample {
            self.sample = sample;
            self.mask = 0;
        }
        decode_action_frame(k, frame.data(), &mut self.values)?;
        self.mask |= 1 << k;
        if self.mask == (1 << ACTION_FRAMES) - 1 {
            self.mask = 0;
            self.sample = 0xFF;
            if self.values.iter().all(|v| v.is_finite()) {
                self.newest = Some((self.values, sample));
                return Some(sample);
            }
            self.rejected += 1;
        }
        None
    }
}

/// Steps an action stays valid at the plant without a newer one (then zero velocity), matching
/// the controller's 3-cycle observation watchdog.
pub const ACTION_HOLD_STEPS: u64 = 3;

/// Timing of the node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlantTiming {
    /// Simulation time on the bus; each step waits for the answer to its observation.
    Lockstep,
    /// Wall clock at 20 Hz; each step applies the newest action that arrived in time.
    RealTime,
}

/// How a lockstep plant sets the bus's simulated time.
enum TimeSetter<'b> {
    /// The bus runs in this process.
    InProcess(&'b Bus),
    /// The bus is another process (`hil-sim bus --lockstep`): a second connection sends
    /// `< time US >` and waits for the bus's answer before the cycle's frames go out.
    Remote(Box<BusClient>),
}

/// The plant on the bus: also the NMT master of the run.
pub struct PlantNode<'b> {
    client: BusClient,
    time: TimeSetter<'b>,
    timing: PlantTiming,
    node_id: u8,
    layout: FrameLayout,
    tx: [E2eSender; OBS_FRAMES],
    actions: ActionAssembler,
    sample: u8,
    sim_us: u64,
    controller_state: Option<u8>,
    emcy: Vec<u16>,
    step_index: u64,
    newest_at: u64,
    /// Every applied command, when recording is on (for determinism checks).
    pub record: Option<Vec<[f32; ACT_DIM]>>,
}

impl<'b> PlantNode<'b> {
    /// Connects to `bus`.
    pub fn connect(bus: &'b Bus, timing: PlantTiming, node_id: u8) -> Result<Self, PlantError> {
        Self::with_time(
            BusClient::connect(bus.addr(), "vcan0")?,
            TimeSetter::InProcess(bus),
            timing,
            node_id,
        )
    }

    /// Connects to a bus in another process at `addr` (for lockstep, one started with a virtual
    /// clock and a lockstep controller: `hil-sim bus --lockstep`).
    pub fn connect_remote(
        addr: std::net::SocketAddr,
        timing: PlantTiming,
        node_id: u8,
    ) -> Result<PlantNode<'static>, PlantError> {
        PlantNode::with_time(
            BusClient::connect(addr, "vcan0")?,
            TimeSetter::Remote(Box::new(BusClient::connect_raw(addr)?)),
            timing,
            node_id,
        )
    }

    fn with_time(
        client: BusClient,
        time: TimeSetter<'b>,
        timing: PlantTiming,
        node_id: u8,
    ) -> Result<Self, PlantError> {
        Ok(PlantNode {
            client,
            time,
            timing,
            node_id,
            layout: FrameLayout::Classic,
            tx: [E2eSender::default(); OBS_FRAMES],
            actions: ActionAssembler::new(node_id),
            sample: 0,
            sim_us: 0,
            controller_state: None,
            emcy: Vec::new(),
            step_index: 0,
            newest_at: 0,
            record: None,
        })
    }

    /// The plant in the frame layout `layout` (the controller's; default classic): on a CAN FD
    /// bus, [`FrameLayout::Fd`] sends the observation in two FD frames and takes the action
    /// from one.
    pub fn with_layout(mut self, layout: FrameLayout) -> Self {
        self.layout = layout;
        self.actions = ActionAssembler::with_layout(self.node_id, layout);
        self
    }

    /// Emergency codes seen so far.
    pub fn emergencies(&self) -> &[u16] {
        &self.emcy
    }

    fn tick(&mut self) -> Result<(), PlantError> {
        if self.timing == PlantTiming::Lockstep {
            match &mut self.time {
                TimeSetter::InProcess(bus) => bus.set_time(self.sim_us),
                TimeSetter::Remote(c) => {
                    c.control(&format!("time {}", self.sim_us))?;
                }
            }
            let sync = CanFrame::standard(SYNC_ID, &[]).ok_or(PlantError::Sim("sync id".into()))?;
            self.client.queue(&sync);
        }
        Ok(())
    }

    /// Handles one received frame; returns the sample nibble of an action it completed.
    fn absorb(&mut self, r: Received) -> Option<u8> {
        let f = match r {
            Received::Frame(f, _) => f,
            Received::Fd(f, _) => {
                let done = self.actions.push_fd(&f);
                if done.is_some() {
                    self.newest_at = self.step_index;
                }
                return done;
            }
            Received::Error(..) => return None,
        };
        let id = f.standard_id()?;
        if id == HEARTBEAT_BASE_ID + u16::from(self.node_id) {
            self.controller_state = f.data().first().copied();
            None
        } else if id == EMCY_BASE_ID + u16::from(self.node_id) {
            if let Some(c) = f.data().get(0..2) {
                self.emcy.push(u16::from_le_bytes([c[0], c[1]]));
            }
            None
        } else {
            let done = self.actions.push(&f);
            if done.is_some() {
                self.newest_at = self.step_index;
            }
            done
        }
    }

    fn wait_state(&mut self, state: u8, name: &'static str) -> Result<(), PlantError> {
        let waited = Duration::from_secs(3);
        let deadline = Instant::now() + waited;
        while self.controller_state != Some(state) {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(PlantError::Controller {
                    state: name,
                    waited,
                });
            }
            if let Some(r) = self
                .client
                .receive_timeout(left.min(Duration::from_millis(20)))?
            {
                self.absorb(r);
            }
        }
        Ok(())
    }

    /// Boots the controller (first SYNC in lockstep), waits for pre-operational, sends NMT start
    /// and waits for operational.
    pub fn start_controller(&mut self) -> Result<(), PlantError> {
        self.tick()?;
        self.client.flush()?;
        self.wait_state(0x7F, "pre-operational")?;
        self.client
            .queue(&nmt_frame(NmtCommand::Start, self.node_id));
        self.client.flush()?;
        self.wait_state(0x05, "operational")?;
        self.catch_up()
    }

    /// Lockstep: when the bus time is ahead of the plant's (a timed bus after a flash: its frames'
    /// time on the wire), the next cycle starts at the first period boundary at or after it. On an
    /// untimed bus, whose clock is the plant's own, nothing changes.
    fn catch_up(&mut self) -> Result<(), PlantError> {
        if self.timing != PlantTiming::Lockstep {
            return Ok(());
        }
        let now = match &mut self.time {
            TimeSetter::InProcess(bus) => bus.bus_time(),
            TimeSetter::Remote(c) => {
                let words = c.control("now")?;
                match words.as_slice() {
                    [verb, us] if verb == "now" => us.parse().unwrap_or(0),
                    _ => 0,
                }
            }
        };
        // The next cycle starts at the first period boundary at or after the bus time.
        let period = u64::from(CONTROL_PERIOD_US);
        let before_next = now.div_ceil(period).saturating_sub(1) * period;
        self.sim_us = self.sim_us.max(before_next);
        Ok(())
    }

    /// Runs `episodes` episodes, episode `e` from `episode_seed(seed, e)` as `trainer eval` does,
    /// calling `on_episode` after each; with `record` every applied command is kept.
    pub fn episodes(
        &mut self,
        plant: &mut dyn Plant,
        episodes: u32,
        seed: u64,
        record: bool,
        on_episode: &mut dyn FnMut(u32, &EpisodeReport),
    ) -> Result<EpisodesReport, PlantError> {
        let mut out = EpisodesReport::default();
        for e in 0..episodes {
            if record {
                self.record = Some(Vec::new());
            }
            let r = self.episode(plant, episode_seed(seed, u64::from(e)), u32::MAX)?;
            on_episode(e, &r);
            out.successes += u32::from(r.success);
            out.total_return += r.episode_return;
            if record {
                out.actions.push(self.record.take().unwrap_or_default());
            }
        }
        Ok(out)
    }

    /// Runs one episode from `seed`.
    pub fn episode(
        &mut self,
        plant: &mut dyn Plant,
        seed: u64,
        max_steps: u32,
    ) -> Result<EpisodeReport, PlantError> {
        let mut obs = plant.reset(seed)?;
        let mut report = EpisodeReport {
            seed,
            episode_return: 0.0,
            success: false,
            steps: 0,
            steps_without_action: 0,
        };
        let period = Duration::from_micros(u64::from(CONTROL_PERIOD_US));
        let mut next_wall = Instant::now();
        while report.steps < max_steps {
            if self.timing == PlantTiming::RealTime {
                let now = Instant::now();
                if next_wall > now {
                    std::thread::sleep(next_wall - now);
                }
                next_wall += period;
            }
            self.sim_us += u64::from(CONTROL_PERIOD_US);
            self.sample = (self.sample + 1) & 0x0F;
            self.tick()?;
            match self.layout {
                FrameLayout::Classic => {
                    for f in encode_observation(self.node_id, &obs, self.sample, &mut self.tx) {
                        self.client.queue(&f);
                    }
                }
                FrameLayout::Fd => {
                    if let Some(tx) = self.tx.first_chunk_mut::<FD_OBS_FRAMES>() {
                        for f in encode_observation_fd(self.node_id, &obs, self.sample, tx) {
                            self.client.queue_fd(&f);
                        }
                    }
                }
            }
            self.client.flush()?;
            let (command, fresh) = self.await_action()?;
            if !fresh {
                report.steps_without_action += 1;
            }
            if let Some(rec) = self.record.as_mut() {
                rec.push(command);
            }
            let s = plant.step(&command)?;
            report.episode_return += f64::from(s.reward);
            report.success = s.success;
            report.steps += 1;
            obs = s.observation;
            if s.done {
                break;
            }
        }
        Ok(report)
    }

    /// Waits for the answer to the current sample: in lockstep until it arrives (or the controller
    /// leaves operational, or 2 s pass), in real time for at most 20 ms. Returns the command to
    /// apply, the newest valid action if it arrived within the last [`ACTION_HOLD_STEPS`] steps
    /// (else zero velocity), and whether it answers this step's observation.
    fn await_action(&mut self) -> Result<([f32; ACT_DIM], bool), PlantError> {
        self.step_index += 1;
        let limit = match self.timing {
            PlantTiming::Lockstep => Duration::from_secs(2),
            PlantTiming::RealTime => Duration::from_millis(20),
        };
        let deadline = Instant::now() + limit;
        let emcy_before = self.emcy.len();
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            let Some(r) = self.client.receive_timeout(left)? else {
                break;
            };
            if self.absorb(r) == Some(self.sample) {
                break;
            }
            if self.emcy[emcy_before..].iter().any(|&c| is_fault_emcy(c))
                || self.controller_state != Some(0x05)
            {
                break;
            }
        }
        let fresh = matches!(self.actions.newest, Some((_, s)) if s == self.sample);
        let command = match self.actions.newest {
            Some((a, _)) if self.step_index - self.newest_at <= ACTION_HOLD_STEPS => a,
            _ => [0.0; ACT_DIM],
        };
        Ok((command, fresh))
    }
}
