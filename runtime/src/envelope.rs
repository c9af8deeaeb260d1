//! The safety envelope: a guard between the policy and the arm that no policy output gets past.
//!
//! Every control cycle, after the policy, [`Envelope::apply`] scales the six arm joints' velocity
//! commands by one factor `s` in `[0, 1]` (so the direction is kept) such that over the next period
//!
//! - (a) no limited joint passes its position limit ([`EnvelopeConfig::joint_min`] /
//!   [`EnvelopeConfig::joint_max`]),
//! - (b) the pinch site stays above the table plus a margin and inside a workspace box,
//! - (c) no joint's velocity changes faster than [`EnvelopeConfig::max_accel`].
//!
//! The fingers keep their own clamps (`interface::ACTION_JOINTS`) and are not touched.
//!
//! What the controller knows is what the observation carries: each arm joint's sine and cosine (so
//! its angle, unwrapped around the middle of a limited joint's range) and its velocity. The pinch
//! site's position is computed from the angles by [`crate::kinematics`] (constants generated from
//! the simulation's MJCF), not taken from the plant's pinch-to-brick vectors, which depend on the
//! bricks and would trust the plant's own kinematics.
//!
//! How `s` is found (bounded work: at most 2 x ([`BISECTION_STEPS`] + 1) + 1 forward kinematics,
//! each without trigonometry; one f32 sine and cosine per joint and per evaluation):
//!
//! 1. Acceleration. The change of joint `j` from its measured velocity `v_j` to `s * u_j` must stay
//!    within `d_j = max_accel_j * period`; the admissible `s` form an interval, and `s_acc` is its
//!    top (at most 1). When no `s` in `[0, 1]` meets every joint (the command reverses or turns
//!    faster than the arm may: no scaling of it is slow enough), the command becomes
//!    `v + r (u - v)` with the one factor `r` that brings the largest change down to its limit,
//!    and `s_acc = 1` for it. Only then does the envelope not keep the policy's direction; it keeps
//!    the direction of the change instead, and is counted as [`EnvelopeStats::turns`].
//! 2. Position. `s` is the largest value in `[0, s_acc]` (checked at `s_acc`, else bisection in
//!    [`BISECTION_STEPS`] halvings from 0, which is always admissible) for which the joint angles
//!    after the period, `q + s c T`, and after braking from there at `max_accel`,
//!    `q + s c T + s c |s c| / (2 a)`, satisfy (a) and (b). The braking point keeps the arm able to
//!    stop inside the envelope under the acceleration limit. A constraint already violated (a start
//!    state outside the box, a joint beyond its limit) may not get worse, so the arm can always move
//!    back in. Position has priority over acceleration: when it needs an `s` below the acceleration
//!    interval, the acceleration limit is exceeded for that cycle and counted
//!    ([`EnvelopeStats::accel_overridden`]).
//!
//! The kinematics of step 2: every candidate moves the angles along a line from `q`, so the
//! joints' sines and cosines are taken once per cycle ([`JointTrig::of`]), each candidate's by
//! angle addition with its offset's sine and cosine ([`JointTrig::shifted`]; every sine and cosine
//! by [`crate::kinematics::sin_cos`], f32 arithmetic only), and the pinch site from those by 3x3 matrices
//! ([`pinch_position_trig`]). Nothing is linearised: every candidate's pinch site is its forward
//! kinematics, exact up to f32 rounding (within 4e-7 m of an f64 evaluation of the same chain,
//! `runtime/tests/kinematics.rs`), so the guarantees hold as stated for every chosen `s`. The
//! bisection stops checking a candidate at the first broken constraint.
//!
//! Everything is f32 with `libm`, in a fixed order: the host and the Cortex-M4F give the same bits.

use crate::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM, OBSERVATION_FIELDS};
use crate::jaco_kinematics::{JOINT_LIMITED, JOINT_RANGE};
use crate::kinematics::{ARM_JOINTS, JointTrig, pinch_position_trig};

/// Halvings of the position search: `s` is found to 1/256 (conservatively: the admissible end).
pub const BISECTION_STEPS: u32 = 8;

/// The margin inside the model's joint range that [`EnvelopeConfig::jaco`] keeps, radians.
pub const JACO_JOINT_MARGIN: f32 = 0.05;

/// Status bits of [`Envelope::status`] (heartbeat byte 4).
pub mod status {
    /// The envelope is enabled.
    pub const ENABLED: u8 = 0x01;
    /// It limited for more than [`super::EnvelopeConfig::sustained_cycles`] consecutive cycles.
    pub const SUSTAINED: u8 = 0x02;
    /// Last cycle: a joint position limit bound.
    pub const JOINT_LIMIT: u8 = 0x04;
    /// Last cycle: the table margin bound.
    pub const TABLE: u8 = 0x08;
    /// Last cycle: the workspace box bound.
    pub const WORKSPACE: u8 = 0x10;
    /// Last cycle: the acceleration limit bound.
    pub const ACCELERATION: u8 = 0x20;
    /// Any limit bound last cycle.
    pub const LIMITING: u8 = JOINT_LIMIT | TABLE | WORKSPACE | ACCELERATION;
}

/// Settings of the envelope. Part of the controller's configuration, never of a policy file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvelopeConfig {
    /// Off: actions pass unchanged (and nothing is counted).
    pub enabled: bool,
    /// Which arm joints have position limits (the others are continuous).
    pub joint_limited: [bool; ARM_JOINTS],
    /// Lowest angle each limited joint may reach, radians (in the model's convention).
    pub joint_min: [f32; ARM_JOINTS],
    /// Highest angle each limited joint may reach, radians.
    pub joint_max: [f32; ARM_JOINTS],
    /// Height of the table surface in the world frame, metres.
    pub table_z: f32,
    /// Clearance the pinch site keeps above the table, metres.
    pub table_margin: f32,
    /// Lower corner of the box the pinch site stays in (world frame), metres.
    pub workspace_min: [f32; 3],
    /// Upper corner of that box, metres.
    pub workspace_max: [f32; 3],
    /// Largest velocity change per second of each arm joint, rad/s^2.
    pub max_accel: [f32; ARM_JOINTS],
    /// Limiting in more than this many consecutive cycles raises the "sustained" emergency.
    pub sustained_cycles: u32,
}

/// Why an [`EnvelopeConfig`] was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EnvelopeConfigError {
    /// A value is NaN or infinite.
    NonFinite,
    /// A limited joint's minimum is not below its maximum.
    JointRange {
        /// Arm joint index.
        joint: usize,
    },
    /// The workspace box is empty along an axis, or the table margin puts its floor above the top.
    Workspace {
        /// Axis (0 x, 1 y, 2 z).
        axis: usize,
    },
    /// An acceleration limit or the table margin is not positive.
    NotPositive,
}

impl core::fmt::Display for EnvelopeConfigError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EnvelopeConfigError::NonFinite => f.write_str("a value is not finite"),
            EnvelopeConfigError::JointRange { joint } => {
                write!(f, "arm joint {} has an empty range", joint + 1)
            }
            EnvelopeConfigError::Workspace { axis } => {
                write!(f, "the workspace box is empty along axis {axis}")
            }
            EnvelopeConfigError::NotPositive => {
                f.write_str("an acceleration limit or the table margin is not positive")
            }
        }
    }
}

impl core::error::Error for EnvelopeConfigError {}

impl EnvelopeConfig {
    /// The Jaco cell's envelope (docs/runtime.md says where each number comes from): the model's
    /// joint ranges less [`JACO_JOINT_MARGIN`], the pinch site 5 mm above the table and inside
    /// x, y in [-0.45, 0.45] m, z up to 0.6 m, 10 rad/s^2 per joint, 20 cycles (1 s) to "sustained".
    pub const fn jaco() -> Self {
        let mut joint_min = [0.0; ARM_JOINTS];
        let mut joint_max = [0.0; ARM_JOINTS];
        let mut j = 0;
        while j < ARM_JOINTS {
            if JOINT_LIMITED[j] {
                joint_min[j] = JOINT_RANGE[j][0] + JACO_JOINT_MARGIN;
                joint_max[j] = JOINT_RANGE[j][1] - JACO_JOINT_MARGIN;
            }
            j += 1;
        }
        EnvelopeConfig {
            enabled: true,
            joint_limited: JOINT_LIMITED,
            joint_min,
            joint_max,
            table_z: 0.0,
            table_margin: 0.005,
            workspace_min: [-0.45, -0.45, 0.0],
            workspace_max: [0.45, 0.45, 0.6],
            max_accel: [10.0; ARM_JOINTS],
            sustained_cycles: 20,
        }
    }

    /// [`EnvelopeConfig::jaco`] switched off.
    pub const fn disabled() -> Self {
        let mut c = Self::jaco();
        c.enabled = false;
        c
    }

    /// Checks the settings (a disabled envelope is always accepted).
    pub fn validate(&self) -> Result<(), EnvelopeConfigError> {
        if !self.enabled {
            return Ok(());
        }
        let scalars = [self.table_z, self.table_margin];
        let all = self
            .joint_min
            .iter()
            .chain(&self.joint_max)
            .chain(&self.workspace_min)
            .chain(&self.workspace_max)
            .chain(&self.max_accel)
            .chain(&scalars);
        if all.clone().any(|x| !x.is_finite()) {
            return Err(EnvelopeConfigError::NonFinite);
        }
        for j in 0..ARM_JOINTS {
            if self.joint_limited[j] && self.joint_min[j] >= self.joint_max[j] {
                return Err(EnvelopeConfigError::JointRange { joint: j });
            }
        }
        if self.max_accel.iter().any(|&a| a <= 0.0) || self.table_margin < 0.0 {
            return Err(EnvelopeConfigError::NotPositive);
        }
        let floor = self.table_z + self.table_margin;
        for axis in 0..3 {
            let lo = if axis == 2 {
                self.workspace_min[2].max(floor)
            } else {
                self.workspace_min[axis]
            };
            if lo >= self.workspace_max[axis] {
                return Err(EnvelopeConfigError::Workspace { axis });
            }
        }
        Ok(())
    }
}

impl Default for EnvelopeConfig {
    fn default() -> Self {
        Self::jaco()
    }
}

/// What the envelope did, counted since the controller started; counters saturate.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EnvelopeStats {
    /// Cycles the envelope ran (enabled, on a policy action).
    pub cycles: u64,
    /// Cycles in which it changed the action (any limit bound).
    pub limited: u64,
    /// Cycles in which a joint position limit bound.
    pub joint_limit: u64,
    /// Cycles in which the table margin bound.
    pub table: u64,
    /// Cycles in which the workspace box bound.
    pub workspace: u64,
    /// Cycles in which the acceleration limit bound.
    pub acceleration: u64,
    /// Cycles in which no scaling met the acceleration limit, so the change was limited instead.
    pub turns: u64,
    /// Cycles in which position needed a smaller scale than the acceleration limit allowed.
    pub accel_overridden: u64,
    /// Current run of consecutive limited cycles.
    pub consecutive: u32,
    /// Longest run of consecutive limited cycles.
    pub longest: u32,
    /// Times a run grew past [`EnvelopeConfig::sustained_cycles`] (emergency 0xFF10).
    pub sustained_events: u64,
}

/// What one [`Envelope::apply`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Outcome {
    /// Factor applied to the arm command (1 when nothing bound).
    pub scale: f32,
    /// [`status`] bits of the limits that bound.
    pub limits: u8,
    /// This cycle made the run of limited cycles exceed the sustained threshold.
    pub sustained_started: bool,
    /// This cycle ended a sustained run (the first cycle without limiting after it).
    pub sustained_ended: bool,
}

/// The envelope's state: its settings, the control period and its counters.
#[derive(Debug, Clone)]
pub struct Envelope {
    cfg: EnvelopeConfig,
    period_s: f32,
    stats: EnvelopeStats,
    last_limits: u8,
}

/// Where the arm's sines, cosines and velocities are in the observation.
const fn field_offset(name: &str) -> usize {
    let mut start = 0;
    let mut i = 0;
    while i < OBSERVATION_FIELDS.len() {
        if const_str_eq(OBSERVATION_FIELDS[i].name, name) {
            return start;
        }
        start += OBSERVATION_FIELDS[i].size;
        i += 1;
    }
    panic!("observation field missing")
}

const fn const_str_eq(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    let mut i = 0;
    while i < a.len() {
        if a[i] != b[i] {
            return false;
        }
        i += 1;
    }
    true
}

const SIN: usize = field_offset("arm_joint_sin");
const COS: usize = field_offset("arm_joint_cos");
const VEL: usize = field_offset("joint_vel");
const _: () = assert!(SIN + ARM_JOINTS <= OBS_DIM && COS + ARM_JOINTS <= OBS_DIM);
const _: () = assert!(VEL + ARM_JOINTS <= OBS_DIM && ARM_JOINTS <= ACT_DIM);

/// Writes arm joint angles `q` (as sine and cosine) and velocities `v` into an observation, where
/// [`Envelope::arm_state`] reads them (for tests and tools).
pub fn write_arm_state(obs: &mut [f32; OBS_DIM], q: &[f32; ARM_JOINTS], v: &[f32; ARM_JOINTS]) {
    for j in 0..ARM_JOINTS {
        obs[SIN + j] = libm::sinf(q[j]);
        obs[COS + j] = libm::cosf(q[j]);
        obs[VEL + j] = v[j];
    }
}

/// Per-constraint excess (positive: violated) of a pinch-site position: table, then box x, y, z.
fn pinch_excess(cfg: &EnvelopeConfig, p: &nalgebra::Vector3<f32>) -> [f32; 7] {
    [
        cfg.table_z + cfg.table_margin - p[2],
        cfg.workspace_min[0] - p[0],
        p[0] - cfg.workspace_max[0],
        cfg.workspace_min[1] - p[1],
        p[1] - cfg.workspace_max[1],
        cfg.workspace_min[2] - p[2],
        p[2] - cfg.workspace_max[2],
    ]
}

impl Envelope {
    /// An envelope with `cfg` for a control period of `period_us` microseconds.
    pub fn new(cfg: EnvelopeConfig, period_us: u32) -> Self {
        Envelope {
            cfg,
            period_s: period_us as f32 * 1.0e-6,
            stats: EnvelopeStats::default(),
            last_limits: 0,
        }
    }

    /// The settings.
    pub fn config(&self) -> &EnvelopeConfig {
        &self.cfg
    }

    /// The counters.
    pub fn stats(&self) -> &EnvelopeStats {
        &self.stats
    }

    /// [`status`] bits: enabled, sustained, and the limits that bound in the last cycle.
    pub fn status(&self) -> u8 {
        if !self.cfg.enabled {
            return 0;
        }
        let sustained = if self.stats.consecutive > self.cfg.sustained_cycles {
            status::SUSTAINED
        } else {
            0
        };
        status::ENABLED | sustained | self.last_limits
    }

    /// Forgets the current run of limited cycles (the controller left operational).
    pub fn end_run(&mut self) {
        self.stats.consecutive = 0;
        self.last_limits = 0;
    }

    /// Arm joint angles (unwrapped around the middle of each limited joint's range) and
    /// velocities from an observation.
    pub fn arm_state(&self, obs: &[f32; OBS_DIM]) -> ([f32; ARM_JOINTS], [f32; ARM_JOINTS]) {
        let mut q = [0.0f32; ARM_JOINTS];
        let mut v = [0.0f32; ARM_JOINTS];
        for j in 0..ARM_JOINTS {
            let mut a = libm::atan2f(obs[SIN + j], obs[COS + j]);
            if self.cfg.joint_limited[j] {
                let mid = 0.5 * (self.cfg.joint_min[j] + self.cfg.joint_max[j]);
                let tau = 2.0 * core::f32::consts::PI;
                if a < mid - core::f32::consts::PI {
                    a += tau;
                } else if a >= mid + core::f32::consts::PI {
                    a -= tau;
                }
            }
            q[j] = a;
            v[j] = obs[VEL + j];
        }
        (q, v)
    }

    /// Applies the envelope to `action` (arm joints 0..6 only) for observation `obs`.
    pub fn apply(&mut self, obs: &[f32; OBS_DIM], action: &mut [f32; ACT_DIM]) -> Outcome {
        let mut outcome = Outcome {
            scale: 1.0,
            limits: 0,
            sustained_started: false,
            sustained_ended: false,
        };
        if !self.cfg.enabled {
            return outcome;
        }
        let (q, v) = self.arm_state(obs);
        let mut u = [0.0f32; ARM_JOINTS];
        u.copy_from_slice(&action[..ARM_JOINTS]);
        let (scale, limits) = if q.iter().chain(&v).chain(&u).all(|x| x.is_finite()) {
            let (cmd, s, limits) = self.solve(&q, &v, &u);
            for (j, joint) in ACTION_JOINTS.iter().enumerate().take(ARM_JOINTS) {
                // The clamp only acts after a turn, where the command starts from the measured
                // velocity.
                action[j] = (s * cmd[j]).clamp(joint.min, joint.max);
            }
            (s, limits)
        } else {
            // Unreachable behind the controller's checks; stop the arm rather than guess.
            for a in action.iter_mut().take(ARM_JOINTS) {
                *a = 0.0;
            }
            (0.0, status::JOINT_LIMIT)
        };
        outcome.scale = scale;
        outcome.limits = limits;
        self.count(&mut outcome);
        outcome
    }

    fn count(&mut self, outcome: &mut Outcome) {
        let st = &mut self.stats;
        let inc = |c: &mut u64| *c = c.saturating_add(1);
        inc(&mut st.cycles);
        let l = outcome.limits;
        let was_sustained = st.consecutive > self.cfg.sustained_cycles;
        if l & status::LIMITING != 0 {
            inc(&mut st.limited);
            st.consecutive = st.consecutive.saturating_add(1);
            st.longest = st.longest.max(st.consecutive);
            if !was_sustained && st.consecutive > self.cfg.sustained_cycles {
                inc(&mut st.sustained_events);
                outcome.sustained_started = true;
            }
        } else {
            st.consecutive = 0;
            outcome.sustained_ended = was_sustained;
        }
        for (bit, c) in [
            (status::JOINT_LIMIT, &mut st.joint_limit),
            (status::TABLE, &mut st.table),
            (status::WORKSPACE, &mut st.workspace),
            (status::ACCELERATION, &mut st.acceleration),
        ] {
            if l & bit != 0 {
                inc(c);
            }
        }
        self.last_limits = l & status::LIMITING;
    }

    /// The command direction, its scale and the limits that bound (see the module docs).
    fn solve(
        &mut self,
        q: &[f32; ARM_JOINTS],
        v: &[f32; ARM_JOINTS],
        u: &[f32; ARM_JOINTS],
    ) -> ([f32; ARM_JOINTS], f32, u8) {
        let cfg = self.cfg;
        let dt = self.period_s;
        let mut limits = 0u8;
        // 1. Acceleration: lo <= s <= hi with |s u_j - v_j| <= d_j for every joint.
        let (mut lo, mut hi) = (0.0f32, 1.0f32);
        for j in 0..ARM_JOINTS {
            let d = cfg.max_accel[j] * dt;
            if u[j] == 0.0 {
                if libm::fabsf(v[j]) > d {
                    lo = 1.0;
                    hi = 0.0;
                }
                continue;
            }
            let (a, b) = ((v[j] - d) / u[j], (v[j] + d) / u[j]);
            let (a, b) = if a <= b { (a, b) } else { (b, a) };
            lo = lo.max(a);
            hi = hi.min(b);
        }
        let mut cmd = *u;
        let s_acc;
        if lo <= hi {
            s_acc = hi;
            if hi < 1.0 {
                limits |= status::ACCELERATION;
            }
        } else {
            // No scaling of u is slow enough: limit the change from v by one factor r.
            let mut r = 1.0f32;
            for j in 0..ARM_JOINTS {
                let d = cfg.max_accel[j] * dt;
                let change = libm::fabsf(u[j] - v[j]);
                if change > d {
                    r = r.min(d / change);
                }
            }
            for j in 0..ARM_JOINTS {
                cmd[j] = v[j] + r * (u[j] - v[j]);
            }
            s_acc = 1.0;
            lo = 1.0;
            limits |= status::ACCELERATION;
            self.stats.turns = self.stats.turns.saturating_add(1);
        }
        // 2. Position: the largest admissible s in [0, s_acc]. The joints' sines and cosines are
        // taken once; every candidate's angles are offsets from them (`JointTrig::shifted`).
        let trig = JointTrig::of(q);
        let now = pinch_excess(&cfg, &pinch_position_trig(&trig));
        let mut s = s_acc;
        let first = self.violations(q, &trig, &cmd, s, &now, true);
        if first != 0 {
            limits |= first;
            let (mut ok, mut bad) = (0.0f32, s_acc);
            for _ in 0..BISECTION_STEPS {
                let mid = 0.5 * (ok + bad);
                if self.violations(q, &trig, &cmd, mid, &now, false) == 0 {
                    ok = mid;
                } else {
                    bad = mid;
                }
            }
            s = ok;
            if s < lo {
                self.stats.accel_overridden = self.stats.accel_overridden.saturating_add(1);
            }
        }
        (cmd, s, limits)
    }

    /// The [`status`] bits of the constraints that `s * cmd` breaks over the next period (`trig`:
    /// the sines and cosines of `q`). With `all` false it returns at the first broken kind
    /// (joint limits, then the pinch site after the period, then after braking): the bisection
    /// only asks whether any is broken.
    fn violations(
        &self,
        q: &[f32; ARM_JOINTS],
        trig: &JointTrig,
        cmd: &[f32; ARM_JOINTS],
        s: f32,
        now: &[f32; 7],
        all: bool,
    ) -> u8 {
        let cfg = &self.cfg;
        let dt = self.period_s;
        // The offsets from q after the period and at the braking point.
        let mut d_after = [0.0f32; ARM_JOINTS];
        let mut d_stopped = [0.0f32; ARM_JOINTS];
        let mut bits = 0u8;
        for j in 0..ARM_JOINTS {
            let w = s * cmd[j];
            let brake = w * libm::fabsf(w) / (2.0 * cfg.max_accel[j]);
            d_after[j] = w * dt;
            d_stopped[j] = d_after[j] + brake;
            let after = q[j] + d_after[j];
            let stopped = after + brake;
            if cfg.joint_limited[j] {
                // A joint already at or past a limit may not move further out at all: a sign
                // test, because a motion below the angle's rounding leaves `q + w dt` unchanged.
                let past_max = q[j] >= cfg.joint_max[j];
                let past_min = q[j] <= cfg.joint_min[j];
                if (past_max && w > 0.0) || (past_min && w < 0.0) {
                    bits |= status::JOINT_LIMIT;
                }
                for x in [after, stopped] {
                    if (!past_max && x > cfg.joint_max[j]) || (!past_min && x < cfg.joint_min[j]) {
                        bits |= status::JOINT_LIMIT;
                    }
                }
            }
        }
        for d in [&d_after, &d_stopped] {
            if bits != 0 && !all {
                return bits;
            }
            let e = pinch_excess(cfg, &pinch_position_trig(&trig.shifted(d)));
            for (k, (&x, &n)) in e.iter().zip(now).enumerate() {
                if x > n.max(0.0) {
                    bits |= if k == 0 {
                        status::TABLE
                    } else {
                        status::WORKSPACE
                    };
                }
            }
        }
        bits
    }
}
