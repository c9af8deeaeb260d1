//! The fine-tune's checkpoint file: a versioned header, then the state in postcard with the
//! settings as JSON.
//!
//! Why the settings are JSON inside a binary file: postcard is not self-describing, so a setting
//! added to [`GroupPg`] (session 35's `stall_noise_steps`) changed the layout and an older run
//! folder no longer decoded. As JSON, a setting added later with a serde default decodes from an
//! older checkpoint as that default, which is the value the older run ran with. The header names
//! the layout of the rest, so a checkpoint of another layout is refused by name, not by a decode
//! error.

use serde::{Deserialize, Serialize};

use crate::pipeline::stall_starts::StallStart;

use super::GroupPg;

/// The first bytes of a checkpoint.
pub const MAGIC: [u8; 4] = *b"DXPG";

/// The layout this trainer writes and reads (little-endian after [`MAGIC`]).
pub const VERSION: u16 = 1;

/// A fine-tune's checkpoint: its settings and its state after an iteration.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Checkpoint {
    pub settings: GroupPg,
    pub state: State,
}

/// What a run has done so far (layout 1 writes it after the settings' JSON, in postcard).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(super) struct State {
    pub next_iteration: u32,
    pub env_steps: u64,
    pub params: Vec<f32>,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    pub t_local: u64,
    pub t_shared: u64,
    pub hard: Vec<u64>,
    pub stalls: Vec<StallStart>,
}

/// Layout 1's bytes of `settings_json` and `state`, after the header.
fn encode_v1(settings_json: &str, state: &State) -> Result<Vec<u8>, String> {
    let mut out = MAGIC.to_vec();
    out.extend_from_slice(&VERSION.to_le_bytes());
    postcard::to_extend(&(settings_json, state), out).map_err(|e| e.to_string())
}

impl Checkpoint {
    /// The file's bytes; the error says why it could not be written.
    pub fn encode(&self) -> Result<Vec<u8>, String> {
        let json = serde_json::to_string(&self.settings).map_err(|e| e.to_string())?;
        encode_v1(&json, &self.state)
    }

    /// The checkpoint in `bytes`; the error says why it is refused.
    pub fn decode(bytes: &[u8]) -> Result<Checkpoint, String> {
        let Some(rest) = bytes.strip_prefix(&MAGIC[..]) else {
            return Err(
                "it has no version header: it was written by a trainer older than \
                        the versioned checkpoint (before 2026-12-06), whose layout this one \
                        does not read; finish the run with that trainer or use another folder"
                    .to_owned(),
            );
        };
        let (version, body) = match rest {
            [a, b, body @ ..] => (u16::from_le_bytes([*a, *b]), body),
            _ => return Err("it ends inside its header".to_owned()),
        };
        if version != VERSION {
            return Err(format!(
                "it has layout version {version}, this trainer reads version {VERSION}; use \
                 the trainer that wrote it or another folder"
            ));
        }
        let (json, state): (String, State) =
            postcard::from_bytes(body).map_err(|e| e.to_string())?;
        let settings: GroupPg =
            serde_json::from_str(&json).map_err(|e| format!("its settings: {e}"))?;
        Ok(Checkpoint { settings, state })
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    fn checkpoint() -> Checkpoint {
        Checkpoint {
            settings: GroupPg {
                stall_groups: 4,
                stall_noise_steps: 60,
                ..GroupPg::new(PathBuf::from("start.dxpl"))
            },
            state: State {
                next_iteration: 7,
                env_steps: 123_456,
                params: vec![0.5, -1.25, 3.0],
                m: vec![0.1, 0.2, 0.3],
                v: vec![1e-6, 2e-6, 3e-6],
                t_local: 21,
                t_shared: 42,
                hard: vec![9, 8],
                stalls: Vec::new(),
            },
        }
    }

    #[test]
    fn a_checkpoint_reads_back_as_written() {
        let c = checkpoint();
        let bytes = c.encode().unwrap();
        assert_eq!(&bytes[..4], b"DXPG");
        assert_eq!(Checkpoint::decode(&bytes).unwrap(), c);
    }

    #[test]
    fn a_setting_added_later_reads_as_its_default_from_an_older_checkpoint() {
        let c = checkpoint();
        let mut json: serde_json::Value = serde_json::to_value(&c.settings).unwrap();
        json.as_object_mut().unwrap().remove("stall_noise_steps");
        let bytes = encode_v1(&json.to_string(), &c.state).unwrap();
        let back = Checkpoint::decode(&bytes).unwrap();
        assert_eq!(back.settings.stall_noise_steps, 0);
        assert_eq!(back.state, c.state);
    }

    #[test]
    fn other_layouts_are_refused_by_name() {
        let bytes = checkpoint().encode().unwrap();
        let old = &bytes[6..];
        let why = Checkpoint::decode(old).unwrap_err();
        assert!(why.contains("no version header"), "{why}");
        let mut newer = bytes.clone();
        newer[4..6].copy_from_slice(&2u16.to_le_bytes());
        let why = Checkpoint::decode(&newer).unwrap_err();
        assert!(why.contains("layout version 2"), "{why}");
        assert!(Checkpoint::decode(b"DXPG\x01").is_err());
        assert!(Checkpoint::decode(&bytes[..bytes.len() - 3]).is_err());
    }
}
