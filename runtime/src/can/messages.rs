//! The cell's CAN messages: identifiers, byte layouts and the codecs for both ends of the bus.
//! `can/jaco.dbc` describes the same layouts for the default node 0x10 (generated from this
//! module, see `dbc`); `can/jaco.eds` describes the PDOs in its communication and mapping
//! objects (0x1400.., 0x1600.., 0x1800.., 0x1A00..).
//!
//! Every node-specific identifier derives from the node id (1..=31, [`check_node_id`]), so
//! several controllers share one bus. RPDO `k` of a node has COB-ID
//! `0x200 + 0x100*(k % 4) + node + 32*(k / 4)` ([`rpdo_cob_id`]) and TPDO `k`
//! `0x180 + 0x100*(k % 4) + node + 32*(k / 4)` ([`tpdo_cob_id`]): the first four of each are
//! CiA 301's pre-defined connection set (RPDO1-4 = 0x200/0x300/0x400/0x500 + node, TPDO1-4 =
//! 0x180/0x280/0x380/0x480 + node); further PDOs borrow the pre-defined identifiers of node + 32,
//! node + 64 and node + 96, which therefore must not be given to other devices on the bus.
//!
//! | id | message | from | protected | layout |
//! |---|---|---|---|---|
//! | 0x000 | NMT command | master | no (CANopen) | command, node id (0 = all) |
//! | 0x080 + node | emergency (CiA 301) | controller | E2E at the end | error code u16 LE, error register, fault code, state, 0, counter, CRC |
//! | RPDO k = 0..14 | observation k | plant | E2E | CRC, counter + sample nibble, 3 x i16 LE |
//! | TPDO k = 0..2 | action k | controller | E2E | CRC, counter + sample nibble, 3 x i16 LE |
//! | TPDO 3 | policy info | controller | E2E | CRC, counter, layout hash u32 LE, format version, task |
//! | TPDO 4 | status | controller | E2E | CRC, counter, state, fault code, envelope status (5 bytes) |
//! | 0x700 + node | heartbeat (CiA 301) | controller | no (CANopen) | NMT state (0x00 boot-up, 0x04, 0x05, 0x7F) |
//!
//! For the default node 0x10: observations on 0x210, 0x310, 0x410, 0x510, 0x230, 0x330, ...,
//! 0x470 (k = 14); actions on 0x190, 0x290, 0x390; policy info on 0x490; status on 0x1B0.
//! SYNC (0x080) is not used; it cannot clash with an emergency, whose node id is at least 1.
//!
//! The status TPDO goes out with every heartbeat (the producer heartbeat time, 0x1017) and on
//! every state change, even with the heartbeat off: it carries what CiA 301's one-byte
//! heartbeat cannot (the controller state, the fault code, the safety envelope's status), which
//! an SDO client also reads in objects 0x2002 and 0x2001.
//!
//! A signal value is `raw * lsb` with `raw` a little-endian i16; raw -32768 (0x8000) means
//! "not available" and decodes to NaN, which is how a plant reports a non-finite value.

use crate::can::e2e::{E2eLayout, E2eSender, protect};
use crate::can::frame::CanFrame;
use crate::interface::{ACT_DIM, OBS_DIM, Quantity, quantity_of};

/// NMT command identifier.
pub const NMT_ID: u16 = 0x000;
/// Base of the emergency identifier (`+ node id`).
pub const EMCY_BASE_ID: u16 = 0x080;
/// Base of the heartbeat identifier (`+ node id`).
pub const HEARTBEAT_BASE_ID: u16 = 0x700;
/// Smallest node id a controller may have.
pub const NODE_ID_MIN: u8 = 1;
/// Largest node id a controller may have: its PDOs past the fourth borrow the pre-defined
/// identifiers of node + 32, + 64 and + 96, which must stay below 128.
pub const NODE_ID_MAX: u8 = 31;
/// Signals per observation or action frame.
pub const SIGNALS_PER_FRAME: usize = 3;
/// Observation frames per cycle (RPDOs 0..OBS_FRAMES).
pub const OBS_FRAMES: usize = OBS_DIM.div_ceil(SIGNALS_PER_FRAME);
/// Action frames per cycle (TPDOs 0..ACTION_FRAMES).
pub const ACTION_FRAMES: usize = ACT_DIM.div_ceil(SIGNALS_PER_FRAME);
/// TPDO number of the policy information frame.
pub const POLICY_INFO_TPDO: usize = ACTION_FRAMES;
/// TPDO number of the status frame.
pub const STATUS_TPDO: usize = ACTION_FRAMES + 1;
/// TPDOs of a controller (actions, policy information, status).
pub const TPDOS: usize = STATUS_TPDO + 1;
/// Bytes of the status frame.
pub const STATUS_LEN: usize = 5;
/// Physical unit of action signals: joint velocity commands in rad/s (fingers: actuator units).
pub const ACTION_QUANTITY: Quantity = Quantity::AngularVelocity;
/// Raw value meaning "not available".
pub const RAW_NOT_AVAILABLE: i16 = i16::MIN;

/// A node id outside [`NODE_ID_MIN`]..=[`NODE_ID_MAX`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeIdError(pub u8);

impl core::fmt::Display for NodeIdError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "node id {} is outside {NODE_ID_MIN}..={NODE_ID_MAX}: PDOs past the fourth use the \
             pre-defined identifiers of node + 32, + 64 and + 96, which must stay below 128",
            self.0
        )
    }
}

impl core::error::Error for NodeIdError {}

/// `node` if a controller may have it (1..=31), else why not.
pub const fn check_node_id(node: u8) -> Result<u8, NodeIdError> {
    if node >= NODE_ID_MIN && node <= NODE_ID_MAX {
        Ok(node)
    } else {
        Err(NodeIdError(node))
    }
}

/// The COB-ID of PDO `k` over `base` (0x200 receive, 0x180 transmit).
const fn pdo_cob_id(base: u16, node: u8, k: usize) -> u16 {
    base + 0x100 * (k % 4) as u16 + node as u16 + 32 * (k / 4) as u16
}

/// COB-ID of the controller's RPDO `k` (observation frame `k`): `0x200 + 0x100*(k % 4) + node +
/// 32*(k / 4)`. For node ids 1..=31 and k below 16 it is below 0x580.
pub const fn rpdo_cob_id(node: u8, k: usize) -> u16 {
    pdo_cob_id(0x200, node, k)
}

/// COB-ID of the controller's TPDO `k` (action frames 0..3, policy information 3, status 4):
/// `0x180 + 0x100*(k % 4) + node + 32*(k / 4)`.
pub const fn tpdo_cob_id(node: u8, k: usize) -> u16 {
    pdo_cob_id(0x180, node, k)
}

/// The number `k < count` of the PDO of `node` over `base` with identifier `id`, if any.
fn pdo_number(base: u16, node: u8, count: usize, id: u16) -> Option<usize> {
    (0..count).find(|&k| pdo_cob_id(base, node, k) == id)
}

/// Index of the observation frame (RPDO) of `node` with CAN id `id`, if it is one.
pub fn observation_frame_index(node: u8, id: u16) -> Option<usize> {
    pdo_number(0x200, node, OBS_FRAMES, id)
}

/// Index of the action frame (TPDO) of `node` with CAN id `id`, if it is one.
pub fn action_frame_index(node: u8, id: u16) -> Option<usize> {
    pdo_number(0x180, node, ACTION_FRAMES, id)
}

/// NMT commands (CANopen).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NmtCommand {
    /// 0x01: start (enter operational).
    Start,
    /// 0x02: stop (enter safe-stop).
    Stop,
    /// 0x80: enter pre-operational.
    EnterPreOperational,
    /// 0x81: reset node.
    ResetNode,
    /// 0x82: reset communication.
    ResetCommunication,
}

impl NmtCommand {
    /// The command byte.
    pub const fn code(self) -> u8 {
        match self {
            NmtCommand::Start => 0x01,
            NmtCommand::Stop => 0x02,
            NmtCommand::EnterPreOperational => 0x80,
            NmtCommand::ResetNode => 0x81,
            NmtCommand::ResetCommunication => 0x82,
        }
    }

    /// Parses a command byte.
    pub const fn from_code(code: u8) -> Option<Self> {
        match code {
            0x01 => Some(NmtCommand::Start),
            0x02 => Some(NmtCommand::Stop),
            0x80 => Some(NmtCommand::EnterPreOperational),
            0x81 => Some(NmtCommand::ResetNode),
            0x82 => Some(NmtCommand::ResetCommunication),
            _ => None,
        }
    }
}

/// An NMT command frame for `node` (0 addresses every node).
pub fn nmt_frame(command: NmtCommand, node: u8) -> CanFrame {
    raw_frame(NMT_ID, &[command.code(), node])
}

/// Physical value to raw signal: rounded, saturated to +-32767, non-finite to "not available".
pub fn to_raw(value: f32, lsb: f32) -> i16 {
    if !value.is_finite() {
        return RAW_NOT_AVAILABLE;
    }
    let scaled = libm::roundf(value / lsb);
    scaled.clamp(-32767.0, 32767.0) as i16
}

/// Raw signal to physical value ("not available" gives NaN).
pub fn from_raw(raw: i16, lsb: f32) -> f32 {
    if raw == RAW_NOT_AVAILABLE {
        f32::NAN
    } else {
        f32::from(raw) * lsb
    }
}

/// Observation value `index` as it arrives at the controller after CAN quantisation.
pub fn quantise_observation(index: usize, value: f32) -> f32 {
    let lsb = quantity_of(index).map_or(1.0, Quantity::lsb);
    from_raw(to_raw(value, lsb), lsb)
}

/// Action value as it arrives at the plant after CAN quantisation.
pub fn quantise_action(value: f32) -> f32 {
    from_raw(to_raw(value, ACTION_QUANTITY.lsb()), ACTION_QUANTITY.lsb())
}

/// A frame from an id below 0x800 (masked to 11 bits) and at most 8 bytes (extra bytes dropped).
pub(crate) fn raw_frame(id: u16, data: &[u8]) -> CanFrame {
    CanFrame::from_parts(id, data)
}

/// Encodes values `values[k*3 .. k*3+3]` into a protected signal frame with identifier `id`.
fn signal_frame(
    id: u16,
    k: usize,
    sample: u8,
    sender: &mut E2eSender,
    values: &[f32],
    lsb_of: impl Fn(usize) -> f32,
) -> CanFrame {
    let mut data = [0u8; 8];
    data[1] = (sample & 0x0F) << 4;
    for s in 0..SIGNALS_PER_FRAME {
        let index = k * SIGNALS_PER_FRAME + s;
        if let Some(&v) = values.get(index) {
            let raw = to_raw(v, lsb_of(index));
            data[2 + 2 * s..4 + 2 * s].copy_from_slice(&raw.to_le_bytes());
        }
    }
    sender.protect(id, &mut data);
    raw_frame(id, &data)
}

/// Plant side: encodes one observation (one value per element of the interface layout) into
/// the [`OBS_FRAMES`] observation frames (RPDOs) of controller `node`, tagged with `sample` (only
/// its low 4 bits are sent).
pub fn encode_observation(
    node: u8,
    obs: &[f32; OBS_DIM],
    sample: u8,
    senders: &mut [E2eSender; OBS_FRAMES],
) -> [CanFrame; OBS_FRAMES] {
    core::array::from_fn(|k| {
        signal_frame(rpdo_cob_id(node, k), k, sample, &mut senders[k], obs, |i| {
            quantity_of(i).map_or(1.0, Quantity::lsb)
        })
    })
}

/// Controller side: encodes one action into the [`ACTION_FRAMES`] action frames (TPDOs) of
/// controller `node`, tagged with `sample`.
pub fn encode_action(
    node: u8,
    action: &[f32; ACT_DIM],
    sample: u8,
    senders: &mut [E2eSender; ACTION_FRAMES],
) -> [CanFrame; ACTION_FRAMES] {
    core::array::from_fn(|k| {
        signal_frame(
            tpdo_cob_id(node, k),
            k,
            sample,
            &mut senders[k],
            action,
            |_| ACTION_QUANTITY.lsb(),
        )
    })
}

/// The sample nibble and the three raw signals of a signal frame (no E2E check).
pub fn split_signal_frame(data: &[u8]) -> Option<(u8, [i16; SIGNALS_PER_FRAME])> {
    if data.len() != 8 {
        return None;
    }
    let raw = |s: usize| i16::from_le_bytes([data[2 + 2 * s], data[3 + 2 * s]]);
    Some((data[1] >> 4, [raw(0), raw(1), raw(2)]))
}

/// Plant side: decodes action frame `k` into `action` (physical values); returns the sample nibble.
/// The caller checks E2E first.
pub fn decode_action_frame(k: usize, data: &[u8], action: &mut [f32; ACT_DIM]) -> Option<u8> {
    let (sample, raw) = split_signal_frame(data)?;
    for (s, r) in raw.iter().enumerate() {
        if let Some(slot) = action.get_mut(k * SIGNALS_PER_FRAME + s) {
            *slot = from_raw(*r, ACTION_QUANTITY.lsb());
        }
    }
    Some(sample)
}

/// Emergency frame of `node` in the CiA 301 layout: error code (u16 LE), error register (the
/// value of 0x1001), then the manufacturer-specific bytes: fault code, controller state, 0, the
/// alive counter (low nibble) and the CRC, protected in the [`E2eLayout::Tail`] layout.
pub fn emcy_frame(
    node: u8,
    error_code: u16,
    error_register: u8,
    fault: u8,
    state: u8,
    sender: &mut E2eSender,
) -> CanFrame {
    let id = EMCY_BASE_ID + u16::from(node);
    let code = error_code.to_le_bytes();
    let mut data = [code[0], code[1], error_register, fault, state, 0, 0, 0];
    sender.protect_in(E2eLayout::Tail, id, &mut data);
    raw_frame(id, &data)
}

/// Protected policy information frame (TPDO [`POLICY_INFO_TPDO`] of `node`; `task` 0xFF: no
/// policy loaded).
pub fn policy_info_frame(
    node: u8,
    layout_hash: u32,
    format_version: u8,
    task: u8,
    sender: &mut E2eSender,
) -> CanFrame {
    let id = tpdo_cob_id(node, POLICY_INFO_TPDO);
    let h = layout_hash.to_le_bytes();
    let mut data = [0, 0, h[0], h[1], h[2], h[3], format_version, task];
    sender.protect(id, &mut data);
    raw_frame(id, &data)
}

/// Protected status frame (TPDO [`STATUS_TPDO`] of `node`, [`STATUS_LEN`] bytes): CRC,
/// counter, controller state, fault code and the safety envelope's status bits
/// (`envelope::status`), the values of objects 0x2002:1, 0x2002:2 and 0x2001.
pub fn status_frame(
    node: u8,
    state: u8,
    fault: u8,
    envelope: u8,
    sender: &mut E2eSender,
) -> CanFrame {
    let id = tpdo_cob_id(node, STATUS_TPDO);
    let mut data = [0, 0, state, fault, envelope];
    sender.protect(id, &mut data);
    raw_frame(id, &data)
}

/// Heartbeat frame (CiA 301): one byte, the NMT state (0x00 boot-up, 0x04 stopped,
/// 0x05 operational, 0x7F pre-operational).
pub fn heartbeat_frame(node: u8, nmt_state: u8) -> CanFrame {
    raw_frame(HEARTBEAT_BASE_ID + u16::from(node), &[nmt_state])
}

/// Protects `data` in place as a frame of `id` with `counter` (for test vectors and tools).
pub fn protect_with(id: u16, counter: u8, data: &mut [u8]) {
    protect(id, counter, data);
}
