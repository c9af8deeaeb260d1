//! The cell's CAN messages: identifiers, byte layouts and the codecs for both ends of the bus.
//! `can/jaco.dbc` describes the same layouts (generated from this module, see `dbc`).
//!
//! | id | message | from | protected | layout |
//! |---|---|---|---|---|
//! | 0x000 | NMT command | master | no (CANopen) | command, node id (0 = all) |
//! | 0x080 + node | emergency | controller | E2E | CRC, counter, error code u16 LE, fault code, state |
//! | 0x200..0x20E | observation k | plant | E2E | CRC, counter + sample nibble, 3 x i16 LE |
//! | 0x280..0x282 | action k | controller | E2E | CRC, counter + sample nibble, 3 x i16 LE |
//! | 0x290 | policy info | controller | E2E | CRC, counter, layout hash u32 LE, format version, task |
//! | 0x700 + node | heartbeat | controller | no (CANopen) | CANopen state, counter, state, fault code, envelope status |
//!
//! A signal value is `raw * lsb` with `raw` a little-endian i16; raw -32768 (0x8000) means
//! "not available" and decodes to NaN, which is how a plant reports a non-finite value.

use crate::can::e2e::{E2eSender, protect};
use crate::can::frame::CanFrame;
use crate::interface::{ACT_DIM, OBS_DIM, Quantity, quantity_of};

/// NMT command identifier.
pub const NMT_ID: u16 = 0x000;
/// Base of the emergency identifier (`+ node id`).
pub const EMCY_BASE_ID: u16 = 0x080;
/// Identifier of observation frame 0; frame `k` is `OBS_BASE_ID + k`.
pub const OBS_BASE_ID: u16 = 0x200;
/// Identifier of action frame 0; frame `k` is `ACTION_BASE_ID + k`.
pub const ACTION_BASE_ID: u16 = 0x280;
/// Policy information identifier.
pub const POLICY_INFO_ID: u16 = 0x290;
/// Base of the heartbeat identifier (`+ node id`).
pub const HEARTBEAT_BASE_ID: u16 = 0x700;
/// Signals per observation or action frame.
pub const SIGNALS_PER_FRAME: usize = 3;
/// Observation frames per cycle.
pub const OBS_FRAMES: usize = OBS_DIM.div_ceil(SIGNALS_PER_FRAME);
/// Action frames per cycle.
pub const ACTION_FRAMES: usize = ACT_DIM.div_ceil(SIGNALS_PER_FRAME);
/// Physical unit of action signals: joint velocity commands in rad/s (fingers: actuator units).
pub const ACTION_QUANTITY: Quantity = Quantity::AngularVelocity;
/// Raw value meaning "not available".
pub const RAW_NOT_AVAILABLE: i16 = i16::MIN;

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

/// Encodes values `values[k*3 .. k*3+3]` into a protected signal frame at `base + k`.
fn signal_frame(
    base: u16,
    k: usize,
    sample: u8,
    sender: &mut E2eSender,
    values: &[f32],
    lsb_of: impl Fn(usize) -> f32,
) -> CanFrame {
    let id = base + k as u16;
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
/// [`OBS_FRAMES`] frames tagged with `sample` (only its low 4 bits are sent).
pub fn encode_observation(
    obs: &[f32; OBS_DIM],
    sample: u8,
    senders: &mut [E2eSender; OBS_FRAMES],
) -> [CanFrame; OBS_FRAMES] {
    core::array::from_fn(|k| {
        signal_frame(OBS_BASE_ID, k, sample, &mut senders[k], obs, |i| {
            quantity_of(i).map_or(1.0, Quantity::lsb)
        })
    })
}

/// Controller side: encodes one action into [`ACTION_FRAMES`] frames tagged with `sample`.
pub fn encode_action(
    action: &[f32; ACT_DIM],
    sample: u8,
    senders: &mut [E2eSender; ACTION_FRAMES],
) -> [CanFrame; ACTION_FRAMES] {
    core::array::from_fn(|k| {
        signal_frame(ACTION_BASE_ID, k, sample, &mut senders[k], action, |_| {
            ACTION_QUANTITY.lsb()
        })
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

/// Protected emergency frame: error code, fault code and state.
pub fn emcy_frame(
    node: u8,
    error_code: u16,
    fault: u8,
    state: u8,
    sender: &mut E2eSender,
) -> CanFrame {
    let id = EMCY_BASE_ID + u16::from(node);
    let code = error_code.to_le_bytes();
    let mut data = [0, 0, code[0], code[1], fault, state, 0, 0];
    sender.protect(id, &mut data);
    raw_frame(id, &data)
}

/// Protected policy information frame (`task` 0xFF: no policy loaded).
pub fn policy_info_frame(
    layout_hash: u32,
    format_version: u8,
    task: u8,
    sender: &mut E2eSender,
) -> CanFrame {
    let h = layout_hash.to_le_bytes();
    let mut data = [0, 0, h[0], h[1], h[2], h[3], format_version, task];
    sender.protect(POLICY_INFO_ID, &mut data);
    raw_frame(POLICY_INFO_ID, &data)
}

/// Heartbeat frame: CANopen state byte, counter, controller state, fault code and the safety
/// envelope's status bits (`envelope::status`).
pub fn heartbeat_frame(
    node: u8,
    canopen_state: u8,
    counter: u8,
    state: u8,
    fault: u8,
    envelope: u8,
) -> CanFrame {
    raw_frame(
        HEARTBEAT_BASE_ID + u16::from(node),
        &[canopen_state, counter, state, fault, envelope],
    )
}

/// Protects `data` in place as a frame of `id` with `counter` (for test vectors and tools).
pub fn protect_with(id: u16, counter: u8, data: &mut [u8]) {
    protect(id, counter, data);
}
