//! The test kit (`std` only): the benchmark network, golden files' values, CAN test vectors and
//! SDO / program-download frames for tests, benchmarks, goldens and the firmware check. Synthetic
//! policies and observation traces live in [`crate::synthetic`], the action-trace line in
//! [`crate::action_trace`] (both used by programs too); they are re-exported here for tests.

use std::vec::Vec;

use dex_policy::synth::{SynthSpec, synth_policy};
use dex_policy::{Activation, FormatError, Task};

use crate::interface::quantity_of;

pub use crate::action_trace::action_line;
/// Re-exported for tests, benchmarks and examples written against the test kit; production code
/// uses [`crate::aligned`].
pub use crate::aligned::{AlignedBytes, aligned_copy};
pub use crate::synthetic::{
    ActionJoint, ObservationField, cell_layout, jaco_policy, jaco_policy_faulting,
    jaco_policy_int8, jaco_policy_with_features, observation_trace,
};

/// The benchmark network of the runtime issue: 48 inputs (one field "obs"), two hidden ReLU layers
/// of 256, 9 tanh outputs (unit scale and limits), seed 1. Not the cell's layout: for speed only.
pub fn mlp_48_256_256_9() -> Result<Vec<u8>, FormatError> {
    let action: Vec<(&str, f32, f32, f32)> = (0..crate::interface::ACT_DIM)
        .map(|_| ("joint", 1.0, -1.0, 1.0))
        .collect();
    synth_policy(&SynthSpec {
        task: Task::Stack,
        observation: &[("obs", 48)],
        action: &action,
        hidden: &[256, 256],
        hidden_activation: Activation::Relu,
        output_activation: Activation::Tanh,
        seed: 1,
    })
}

/// Little-endian f32 values of a byte file (a trace or golden actions); a trailing partial value is
/// ignored.
pub fn f32s_le(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}

/// One CAN test vector: the bytes the Rust codec produced and the physical signal values they carry.
#[derive(Debug, Clone, PartialEq)]
pub struct CanVector {
    /// DBC message name.
    pub message: std::string::String,
    /// 11-bit identifier.
    pub id: u16,
    /// Frame bytes.
    pub data: Vec<u8>,
    /// Signal name and physical value, in DBC order.
    pub signals: Vec<(std::string::String, f64)>,
}

/// Vectors covering every message of the DBC, made with the Rust codec (see `tests/can/`).
pub fn can_vectors() -> Vec<CanVector> {
    use crate::can::e2e::E2eSender;
    use crate::can::messages::{
        ACTION_FRAMES, NmtCommand, OBS_FRAMES, SIGNALS_PER_FRAME, emcy_frame, encode_action,
        encode_observation, heartbeat_frame, nmt_frame, policy_info_frame, split_signal_frame,
        status_frame,
    };
    use crate::dbc::{
        action_message_name, dbc_scale, observation_message_name, observation_signal_name,
    };
    use crate::interface::{ACT_DIM, ACTION_JOINTS};
    use embedded_can::Frame;
    use std::string::ToString;

    let node = crate::ControllerConfig::default().node_id;
    let mut out = Vec::new();
    let head = |data: &[u8], nibble: Option<&str>| {
        let mut s = std::vec![
            ("crc".to_string(), f64::from(data[0])),
            ("alive_counter".to_string(), f64::from(data[1] & 0x0F)),
        ];
        if let Some(n) = nibble {
            s.push((n.to_string(), f64::from(data[1] >> 4)));
        }
        s
    };
    let mut obs_tx = [E2eSender::default(); OBS_FRAMES];
    for (n, obs) in observation_trace(2, 77).iter().enumerate() {
        let frames = encode_observation(node, obs, 3 + n as u8 * 9, &mut obs_tx);
        for (k, f) in frames.iter().enumerate() {
            let mut signals = head(f.data(), Some("sample_counter"));
            if let Some((_, raw)) = split_signal_frame(f.data()) {
                for (slot, r) in raw.iter().enumerate() {
                    let index = k * SIGNALS_PER_FRAME + slot;
                    if let (Some(name), Some(q)) =
                        (observation_signal_name(index), quantity_of(index))
                    {
                        signals.push((name, f64::from(*r) * dbc_scale(q.lsb())));
                    }
                }
            }
            out.push(CanVector {
                message: observation_message_name(k),
                id: f.standard_id().unwrap_or(0),
                data: f.data().to_vec(),
                signals,
            });
        }
    }
    let mut act_tx = [E2eSender::default(); ACTION_FRAMES];
    let action: [f32; ACT_DIM] = [0.5, -0.25, 0.628, -0.838, 0.001, 0.0, 5.0, -4.999, 2.5];
    for (k, f) in encode_action(node, &action, 12, &mut act_tx)
        .iter()
        .enumerate()
    {
        let mut signals = head(f.data(), Some("sample_counter"));
        if let Some((_, raw)) = split_signal_frame(f.data()) {
            for (slot, r) in raw.iter().enumerate() {
                if let Some(j) = ACTION_JOINTS.get(k * SIGNALS_PER_FRAME + slot) {
                    signals.push((j.name.to_string(), f64::from(*r) * dbc_scale(1.0e-3)));
                }
            }
        }
        out.push(CanVector {
            message: action_message_name(k),
            id: f.standard_id().unwrap_or(0),
            data: f.data().to_vec(),
            signals,
        });
    }
    let mut tx = E2eSender::default();
    for _ in 0..3 {
        let f = emcy_frame(node, 0x8250, 0x11, 1, 3, &mut tx);
        let d = f.data();
        let signals = std::vec![
            ("error_code".to_string(), 33360.0),
            ("error_register".to_string(), 17.0),
            ("fault_code".to_string(), 1.0),
            ("state".to_string(), 3.0),
            ("alive_counter".to_string(), f64::from(d[6] & 0x0F)),
            ("crc".to_string(), f64::from(d[7])),
        ];
        out.push(CanVector {
            message: "EMCY".to_string(),
            id: f.standard_id().unwrap_or(0),
            data: f.data().to_vec(),
            signals,
        });
    }
    let f = policy_info_frame(node, 0xDEAD_BEEF, 1, 3, &mut E2eSender::default());
    let mut signals = head(f.data(), None);
    signals.push(("layout_hash".to_string(), f64::from(0xDEAD_BEEFu32)));
    signals.push(("format_version".to_string(), 1.0));
    signals.push(("task".to_string(), 3.0));
    out.push(CanVector {
        message: "POLICY_INFO".to_string(),
        id: f.standard_id().unwrap_or(0),
        data: f.data().to_vec(),
        signals,
    });
    let f = heartbeat_frame(node, 0x05);
    out.push(CanVector {
        message: "HEARTBEAT".to_string(),
        id: f.standard_id().unwrap_or(0),
        data: f.data().to_vec(),
        signals: std::vec![("nmt_state".to_string(), 5.0)],
    });
    let mut tx = E2eSender::default();
    for _ in 0..2 {
        let f = status_frame(node, 2, 0, 0x05, &mut tx);
        let mut signals = head(f.data(), None);
        signals.extend([
            ("state".to_string(), 2.0),
            ("fault_code".to_string(), 0.0),
            // 0x05: enabled, limited by a joint position limit in the last cycle.
            ("envelope_enabled".to_string(), 1.0),
            ("envelope_sustained".to_string(), 0.0),
            ("envelope_joint_limit".to_string(), 1.0),
            ("envelope_table".to_string(), 0.0),
            ("envelope_workspace".to_string(), 0.0),
            ("envelope_acceleration".to_string(), 0.0),
        ]);
        out.push(CanVector {
            message: "STATUS".to_string(),
            id: f.standard_id().unwrap_or(0),
            data: f.data().to_vec(),
            signals,
        });
    }
    let f = nmt_frame(NmtCommand::Start, node);
    out.push(CanVector {
        message: "NMT".to_string(),
        id: 0,
        data: f.data().to_vec(),
        signals: std::vec![
            ("command".to_string(), 1.0),
            ("node_id".to_string(), f64::from(node)),
        ],
    });
    out
}

/// The vectors as JSON text (one object per line inside a list), as committed in `tests/can/`.
pub fn can_vectors_json() -> std::string::String {
    use std::fmt::Write;
    let mut s = std::string::String::from("[\n");
    let vectors = can_vectors();
    for (i, v) in vectors.iter().enumerate() {
        let hex: std::string::String = v.data.iter().map(|b| std::format!("{b:02x}")).collect();
        let _ = write!(
            s,
            "  {{\"message\": \"{}\", \"id\": {}, \"data\": \"{}\", \"signals\": {{",
            v.message, v.id, hex
        );
        for (j, (name, value)) in v.signals.iter().enumerate() {
            let sep = if j + 1 == v.signals.len() { "" } else { ", " };
            let _ = write!(s, "\"{name}\": {value:?}{sep}");
        }
        let sep = if i + 1 == vectors.len() { "" } else { "," };
        let _ = writeln!(s, "}}}}{sep}");
    }
    s.push_str("]\n");
    s
}

/// The SDO request identifier of `node` (`0x600 + node`).
fn sdo_request_id(node: u8) -> u16 {
    crate::controller::SDO_REQUEST_BASE + u16::from(node)
}

/// The request frames of an SDO block download (CiA 301, with CRC) of `data` into
/// `index`:`sub` of `node`, as a client sends them to a server that offers block size
/// [`crate::canopen::sdo::BLOCK_SIZE`] and acknowledges every segment: initiate (size given),
/// the segments in sub-blocks, end with the CRC-16. `data` must not be empty.
pub fn sdo_block_download(node: u8, index: u16, sub: u8, data: &[u8]) -> Vec<crate::can::CanFrame> {
    use crate::canopen::sdo::{BLOCK_CRC, BLOCK_SIZE};
    let id = sdo_request_id(node);
    let mut out = Vec::new();
    let i = index.to_le_bytes();
    let size = (data.len() as u32).to_le_bytes();
    out.extend(crate::can::CanFrame::standard(
        id,
        &[0xC6, i[0], i[1], sub, size[0], size[1], size[2], size[3]],
    ));
    let chunks: Vec<&[u8]> = data.chunks(7).collect();
    for (k, chunk) in chunks.iter().enumerate() {
        let mut d = [0u8; 8];
        let seq = (k % usize::from(BLOCK_SIZE)) as u8 + 1;
        d[0] = (u8::from(k + 1 == chunks.len()) << 7) | seq;
        d[1..1 + chunk.len()].copy_from_slice(chunk);
        out.extend(crate::can::CanFrame::standard(id, &d));
    }
    let unused = chunks.last().map_or(0, |c| 7 - c.len()) as u8;
    let c = BLOCK_CRC.checksum(data).to_le_bytes();
    out.extend(crate::can::CanFrame::standard(
        id,
        &[0xC1 | (unused << 2), c[0], c[1], 0, 0, 0, 0, 0],
    ));
    out
}

/// An expedited SDO download of `value` (1 to 4 bytes) into `index`:`sub` of `node`.
pub fn sdo_write(node: u8, index: u16, sub: u8, value: &[u8]) -> Option<crate::can::CanFrame> {
    if value.is_empty() || value.len() > 4 {
        return None;
    }
    let i = index.to_le_bytes();
    let mut d = [
        0x23 | (((4 - value.len()) as u8) << 2),
        i[0],
        i[1],
        sub,
        0,
        0,
        0,
        0,
    ];
    d[4..4 + value.len()].copy_from_slice(value);
    crate::can::CanFrame::standard(sdo_request_id(node), &d)
}

/// An SDO upload request for `index`:`sub` of `node`.
pub fn sdo_read(node: u8, index: u16, sub: u8) -> Option<crate::can::CanFrame> {
    let i = index.to_le_bytes();
    crate::can::CanFrame::standard(sdo_request_id(node), &[0x40, i[0], i[1], sub, 0, 0, 0, 0])
}

/// The request frames of a program download (CiA 302-3) of `image` to `node`: the block download
/// into 0x1F50:1 ([`sdo_block_download`]), then program control 0x1F51:1 = 1 (start).
pub fn program_download(node: u8, image: &[u8]) -> Vec<crate::can::CanFrame> {
    use crate::canopen::program::{PROGRAM_CONTROL, PROGRAM_DATA, control};
    let mut out = sdo_block_download(node, PROGRAM_DATA, 1, image);
    out.extend(sdo_write(node, PROGRAM_CONTROL, 1, &[control::START]));
    out
}

/// The abort code of an SDO response's data, if it is an abort (`0x80`).
pub fn sdo_abort_code(data: &[u8]) -> Option<u32> {
    crate::canopen::sdo::abort_code(data)
}
