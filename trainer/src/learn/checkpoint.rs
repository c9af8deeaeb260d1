//! Checkpoints of a whole [`Trainer`]: parameters, targets, Adam moments, generators, counters and
//! replay buffers, so a resumed one-worker run continues bit-identically.
//!
//! Writing is atomic ([`crate::files::atomic_write::write_atomic`]): the file is written to a temporary file
//! next to `PATH`, flushed to disk, renamed over `PATH`, and the folder flushed, so a crash or a power
//! cut leaves either the previous checkpoint or the new one, never a torn file.
//!
//! Format: magic `DEXLRN04` (the format version is its last two digits), then a `postcard` body
//! (the private `Body` below: the [`RunConfig`] as JSON, observation and action sizes, counters,
//! shared parameters, targets, second moments and the update count, the observation statistics,
//! per worker its generator, first moments, transition count and optional replay, the optional
//! shared replay, and with twin critics the second critic, its target, second moment and each
//! worker's first moments), then the CRC-32 ([`dex_policy::CRC32`], u32 little-endian) of
//! everything before it. A replay stores only its filled rows. Demonstration transitions are not
//! stored: the caller gives them again ([`Trainer::set_demonstrations`]). Every array's length is
//! checked against the configuration on the way back.
//!
//! Until format 03 the body was written by hand; `examples/format_spike.rs` measured the two on
//! this data's shape (f32 arrays, 167 MB): postcard encodes as fast and decodes about 30% slower
//! (docs/benchmarks.md), no reason to keep a format of our own. Formats 01-03 are refused as
//! written by an older version.

use super::LearnError;
use super::adam::{AdamLocal, AdamShared};
use super::ddpg::Networks;
use super::norm::ObsStats;
use super::replay::Replay;
use super::rng::Rng;
use super::trainer::{Counters, RunConfig, SharedState, Trainer, WorkerState};
use serde::{Deserialize, Serialize};
use std::borrow::Cow;
use std::path::Path;

const MAGIC: &[u8; 8] = b"DEXLRN04";
/// The magic without its two version digits, to tell an older checkpoint from another file.
const MAGIC_STEM: &[u8; 6] = b"DEXLRN";
/// Bytes of the checksum at the end.
const SUM: usize = 4;

/// An array: borrowed when writing, owned when read back.
type Floats<'a> = Cow<'a, [f32]>;

/// A first or second Adam moment and its step count.
#[derive(Serialize, Deserialize)]
struct Moment<'a> {
    values: Floats<'a>,
    t: u64,
}

/// The filled rows of a replay buffer (and of its labels, when it has them).
#[derive(Serialize, Deserialize)]
struct ReplayRows<'a> {
    next: u64,
    len: u64,
    fields: [Floats<'a>; 5],
    labels: Option<Floats<'a>>,
}

#[derive(Serialize, Deserialize)]
struct WorkerBody<'a> {
    rng: ([u64; 4], Option<f64>),
    actor_m: Moment<'a>,
    critic_m: Moment<'a>,
    transitions: u64,
    replay: Option<ReplayRows<'a>>,
}

/// The second critic of twin-critic runs.
#[derive(Serialize, Deserialize)]
struct TwinBody<'a> {
    critic2: Floats<'a>,
    target_critic2: Floats<'a>,
    adam: Moment<'a>,
    worker_m: Vec<Moment<'a>>,
}

/// Everything between the magic and the checksum.
#[derive(Serialize, Deserialize)]
struct Body<'a> {
    config_json: Cow<'a, str>,
    obs_dim: u64,
    act_dim: u64,
    episodes: u64,
    evals: u64,
    wall_s: f64,
    actor: Floats<'a>,
    critic: Floats<'a>,
    target_actor: Floats<'a>,
    target_critic: Floats<'a>,
    actor_adam: Moment<'a>,
    critic_adam: Moment<'a>,
    updates: u64,
    obs_count: u64,
    obs_mean: Vec<f64>,
    obs_m2: Vec<f64>,
    workers: Vec<WorkerBody<'a>>,
    shared_replay: Option<ReplayRows<'a>>,
    twin: Option<TwinBody<'a>>,
}

const MISMATCH: LearnError =
    LearnError::BadCheckpoint("array size does not match the configuration");

/// `v` when it has `len` values.
fn sized(v: Floats<'_>, len: usize) -> Result<Vec<f32>, LearnError> {
    if v.len() == len {
        Ok(v.into_owned())
    } else {
        Err(MISMATCH)
    }
}

fn shared_moment(m: Moment<'_>, len: usize) -> Result<AdamShared, LearnError> {
    Ok(AdamShared {
        v: sized(m.values, len)?,
        t: m.t,
    })
}

fn local_moment(m: Moment<'_>, len: usize) -> Result<AdamLocal, LearnError> {
    Ok(AdamLocal {
        m: sized(m.values, len)?,
        t: m.t,
    })
}

fn usize_of(v: u64) -> Result<usize, LearnError> {
    usize::try_from(v).map_err(|_| MISMATCH)
}

/// The filled rows of `r`, borrowed.
fn replay_rows(r: Option<&Replay>) -> Option<ReplayRows<'_>> {
    fn filled(f: &[f32], len: usize, cap: usize) -> Floats<'_> {
        Cow::Borrowed(&f[..len * (f.len() / cap)])
    }
    let r = r?;
    let (next, len, fields) = r.raw();
    let cap = r.capacity();
    Some(ReplayRows {
        next: next as u64,
        len: len as u64,
        fields: fields.map(|f| filled(f, len, cap)),
        labels: r.labels().map(|l| filled(l, len, cap)),
    })
}

/// Puts `rows` back into the configured buffer `slot` (both present or both absent).
fn restore_replay(
    slot: &mut Option<Replay>,
    rows: Option<ReplayRows<'_>>,
) -> Result<(), LearnError> {
    let (r, rows) = match (slot.as_mut(), rows) {
        (None, None) => return Ok(()),
        (None, Some(_)) => return Err(LearnError::BadCheckpoint("unexpected replay buffer")),
        (Some(_), None) => return Err(LearnError::BadCheckpoint("missing replay buffer")),
        (Some(r), Some(rows)) => (r, rows),
    };
    let (next, len) = (usize_of(rows.next)?, usize_of(rows.len)?);
    let cap = r.capacity();
    let (_, _, shapes) = r.raw();
    let per_row: [usize; 5] = shapes.map(|f| f.len() / cap);
    let mut fields: [Vec<f32>; 5] = Default::default();
    for ((f, v), pr) in fields.iter_mut().zip(rows.fields).zip(per_row) {
        if v.len() != len.saturating_mul(pr) {
            return Err(LearnError::BadCheckpoint("replay rows do not match"));
        }
        let mut v = v.into_owned();
        v.resize(cap * pr, 0.0);
        *f = v;
    }
    let labels = match (r.labels().map(|l| l.len() / cap), rows.labels) {
        (Some(pr), Some(v)) if v.len() == len.saturating_mul(pr) => {
            let mut v = v.into_owned();
            v.resize(cap * pr, 0.0);
            Some(v)
        }
        (None, None) => None,
        _ => return Err(LearnError::BadCheckpoint("replay labels do not match")),
    };
    let restored = r.restore(next, len, fields) && labels.is_none_or(|l| r.restore_labels(l));
    if restored {
        Ok(())
    } else {
        Err(LearnError::BadCheckpoint(
            "replay does not fit the configured capacity",
        ))
    }
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> LearnError + '_ {
    move |source| LearnError::Io {
        path: path.to_path_buf(),
        source,
    }
}

impl Trainer {
    /// Encodes the whole training state.
    pub fn to_checkpoint_bytes(&self) -> Vec<u8> {
        fn moment(values: &[f32], t: u64) -> Moment<'_> {
            Moment {
                values: Cow::Borrowed(values),
                t,
            }
        }
        let s = &self.shared;
        let body = Body {
            // RunConfig holds only numbers, booleans and enums: serialising it cannot fail.
            config_json: Cow::Owned(serde_json::to_string(&self.cfg).unwrap_or_default()),
            obs_dim: self.nets.obs_dim as u64,
            act_dim: self.nets.act_dim as u64,
            episodes: self.counters.episodes,
            evals: self.counters.evals,
            wall_s: self.counters.wall_s,
            actor: Cow::Borrowed(&s.actor),
            critic: Cow::Borrowed(&s.critic),
            target_actor: Cow::Borrowed(&s.target_actor),
            target_critic: Cow::Borrowed(&s.target_critic),
            actor_adam: moment(&s.actor_adam.v, s.actor_adam.t),
            critic_adam: moment(&s.critic_adam.v, s.critic_adam.t),
            updates: s.updates,
            obs_count: s.obs_stats.count,
            obs_mean: s.obs_stats.mean.clone(),
            obs_m2: s.obs_stats.m2.clone(),
            workers: self
                .workers
                .iter()
                .map(|w| WorkerBody {
                    rng: w.rng.state(),
                    actor_m: moment(&w.actor_m.m, w.actor_m.t),
                    critic_m: moment(&w.critic_m.m, w.critic_m.t),
                    transitions: w.transitions,
                    replay: replay_rows(w.replay.as_ref()),
                })
                .collect(),
            shared_replay: replay_rows(self.shared_replay.as_ref()),
            twin: self.cfg.td3.twin_critics.then(|| TwinBody {
                critic2: Cow::Borrowed(&s.critic2),
                target_critic2: Cow::Borrowed(&s.target_critic2),
                adam: moment(&s.critic2_adam.v, s.critic2_adam.t),
                worker_m: self
                    .workers
                    .iter()
                    .map(|w| moment(&w.critic2_m.m, w.critic2_m.t))
                    .collect(),
            }),
        };
        let mut buf = MAGIC.to_vec();
        // Serialising into a Vec cannot fail (postcard's only errors are a full buffer and
        // types it does not support, neither of which `Body` has).
        buf = postcard::to_extend(&body, buf).unwrap_or_default();
        let sum = dex_policy::CRC32.checksum(&buf);
        buf.extend_from_slice(&sum.to_le_bytes());
        buf
    }

    /// Decodes [`Trainer::to_checkpoint_bytes`].
    pub fn from_checkpoint_bytes(bytes: &[u8]) -> Result<Trainer, LearnError> {
        if bytes.len() < MAGIC.len() + SUM || !bytes.starts_with(MAGIC_STEM) {
            return Err(LearnError::BadCheckpoint("not a learner checkpoint"));
        }
        match &bytes[..MAGIC.len()] {
            b"DEXLRN01" | b"DEXLRN02" | b"DEXLRN03" => {
                return Err(LearnError::BadCheckpoint(
                    "written by an older version of the trainer (checkpoint format 01 to 03, this \
                     build reads 04): resume it with that version or start the run again",
                ));
            }
            m if m != MAGIC => {
                return Err(LearnError::BadCheckpoint(
                    "written by a newer or unknown version of the trainer (this build reads 04)",
                ));
            }
            _ => {}
        }
        let (all, tail) = bytes.split_at(bytes.len() - SUM);
        let stored = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
        if dex_policy::CRC32.checksum(all) != stored {
            return Err(LearnError::BadCheckpoint(
                "checksum mismatch (damaged file)",
            ));
        }
        let (body, rest) = postcard::take_from_bytes::<Body<'_>>(&all[MAGIC.len()..])
            .map_err(|_| LearnError::BadCheckpoint("body does not decode"))?;
        if !rest.is_empty() {
            return Err(LearnError::BadCheckpoint("trailing bytes"));
        }
        let cfg: RunConfig = serde_json::from_str(&body.config_json)
            .map_err(|_| LearnError::BadCheckpoint("configuration is not valid JSON"))?;
        let obs_dim = usize_of(body.obs_dim)?;
        let mut t = Trainer::new(cfg, obs_dim, usize_of(body.act_dim)?)?;
        t.counters = Counters {
            episodes: body.episodes,
            evals: body.evals,
            wall_s: body.wall_s,
        };
        let nets: &Networks = &t.nets;
        let (na, nc) = (nets.actor.num_params(), nets.critic.num_params());
        if body.obs_mean.len() != obs_dim || body.obs_m2.len() != obs_dim {
            return Err(MISMATCH);
        }
        t.shared = SharedState {
            actor: sized(body.actor, na)?,
            critic: sized(body.critic, nc)?,
            target_actor: sized(body.target_actor, na)?,
            target_critic: sized(body.target_critic, nc)?,
            actor_adam: shared_moment(body.actor_adam, na)?,
            critic_adam: shared_moment(body.critic_adam, nc)?,
            updates: body.updates,
            obs_stats: ObsStats {
                count: body.obs_count,
                mean: body.obs_mean,
                m2: body.obs_m2,
            },
            ..SharedState::default()
        };
        if body.workers.len() != t.workers.len() {
            return Err(LearnError::BadCheckpoint("worker count does not match"));
        }
        for (w, b) in t.workers.iter_mut().zip(body.workers) {
            let mut replay = w.replay.take();
            restore_replay(&mut replay, b.replay)?;
            *w = WorkerState {
                rng: Rng::from_state(b.rng.0, b.rng.1),
                actor_m: local_moment(b.actor_m, na)?,
                critic_m: local_moment(b.critic_m, nc)?,
                critic2_m: AdamLocal::new(0),
                replay,
                transitions: b.transitions,
            };
        }
        restore_replay(&mut t.shared_replay, body.shared_replay)?;
        match (t.cfg.td3.twin_critics, body.twin) {
            (false, None) => {}
            (true, Some(twin)) if twin.worker_m.len() == t.workers.len() => {
                t.shared.critic2 = sized(twin.critic2, nc)?;
                t.shared.target_critic2 = sized(twin.target_critic2, nc)?;
                t.shared.critic2_adam = shared_moment(twin.adam, nc)?;
                for (w, m) in t.workers.iter_mut().zip(twin.worker_m) {
                    w.critic2_m = local_moment(m, nc)?;
                }
            }
            _ => {
                return Err(LearnError::BadCheckpoint(
                    "second critic does not match the configuration",
                ));
            }
        }
        Ok(t)
    }

    /// Writes a checkpoint atomically and durably ([`crate::files::atomic_write::write_atomic`]: a
    /// temporary file, fsync, rename, fsync of the folder).
    pub fn save(&self, path: &Path) -> Result<(), LearnError> {
        crate::files::atomic_write::write_atomic(path, &self.to_checkpoint_bytes())
            .map_err(io_err(path))
    }

    /// Reads a checkpoint written by [`Trainer::save`].
    pub fn load(path: &Path) -> Result<Trainer, LearnError> {
        let bytes = std::fs::read(path).map_err(io_err(path))?;
        Self::from_checkpoint_bytes(&bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refused(bytes: &[u8]) -> &'static str {
        match Trainer::from_checkpoint_bytes(bytes) {
            Err(LearnError::BadCheckpoint(why)) => why,
            Err(other) => panic!("another error: {other}"),
            Ok(_) => panic!("not refused"),
        }
    }

    #[test]
    fn round_trips_and_refuses_damage_and_older_versions() {
        let t = Trainer::new(RunConfig::default(), 4, 2).expect("trainer");
        let bytes = t.to_checkpoint_bytes();
        assert_eq!(&bytes[..8], b"DEXLRN04");
        let n = bytes.len() - SUM;
        assert_eq!(
            bytes[n..],
            dex_policy::CRC32.checksum(&bytes[..n]).to_le_bytes()
        );
        let back = Trainer::from_checkpoint_bytes(&bytes).expect("round trip");
        assert_eq!(back.to_checkpoint_bytes(), bytes);

        let mut flipped = bytes.clone();
        flipped[n / 2] ^= 0x10;
        assert_eq!(refused(&flipped), "checksum mismatch (damaged file)");
        assert_eq!(refused(&bytes[..n]), "checksum mismatch (damaged file)");
        // A checkpoint of an earlier version (FNV-1a 64 at the end, or the hand-made body of 03)
        // gets a clear error, not a checksum mismatch.
        for old in [b"DEXLRN01", b"DEXLRN02", b"DEXLRN03"] {
            let mut b = bytes.clone();
            b[..8].copy_from_slice(old);
            assert!(refused(&b).starts_with("written by an older version"));
        }
        let mut newer = bytes.clone();
        newer[..8].copy_from_slice(b"DEXLRN05");
        assert!(refused(&newer).starts_with("written by a newer"));
        assert_eq!(refused(b"DXDEMO01 and more"), "not a learner checkpoint");
    }

    #[test]
    fn a_run_with_twin_critics_and_two_replays_round_trips_and_checks_sizes() {
        let mut cfg = crate::learn::distributed::point_mass::point_mass_config(3, 2);
        cfg.td3.twin_critics = true;
        cfg.replay.shared = false;
        let mut t = Trainer::new(cfg, 6, 2).expect("trainer");
        let stop = std::sync::atomic::AtomicBool::new(false);
        let env = |_| super::super::PointMass::new(super::super::PointMassConfig::default());
        t.run(env, 600, &stop, &mut |_| {}).expect("run");
        let bytes = t.to_checkpoint_bytes();
        let back = Trainer::from_checkpoint_bytes(&bytes).expect("round trip");
        assert_eq!(back.to_checkpoint_bytes(), bytes);
        assert!(
            back.workers
                .iter()
                .all(|w| w.replay.as_ref().is_some_and(|r| !r.is_empty()))
        );
        // A body whose arrays do not fit the configuration it carries is refused (the actor of a
        // wider network under this configuration), with a valid checksum.
        let mut wide = crate::learn::distributed::point_mass::point_mass_config(3, 2);
        wide.td3.twin_critics = true;
        wide.replay.shared = false;
        wide.ddpg.actor_hidden = vec![64, 64, 64];
        let other = Trainer::new(wide, 6, 2)
            .expect("trainer")
            .to_checkpoint_bytes();
        let (_, rest) =
            postcard::take_from_bytes::<Body<'_>>(&other[8..other.len() - SUM]).unwrap();
        assert!(rest.is_empty());
        let mut body: Body<'_> = postcard::from_bytes(&bytes[8..bytes.len() - SUM]).unwrap();
        let theirs: Body<'_> = postcard::from_bytes(&other[8..other.len() - SUM]).unwrap();
        body.actor = theirs.actor;
        let mut forged = MAGIC.to_vec();
        forged = postcard::to_extend(&body, forged).unwrap();
        let sum = dex_policy::CRC32.checksum(&forged);
        forged.extend_from_slice(&sum.to_le_bytes());
        assert_eq!(
            refused(&forged),
            "array size does not match the configuration"
        );
    }
}
