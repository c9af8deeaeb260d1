//! The plant interface of the Jaco stacking cell: the one definition of the observation and action layout.
//!
//! The trainer's environment builds its observation vector in exactly this order, the exporter writes this
//! layout into the policy file, the CAN codec sizes its frames from it and `can/jaco.dbc` is generated
//! from it. Change it and the layout hash changes, so old policy files are refused by the controller.

/// Physical kind of an observation quantity: fixes its CAN scaling and its plausible range.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Dimensionless value in [-1, 1] (sine, cosine, quaternion component).
    Unit,
    /// Joint angle in radians.
    Angle,
    /// Joint velocity in rad/s.
    AngularVelocity,
    /// Cartesian position or displacement in metres.
    Position,
}

impl Quantity {
    /// Physical value of one least significant bit of the 16-bit CAN signal.
    pub const fn lsb(self) -> f32 {
        match self {
            Quantity::Unit => 1.0 / 16384.0,
            Quantity::Angle => 1.0e-4,
            Quantity::AngularVelocity => 1.0e-3,
            Quantity::Position => 1.0e-4,
        }
    }

    /// Largest magnitude the controller accepts; anything beyond is an out-of-range fault.
    /// Always below the largest representable magnitude (`32767 * lsb`) so saturation is detected.
    pub const fn limit(self) -> f32 {
        match self {
            Quantity::Unit => 1.01,
            Quantity::Angle => 3.2,
            Quantity::AngularVelocity => 30.0,
            Quantity::Position => 3.0,
        }
    }

    /// Unit name written into the DBC.
    pub const fn unit(self) -> &'static str {
        match self {
            Quantity::Unit => "",
            Quantity::Angle => "rad",
            Quantity::AngularVelocity => "rad/s",
            Quantity::Position => "m",
        }
    }
}

/// One named block of the observation vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ObservationField {
    /// Stable name, written into the policy file.
    pub name: &'static str,
    /// Number of consecutive values.
    pub size: usize,
    /// Physical kind of every value in the block.
    pub quantity: Quantity,
}

/// One commanded joint of the action vector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActionJoint {
    /// Stable name, written into the policy file.
    pub name: &'static str,
    /// Velocity command (rad/s, fingers in actuator units) that a network output of 1.0 maps to.
    pub scale: f32,
    /// Lowest command sent to the joint.
    pub min: f32,
    /// Highest command sent to the joint.
    pub max: f32,
}

/// The observation layout, in order (paper: joint angles and velocities, brick poses, pinch-to-brick
/// vectors). Arm angles are given as sine and cosine because four of the six arm joints are continuous.
pub const OBSERVATION_FIELDS: &[ObservationField] = &[
    ObservationField {
        name: "arm_joint_sin",
        size: 6,
        quantity: Quantity::Unit,
    },
    ObservationField {
        name: "arm_joint_cos",
        size: 6,
        quantity: Quantity::Unit,
    },
    ObservationField {
        name: "finger_joint_pos",
        size: 3,
        quantity: Quantity::Angle,
    },
    ObservationField {
        name: "joint_vel",
        size: 9,
        quantity: Quantity::AngularVelocity,
    },
    ObservationField {
        name: "brick1_pos",
        size: 3,
        quantity: Quantity::Position,
    },
    ObservationField {
        name: "brick1_quat",
        size: 4,
        quantity: Quantity::Unit,
    },
    ObservationField {
        name: "brick2_pos",
        size: 3,
        quantity: Quantity::Position,
    },
    ObservationField {
        name: "brick2_quat",
        size: 4,
        quantity: Quantity::Unit,
    },
    ObservationField {
        name: "pinch_to_brick1",
        size: 3,
        quantity: Quantity::Position,
    },
    ObservationField {
        name: "pinch_to_brick2",
        size: 3,
        quantity: Quantity::Position,
    },
];

/// Number of observation values (sum of the field sizes).
pub const OBS_DIM: usize = obs_dim(OBSERVATION_FIELDS);

/// The action layout: dm_control's velocity actuator ranges for the Jaco j2s6s300.
pub const ACTION_JOINTS: &[ActionJoint] = &[
    ActionJoint {
        name: "arm_joint_1",
        scale: 0.628,
        min: -0.628,
        max: 0.628,
    },
    ActionJoint {
        name: "arm_joint_2",
        scale: 0.628,
        min: -0.628,
        max: 0.628,
    },
    ActionJoint {
        name: "arm_joint_3",
        scale: 0.628,
        min: -0.628,
        max: 0.628,
    },
    ActionJoint {
        name: "arm_joint_4",
        scale: 0.838,
        min: -0.838,
        max: 0.838,
    },
    ActionJoint {
        name: "arm_joint_5",
        scale: 0.838,
        min: -0.838,
        max: 0.838,
    },
    ActionJoint {
        name: "arm_joint_6",
        scale: 0.838,
        min: -0.838,
        max: 0.838,
    },
    ActionJoint {
        name: "finger_1",
        scale: 5.0,
        min: -5.0,
        max: 5.0,
    },
    ActionJoint {
        name: "finger_2",
        scale: 5.0,
        min: -5.0,
        max: 5.0,
    },
    ActionJoint {
        name: "finger_3",
        scale: 5.0,
        min: -5.0,
        max: 5.0,
    },
];

/// Number of action values.
pub const ACT_DIM: usize = ACTION_JOINTS.len();

/// Control period of the cell in microseconds (20 Hz).
pub const CONTROL_PERIOD_US: u32 = 50_000;

const fn obs_dim(fields: &[ObservationField]) -> usize {
    let mut total = 0;
    let mut i = 0;
    while i < fields.len() {
        total += fields[i].size;
        i += 1;
    }
    total
}

/// Quantity of observation element `index` (0-based over the flattened vector).
pub fn quantity_of(index: usize) -> Option<Quantity> {
    let mut start = 0;
    for field in OBSERVATION_FIELDS {
        if index < start + field.size {
            return Some(field.quantity);
        }
        start += field.size;
    }
    None
}

/// The observation layout as a policy file lists it ([`dex_policy::Body::observation`]).
pub fn policy_observation()
-> heapless::Vec<dex_policy::ObsField<'static>, { dex_policy::MAX_OBS_FIELDS }> {
    OBSERVATION_FIELDS
        .iter()
        .take(dex_policy::MAX_OBS_FIELDS)
        .map(|f| dex_policy::ObsField {
            name: f.name,
            size: f.size as u16,
        })
        .collect()
}

/// The action layout, with the cell's scales and limits, as a policy file lists it
/// ([`dex_policy::Body::action`]).
pub fn policy_action()
-> heapless::Vec<dex_policy::ActionJoint<'static>, { dex_policy::MAX_ACTIONS }> {
    ACTION_JOINTS
        .iter()
        .take(dex_policy::MAX_ACTIONS)
        .map(|j| dex_policy::ActionJoint {
            name: j.name,
            scale: j.scale,
            min: j.min,
            max: j.max,
        })
        .collect()
}
