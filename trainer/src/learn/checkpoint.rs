//! Checkpoints of a whole [`Trainer`]: parameters, targets, Adam moments, generators, counters and
//! replay buffers, so a resumed one-worker run continues bit-identically.
//!
//! Writing is atomic ([`crate::files::atomic_write::write_atomic`]): the file is written to a temporary file
//! next to `PATH`, flushed to disk, renamed over `PATH`, and the folder flushed, so a crash or a power
//! cut leaves either the previous checkpoint or the new one, never a torn file.
//!
//! Format (little-endian): magic `DEXLRN03` (the format version is its last two digits); the [`RunConfig`] as JSON (u64 length + bytes); observation
//! and action sizes; counters; shared parameters, targets, second moments and the update count; the
//! observation statistics; per worker its generator, first moments, transition count and optional
//! replay; the optional shared replay; with twin critics, the second critic, its target, second
//! moment and each worker's first moment; finally the CRC-32 ([`dex_policy::CRC32`], u32) of
//! everything before it. Formats 01 and 02 (an FNV-1a 64 hash at the end) are refused as written by
//! an older version.
//! Demonstration transitions are not stored: the caller gives them again
//! ([`Trainer::set_demonstrations`]). Arrays are a
//! u64 count then the values. A replay stores only its filled rows.

use super::LearnError;
use super::adam::{AdamLocal, AdamShared};
use super::ddpg::Networks;
use super::norm::ObsStats;
use super::replay::Replay;
use super::rng::Rng;
use super::trainer::{Counters, RunConfig, SharedState, Trainer, WorkerState};
use std::path::Path;

const MAGIC: &[u8; 8] = b"DEXLRN03";
/// The magic without its two version digits, to tell an older checkpoint from another file.
const MAGIC_STEM: &[u8; 6] = b"DEXLRN";
/// Bytes of the checksum at the end.
const SUM: usize = 4;

struct Enc {
    buf: Vec<u8>,
}

impl Enc {
    fn u64(&mut self, v: u64) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn bytes(&mut self, b: &[u8]) {
        self.u64(b.len() as u64);
        self.buf.extend_from_slice(b);
    }
    fn f32s(&mut self, v: &[f32]) {
        self.u64(v.len() as u64);
        self.buf.reserve(v.len() * 4);
        for x in v {
            self.buf.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        v.iter().for_each(|&x| self.f64(x));
    }
    fn rng(&mut self, r: &Rng) {
        let (s, spare) = r.state();
        s.iter().for_each(|&w| self.u64(w));
        self.u64(u64::from(spare.is_some()));
        self.f64(spare.unwrap_or(0.0));
    }
    fn replay(&mut self, r: Option<&Replay>) {
        let Some(r) = r else {
            self.u64(0);
            return;
        };
        self.u64(1);
        let (next, len, fields) = r.raw();
        self.u64(next as u64);
        self.u64(len as u64);
        for f in fields {
            let per_row = f.len() / r.capacity();
            self.f32s(&f[..len * per_row]);
        }
        // A labelling run's labels (the configuration says whether a buffer has them).
        if let Some(l) = r.labels() {
            let per_row = l.len() / r.capacity();
            self.f32s(&l[..len * per_row]);
        }
    }
}

struct Dec<'a> {
    b: &'a [u8],
}

const TRUNC: LearnError = LearnError::BadCheckpoint("file ends early");

impl Dec<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], LearnError> {
        if n > self.b.len() {
            return Err(TRUNC);
        }
        let (h, t) = self.b.split_at(n);
        self.b = t;
        Ok(h)
    }
    fn u64(&mut self) -> Result<u64, LearnError> {
        let mut a = [0u8; 8];
        a.copy_from_slice(self.take(8)?);
        Ok(u64::from_le_bytes(a))
    }
    fn usize(&mut self) -> Result<usize, LearnError> {
        usize::try_from(self.u64()?).map_err(|_| TRUNC)
    }
    fn f64(&mut self) -> Result<f64, LearnError> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn bytes(&mut self) -> Result<&[u8], LearnError> {
        let n = self.usize()?;
        self.take(n)
    }
    fn f32s(&mut self) -> Result<Vec<f32>, LearnError> {
        let n = self.usize()?;
        let raw = self.take(n.checked_mul(4).ok_or(TRUNC)?)?;
        Ok(raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }
    fn f64s_len(&mut self, len: usize) -> Result<Vec<f64>, LearnError> {
        let n = self.usize()?;
        if n != len {
            return Err(LearnError::BadCheckpoint(
                "array size does not match the configuration",
            ));
        }
        (0..n).map(|_| self.f64()).collect()
    }
    fn f32s_len(&mut self, len: usize) -> Result<Vec<f32>, LearnError> {
        let v = self.f32s()?;
        if v.len() == len {
            Ok(v)
        } else {
            Err(LearnError::BadCheckpoint(
                "array size does not match the configuration",
            ))
        }
    }
    fn rng(&mut self) -> Result<Rng, LearnError> {
        let s = [self.u64()?, self.u64()?, self.u64()?, self.u64()?];
        let has = self.u64()? != 0;
        let spare = self.f64()?;
        Ok(Rng::from_state(s, has.then_some(spare)))
    }
    fn replay(&mut self, slot: &mut Option<Replay>) -> Result<(), LearnError> {
        let present = self.u64()? != 0;
        let Some(r) = slot.as_mut() else {
            return if present {
                Err(LearnError::BadCheckpoint("unexpected replay buffer"))
            } else {
                Ok(())
            };
        };
        if !present {
            return Err(LearnError::BadCheckpoint("missing replay buffer"));
        }
        let next = self.usize()?;
        let len = self.usize()?;
        let cap = r.capacity();
        let (_, _, shapes) = r.raw();
        let per_row: Vec<usize> = shapes.iter().map(|f| f.len() / cap).collect();
        let mut fields: [Vec<f32>; 5] = Default::default();
        for (f, &pr) in fields.iter_mut().zip(&per_row) {
            let mut v = self.f32s()?;
            if v.len() != len.saturating_mul(pr) {
                return Err(LearnError::BadCheckpoint("replay rows do not match"));
            }
            v.resize(cap * pr, 0.0);
            *f = v;
        }
        let labels = match r.labels().map(|l| l.len() / cap) {
            Some(pr) => {
                let mut v = self.f32s()?;
                if v.len() != len.saturating_mul(pr) {
                    return Err(LearnError::BadCheckpoint("replay labels do not match"));
                }
                v.resize(cap * pr, 0.0);
                Some(v)
            }
            None => None,
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
        let mut e = Enc { buf: Vec::new() };
        e.buf.extend_from_slice(MAGIC);
        // RunConfig holds only numbers, booleans and enums: serialising it cannot fail.
        e.bytes(&serde_json::to_vec(&self.cfg).unwrap_or_default());
        e.u64(self.nets.obs_dim as u64);
        e.u64(self.nets.act_dim as u64);
        e.u64(self.counters.episodes);
        e.u64(self.counters.evals);
        e.f64(self.counters.wall_s);
        let s = &self.shared;
        for v in [&s.actor, &s.critic, &s.target_actor, &s.target_critic] {
            e.f32s(v);
        }
        for a in [&s.actor_adam, &s.critic_adam] {
            e.f32s(&a.v);
            e.u64(a.t);
        }
        e.u64(s.updates);
        e.u64(s.obs_stats.count);
        e.f64s(&s.obs_stats.mean);
        e.f64s(&s.obs_stats.m2);
        e.u64(self.workers.len() as u64);
        for w in &self.workers {
            e.rng(&w.rng);
            for m in [&w.actor_m, &w.critic_m] {
                e.f32s(&m.m);
                e.u64(m.t);
            }
            e.u64(w.transitions);
            e.replay(w.replay.as_ref());
        }
        e.replay(self.shared_replay.as_ref());
        if self.cfg.td3.twin_critics {
            e.f32s(&s.critic2);
            e.f32s(&s.target_critic2);
            e.f32s(&s.critic2_adam.v);
            e.u64(s.critic2_adam.t);
            for w in &self.workers {
                e.f32s(&w.critic2_m.m);
                e.u64(w.critic2_m.t);
            }
        }
        let sum = dex_policy::CRC32.checksum(&e.buf);
        e.buf.extend_from_slice(&sum.to_le_bytes());
        e.buf
    }

    /// Decodes [`Trainer::to_checkpoint_bytes`].
    pub fn from_checkpoint_bytes(bytes: &[u8]) -> Result<Trainer, LearnError> {
        if bytes.len() < MAGIC.len() + SUM || !bytes.starts_with(MAGIC_STEM) {
            return Err(LearnError::BadCheckpoint("not a learner checkpoint"));
        }
        match &bytes[..MAGIC.len()] {
            b"DEXLRN01" | b"DEXLRN02" => {
                return Err(LearnError::BadCheckpoint(
                    "written by an older version of the trainer (checkpoint format 01 or 02, this \
                     build reads 03): resume it with that version or start the run again",
                ));
            }
            m if m != MAGIC => {
                return Err(LearnError::BadCheckpoint(
                    "written by a newer or unknown version of the trainer (this build reads 03)",
                ));
            }
            _ => {}
        }
        let (body, tail) = bytes.split_at(bytes.len() - SUM);
        let stored = u32::from_le_bytes([tail[0], tail[1], tail[2], tail[3]]);
        if dex_policy::CRC32.checksum(body) != stored {
            return Err(LearnError::BadCheckpoint(
                "checksum mismatch (damaged file)",
            ));
        }
        let mut d = Dec { b: &body[8..] };
        let cfg: RunConfig = serde_json::from_slice(d.bytes()?)
            .map_err(|_| LearnError::BadCheckpoint("configuration is not valid JSON"))?;
        let obs_dim = d.usize()?;
        let act_dim = d.usize()?;
        let mut t = Trainer::new(cfg, obs_dim, act_dim)?;
        t.counters = Counters {
            episodes: d.u64()?,
            evals: d.u64()?,
            wall_s: d.f64()?,
        };
        let nets: &Networks = &t.nets;
        let (na, nc) = (nets.actor.num_params(), nets.critic.num_params());
        let mut s = SharedState {
            actor: d.f32s_len(na)?,
            critic: d.f32s_len(nc)?,
            target_actor: d.f32s_len(na)?,
            target_critic: d.f32s_len(nc)?,
            ..SharedState::default()
        };
        s.actor_adam = AdamShared {
            v: d.f32s_len(na)?,
            t: d.u64()?,
        };
        s.critic_adam = AdamShared {
            v: d.f32s_len(nc)?,
            t: d.u64()?,
        };
        s.updates = d.u64()?;
        s.obs_stats = ObsStats {
            count: d.u64()?,
            mean: d.f64s_len(obs_dim)?,
            m2: d.f64s_len(obs_dim)?,
        };
        t.shared = s;
        if d.usize()? != t.workers.len() {
            return Err(LearnError::BadCheckpoint("worker count does not match"));
        }
        for w in &mut t.workers {
            let rng = d.rng()?;
            let actor_m = AdamLocal {
                m: d.f32s_len(na)?,
                t: d.u64()?,
            };
            let critic_m = AdamLocal {
                m: d.f32s_len(nc)?,
                t: d.u64()?,
            };
            let transitions = d.u64()?;
            d.replay(&mut w.replay)?;
            *w = WorkerState {
                rng,
                actor_m,
                critic_m,
                critic2_m: AdamLocal::new(0),
                replay: w.replay.take(),
                transitions,
            };
        }
        d.replay(&mut t.shared_replay)?;
        if t.cfg.td3.twin_critics {
            t.shared.critic2 = d.f32s_len(nc)?;
            t.shared.target_critic2 = d.f32s_len(nc)?;
            t.shared.critic2_adam = AdamShared {
                v: d.f32s_len(nc)?,
                t: d.u64()?,
            };
            for w in &mut t.workers {
                w.critic2_m = AdamLocal {
                    m: d.f32s_len(nc)?,
                    t: d.u64()?,
                };
            }
        }
        if !d.b.is_empty() {
            return Err(LearnError::BadCheckpoint("trailing bytes"));
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
        assert_eq!(&bytes[..8], b"DEXLRN03");
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
        // A checkpoint of an earlier version (FNV-1a 64 at the end) gets a clear error, not a
        // checksum mismatch.
        for old in [b"DEXLRN01", b"DEXLRN02"] {
            let mut b = bytes.clone();
            b[..8].copy_from_slice(old);
            assert!(refused(&b).starts_with("written by an older version"));
        }
        let mut newer = bytes.clone();
        newer[..8].copy_from_slice(b"DEXLRN04");
        assert!(refused(&newer).starts_with("written by a newer"));
        assert_eq!(refused(b"DXDEMO01 and more"), "not a learner checkpoint");
    }
}
