//! The messages between the parameter server (rank 0) and the worker ranks, as bytes.
//!
//! Every message is a header, a body and a checksum (all little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 4 | magic `DXMP` |
//! | 2 | [`VERSION`] |
//! | 1 | kind: 1 [`Push`], 2 [`Params`], 3 stop |
//! | 1 | zero |
//! | 4 | sending rank |
//! | 8 | body length in bytes |
//! | body | per kind, below |
//! | 4 | CRC-32 ([`dex_policy::CRC32`]) of everything before it |
//!
//! Arrays are a u32 count then the values. A [`Push`] body: transitions, episodes and updates
//! since the previous push (u64 each), the sum of training returns (f64) and their count (u64),
//! the networks (u32 count; per network its Adam steps u64, then the parameter change and the
//! second-moment change as f32 arrays), then the evaluations (u32 count; per evaluation success
//! rate, mean return and training return as f64 and the worker thread as u32). A [`Params`]
//! body: the update count and the transitions of the whole run (u64 each), then per network
//! (u32 count) the parameters, the target and the second moment (f32 arrays) and Adam's step
//! count (u64). A stop has an empty body.
//!
//! [`decode`] refuses anything that is not exactly such a message for the networks it expects:
//! a wrong magic, version, kind, length or checksum, arrays of the wrong size, and non-finite
//! values. The caller counts refusals; nothing of a refused message is applied.

use super::DistributedError;

/// The wire version; a change of any layout above bumps it (version 1 ended in an FNV-1a 64
/// checksum, version 2 in a CRC-32).
pub const VERSION: u16 = 2;
/// Bytes of the checksum at the end.
const SUM: usize = 4;
const MAGIC: &[u8; 4] = b"DXMP";
const HEADER: usize = 4 + 2 + 1 + 1 + 4 + 8;
const KIND_PUSH: u8 = 1;
const KIND_PARAMS: u8 = 2;
const KIND_STOP: u8 = 3;

/// One network's part of a [`Push`].
#[derive(Debug, Clone, PartialEq)]
pub struct NetDelta {
    /// Adam steps this rank applied to the network since its previous push.
    pub steps: u64,
    /// Change of the parameters since the previous push (the sum of the rank's Adam steps).
    pub delta: Vec<f32>,
    /// Change of the second moment: `v_now - beta2^steps * v_then`.
    pub dv: Vec<f32>,
}

/// One evaluation of a worker rank, forwarded to the server's log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemoteEval {
    /// Fraction of evaluation episodes ending in success.
    pub success_rate: f64,
    /// Mean undiscounted return of the evaluation episodes.
    pub mean_return: f64,
    /// Mean return of the rank's training episodes since its previous evaluation.
    pub train_return: f64,
    /// The worker thread (on its rank) that ran it.
    pub worker: u32,
}

/// Worker rank to server: what the rank learned and collected since its previous push.
#[derive(Debug, Clone, PartialEq)]
pub struct Push {
    /// Environment transitions since the previous push.
    pub transitions: u64,
    /// Training episodes finished since the previous push.
    pub episodes: u64,
    /// Updates (mini-batches) since the previous push.
    pub updates: u64,
    /// Sum of the training episodes' returns since the previous push.
    pub return_sum: f64,
    /// Number of those episodes.
    pub return_n: u64,
    /// Actor, critic (and twin critic).
    pub nets: Vec<NetDelta>,
    /// Evaluations finished since the previous push.
    pub evals: Vec<RemoteEval>,
}

/// One network's part of [`Params`].
#[derive(Debug, Clone, PartialEq)]
pub struct NetParams {
    /// Online parameters.
    pub params: Vec<f32>,
    /// Target parameters.
    pub target: Vec<f32>,
    /// Adam's shared second moment.
    pub v: Vec<f32>,
    /// Adam's shared step count.
    pub t: u64,
}

/// Server to worker rank: the shared state as it is now.
#[derive(Debug, Clone, PartialEq)]
pub struct Params {
    /// Updates of the whole run.
    pub updates: u64,
    /// Transitions of the whole run.
    pub transitions: u64,
    /// Actor, critic (and twin critic).
    pub nets: Vec<NetParams>,
}

/// A decoded message.
#[derive(Debug, Clone, PartialEq)]
pub enum Message {
    /// Worker to server.
    Push(Push),
    /// Server to worker.
    Params(Params),
    /// Server to worker: the run is over (or failed); stop and exit.
    Stop,
}

/// Encodes `msg` as sent by `rank`.
pub fn encode(rank: u32, msg: &Message) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(MAGIC);
    b.extend_from_slice(&VERSION.to_le_bytes());
    let kind = match msg {
        Message::Push(_) => KIND_PUSH,
        Message::Params(_) => KIND_PARAMS,
        Message::Stop => KIND_STOP,
    };
    b.push(kind);
    b.push(0);
    b.extend_from_slice(&rank.to_le_bytes());
    b.extend_from_slice(&0u64.to_le_bytes());
    match msg {
        Message::Push(p) => {
            for v in [p.transitions, p.episodes, p.updates] {
                put_u64(&mut b, v);
            }
            put_u64(&mut b, p.return_sum.to_bits());
            put_u64(&mut b, p.return_n);
            put_u32(&mut b, p.nets.len() as u32);
            for n in &p.nets {
                put_u64(&mut b, n.steps);
                put_f32s(&mut b, &n.delta);
                put_f32s(&mut b, &n.dv);
            }
            put_u32(&mut b, p.evals.len() as u32);
            for e in &p.evals {
                for v in [e.success_rate, e.mean_return, e.train_return] {
                    put_u64(&mut b, v.to_bits());
                }
                put_u32(&mut b, e.worker);
            }
        }
        Message::Params(p) => {
            put_u64(&mut b, p.updates);
            put_u64(&mut b, p.transitions);
            put_u32(&mut b, p.nets.len() as u32);
            for n in &p.nets {
                put_f32s(&mut b, &n.params);
                put_f32s(&mut b, &n.target);
                put_f32s(&mut b, &n.v);
                put_u64(&mut b, n.t);
            }
        }
        Message::Stop => {}
    }
    let body = (b.len() - HEADER) as u64;
    b[HEADER - 8..HEADER].copy_from_slice(&body.to_le_bytes());
    let sum = dex_policy::CRC32.checksum(&b);
    put_u32(&mut b, sum);
    b
}

/// Decodes a message from `bytes`, checking it against the networks' parameter counts
/// (`net_sizes`: actor, critic, and the twin critic when the run has one). Returns the sending
/// rank and the message.
pub fn decode(bytes: &[u8], net_sizes: &[usize]) -> Result<(u32, Message), DistributedError> {
    let bad = |why: &'static str| DistributedError::BadMessage { why };
    if bytes.len() < HEADER + SUM {
        return Err(bad("shorter than a header"));
    }
    if &bytes[..4] != MAGIC {
        return Err(bad("wrong magic"));
    }
    let mut d = Dec { b: &bytes[4..] };
    match d.u16()? {
        VERSION => {}
        v if v < VERSION => return Err(bad("older wire version (a rank of an older build)")),
        _ => return Err(bad("wrong wire version")),
    }
    let kind = d.u8()?;
    let _zero = d.u8()?;
    let rank = d.u32()?;
    let body = d.u64()?;
    if body != (bytes.len() - HEADER - SUM) as u64 {
        return Err(bad("length does not match the header"));
    }
    let (payload, sum) = bytes.split_at(bytes.len() - SUM);
    if u32::from_le_bytes([sum[0], sum[1], sum[2], sum[3]]) != dex_policy::CRC32.checksum(payload) {
        return Err(bad("checksum mismatch"));
    }
    let mut d = Dec {
        b: &payload[HEADER..],
    };
    let msg = match kind {
        KIND_PUSH => {
            let transitions = d.u64()?;
            let episodes = d.u64()?;
            let updates = d.u64()?;
            let return_sum = f64::from_bits(d.u64()?);
            let return_n = d.u64()?;
            if !return_sum.is_finite() {
                return Err(bad("non-finite return"));
            }
            let n = d.u32()? as usize;
            if n != net_sizes.len() {
                return Err(bad("wrong number of networks"));
            }
            let mut nets = Vec::with_capacity(n);
            for &size in net_sizes {
                let steps = d.u64()?;
                let delta = d.f32s(size)?;
                let dv = d.f32s(size)?;
                nets.push(NetDelta { steps, delta, dv });
            }
            let ne = d.u32()? as usize;
            if ne > d.b.len() / 28 {
                return Err(bad("evaluation count beyond the message"));
            }
            let mut evals = Vec::with_capacity(ne);
            for _ in 0..ne {
                let e = RemoteEval {
                    success_rate: f64::from_bits(d.u64()?),
                    mean_return: f64::from_bits(d.u64()?),
                    train_return: f64::from_bits(d.u64()?),
                    worker: d.u32()?,
                };
                if !(e.success_rate.is_finite()
                    && e.mean_return.is_finite()
                    && e.train_return.is_finite())
                {
                    return Err(bad("non-finite evaluation"));
                }
                evals.push(e);
            }
            Message::Push(Push {
                transitions,
                episodes,
                updates,
                return_sum,
                return_n,
                nets,
                evals,
            })
        }
        KIND_PARAMS => {
            let updates = d.u64()?;
            let transitions = d.u64()?;
            let n = d.u32()? as usize;
            if n != net_sizes.len() {
                return Err(bad("wrong number of networks"));
            }
            let mut nets = Vec::with_capacity(n);
            for &size in net_sizes {
                nets.push(NetParams {
                    params: d.f32s(size)?,
                    target: d.f32s(size)?,
                    v: d.f32s(size)?,
                    t: d.u64()?,
                });
            }
            Message::Params(Params {
                updates,
                transitions,
                nets,
            })
        }
        KIND_STOP => Message::Stop,
        _ => return Err(bad("unknown kind")),
    };
    if !d.b.is_empty() {
        return Err(bad("bytes after the body"));
    }
    Ok((rank, msg))
}

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}

fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}

fn put_f32s(b: &mut Vec<u8>, v: &[f32]) {
    put_u32(b, v.len() as u32);
    b.reserve(v.len() * 4);
    for x in v {
        b.extend_from_slice(&x.to_le_bytes());
    }
}

struct Dec<'a> {
    b: &'a [u8],
}

const SHORT: DistributedError = DistributedError::BadMessage {
    why: "ends inside the body",
};

impl Dec<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], DistributedError> {
        if self.b.len() < N {
            return Err(SHORT);
        }
        let (h, t) = self.b.split_at(N);
        self.b = t;
        let mut a = [0u8; N];
        a.copy_from_slice(h);
        Ok(a)
    }
    fn u8(&mut self) -> Result<u8, DistributedError> {
        Ok(self.take::<1>()?[0])
    }
    fn u16(&mut self) -> Result<u16, DistributedError> {
        Ok(u16::from_le_bytes(self.take()?))
    }
    fn u32(&mut self) -> Result<u32, DistributedError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    fn u64(&mut self) -> Result<u64, DistributedError> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    /// An array that must hold exactly `want` finite values.
    fn f32s(&mut self, want: usize) -> Result<Vec<f32>, DistributedError> {
        let n = self.u32()? as usize;
        if n != want {
            return Err(DistributedError::BadMessage {
                why: "array size does not match the network",
            });
        }
        let bytes = n.checked_mul(4).ok_or(SHORT)?;
        if self.b.len() < bytes {
            return Err(SHORT);
        }
        let (h, t) = self.b.split_at(bytes);
        self.b = t;
        let v: Vec<f32> = h
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if v.iter().any(|x| !x.is_finite()) {
            return Err(DistributedError::BadMessage {
                why: "non-finite value",
            });
        }
        Ok(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SIZES: [usize; 2] = [3, 2];

    fn push() -> Message {
        Message::Push(Push {
            transitions: 50,
            episodes: 2,
            updates: 10,
            return_sum: -3.5,
            return_n: 2,
            nets: vec![
                NetDelta {
                    steps: 10,
                    delta: vec![0.1, -0.2, 0.3],
                    dv: vec![1e-4, 0.0, 2e-4],
                },
                NetDelta {
                    steps: 10,
                    delta: vec![0.5, 0.25],
                    dv: vec![0.0, 1e-3],
                },
            ],
            evals: vec![RemoteEval {
                success_rate: 0.8,
                mean_return: 12.0,
                train_return: 9.0,
                worker: 1,
            }],
        })
    }

    fn params() -> Message {
        Message::Params(Params {
            updates: 1234,
            transitions: 5678,
            nets: SIZES
                .iter()
                .map(|&n| NetParams {
                    params: vec![1.0; n],
                    target: vec![0.5; n],
                    v: vec![0.01; n],
                    t: 99,
                })
                .collect(),
        })
    }

    /// Re-seals a message whose bytes a test changed, so that only the change is wrong.
    fn reseal(mut b: Vec<u8>) -> Vec<u8> {
        let n = b.len() - SUM;
        let sum = dex_policy::CRC32.checksum(&b[..n]);
        b[n..].copy_from_slice(&sum.to_le_bytes());
        b
    }

    #[test]
    fn every_kind_round_trips() {
        for m in [push(), params(), Message::Stop] {
            let b = encode(7, &m);
            assert_eq!(decode(&b, &SIZES).ok(), Some((7, m)));
        }
    }

    #[test]
    fn header_layout_is_pinned() {
        let b = encode(2, &Message::Stop);
        assert_eq!(&b[..4], b"DXMP");
        assert_eq!(&b[4..8], &[2, 0, 3, 0]);
        assert_eq!(&b[8..12], &[2, 0, 0, 0]);
        assert_eq!(&b[12..20], &[0; 8]);
        assert_eq!(b.len(), HEADER + SUM);
    }

    fn refused(b: &[u8]) -> &'static str {
        match decode(b, &SIZES) {
            Err(DistributedError::BadMessage { why }) => why,
            other => panic!("not refused: {other:?}"),
        }
    }

    #[test]
    fn wrong_version_is_refused() {
        let mut b = encode(1, &push());
        b[4] = 3;
        assert_eq!(refused(&reseal(b.clone())), "wrong wire version");
        b[4] = 1;
        assert_eq!(
            refused(&reseal(b)),
            "older wire version (a rank of an older build)"
        );
    }

    #[test]
    fn wrong_length_is_refused() {
        let b = encode(1, &push());
        // Cut short, one byte more, and an empty buffer.
        assert_eq!(
            refused(&b[..b.len() - 1]),
            "length does not match the header"
        );
        let mut long = b.clone();
        long.push(0);
        assert_eq!(refused(&long), "length does not match the header");
        assert_eq!(refused(&[]), "shorter than a header");
        // A header that claims the right length around a body cut inside an array.
        let mut cut = b[..b.len() - SUM - 40].to_vec();
        let body = (cut.len() - HEADER) as u64;
        cut[HEADER - 8..HEADER].copy_from_slice(&body.to_le_bytes());
        cut.extend_from_slice(&[0; SUM]);
        assert_eq!(refused(&reseal(cut)), "ends inside the body");
    }

    #[test]
    fn wrong_sizes_and_kinds_are_refused() {
        let b = encode(1, &push());
        assert!(matches!(
            decode(&b, &[3, 3]),
            Err(DistributedError::BadMessage {
                why: "array size does not match the network"
            })
        ));
        assert!(matches!(
            decode(&b, &[3, 2, 2]),
            Err(DistributedError::BadMessage {
                why: "wrong number of networks"
            })
        ));
        let mut k = b.clone();
        k[6] = 9;
        assert_eq!(refused(&reseal(k)), "unknown kind");
        let mut m = b;
        m[0] = b'X';
        assert_eq!(refused(&m), "wrong magic");
    }

    #[test]
    fn flipped_bit_fails_the_checksum() {
        let mut b = encode(1, &params());
        let i = b.len() / 2;
        b[i] ^= 0x10;
        assert_eq!(refused(&b), "checksum mismatch");
    }

    #[test]
    fn non_finite_gradients_are_refused() {
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let Message::Push(mut p) = push() else {
                unreachable!()
            };
            p.nets[1].delta[0] = bad;
            assert_eq!(
                refused(&encode(1, &Message::Push(p.clone()))),
                "non-finite value"
            );
            p.nets[1].delta[0] = 0.0;
            p.nets[0].dv[2] = bad;
            assert_eq!(refused(&encode(1, &Message::Push(p))), "non-finite value");
        }
        let Message::Push(mut p) = push() else {
            unreachable!()
        };
        p.evals[0].success_rate = f64::NAN;
        assert_eq!(
            refused(&encode(1, &Message::Push(p))),
            "non-finite evaluation"
        );
    }
}
