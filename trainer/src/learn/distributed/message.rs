//! The messages between the parameter server (rank 0) and the worker ranks, as bytes.
//!
//! Every message is a fixed header, a body and a checksum:
//!
//! | bytes | field |
//! |---|---|
//! | 4 | magic `DXMP` |
//! | 2 | [`VERSION`], little-endian |
//! | 1 | kind: 1 [`Push`], 2 [`Params`], 3 stop |
//! | 1 | zero |
//! | 4 | sending rank, little-endian |
//! | 8 | body length in bytes, little-endian |
//! | body | the kind's struct ([`Push`] or [`Params`]) in `postcard`; empty for a stop |
//! | 4 | CRC-32 ([`dex_policy::CRC32`]) of everything before it |
//!
//! The header stays fixed-width so that a receiver can refuse a message of another build or
//! kind, or a truncated one, before it decodes anything; the body is `postcard`, the workspace's
//! format for structured bytes (the checkpoints use it too).
//!
//! [`decode`] refuses anything that is not exactly such a message for the networks it expects:
//! a wrong magic, version, kind, length or checksum, a body that does not decode or has bytes
//! after it, arrays of the wrong size, and non-finite values. The caller counts refusals; nothing
//! of a refused message is applied.

use serde::{Deserialize, Serialize};

use super::DistributedError;

/// The wire version; a change of any layout above bumps it (version 1 ended in an FNV-1a 64
/// checksum, version 2 had a hand-made body, version 3 a `postcard` one).
pub const VERSION: u16 = 3;
/// Bytes of the checksum at the end.
const SUM: usize = 4;
const MAGIC: &[u8; 4] = b"DXMP";
const HEADER: usize = 4 + 2 + 1 + 1 + 4 + 8;
const KIND_PUSH: u8 = 1;
const KIND_PARAMS: u8 = 2;
const KIND_STOP: u8 = 3;

/// One network's part of a [`Push`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetDelta {
    /// Adam steps this rank applied to the network since its previous push.
    pub steps: u64,
    /// Change of the parameters since the previous push (the sum of the rank's Adam steps).
    pub delta: Vec<f32>,
    /// Change of the second moment: `v_now - beta2^steps * v_then`.
    pub dv: Vec<f32>,
}

/// One evaluation of a worker rank, forwarded to the server's log.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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

fn bad(why: &'static str) -> DistributedError {
    DistributedError::BadMessage { why }
}

/// Encodes `msg` as sent by `rank`.
pub fn encode(rank: u32, msg: &Message) -> Result<Vec<u8>, DistributedError> {
    let kind = match msg {
        Message::Push(_) => KIND_PUSH,
        Message::Params(_) => KIND_PARAMS,
        Message::Stop => KIND_STOP,
    };
    let mut b = Vec::with_capacity(HEADER);
    b.extend_from_slice(MAGIC);
    b.extend_from_slice(&VERSION.to_le_bytes());
    b.push(kind);
    b.push(0);
    b.extend_from_slice(&rank.to_le_bytes());
    b.extend_from_slice(&0u64.to_le_bytes());
    let body = match msg {
        Message::Push(p) => postcard::to_extend(p, b),
        Message::Params(p) => postcard::to_extend(p, b),
        Message::Stop => Ok(b),
    };
    let mut b = body.map_err(|_| bad("the body does not encode"))?;
    let len = (b.len() - HEADER) as u64;
    b[HEADER - 8..HEADER].copy_from_slice(&len.to_le_bytes());
    let sum = dex_policy::CRC32.checksum(&b);
    b.extend_from_slice(&sum.to_le_bytes());
    Ok(b)
}

/// Decodes a message from `bytes`, checking it against the networks' parameter counts
/// (`net_sizes`: actor, critic, and the twin critic when the run has one). Returns the sending
/// rank and the message.
pub fn decode(bytes: &[u8], net_sizes: &[usize]) -> Result<(u32, Message), DistributedError> {
    if bytes.len() < HEADER + SUM {
        return Err(bad("shorter than a header"));
    }
    if &bytes[..4] != MAGIC {
        return Err(bad("wrong magic"));
    }
    match u16::from_le_bytes([bytes[4], bytes[5]]) {
        VERSION => {}
        v if v < VERSION => return Err(bad("older wire version (a rank of an older build)")),
        _ => return Err(bad("wrong wire version")),
    }
    let kind = bytes[6];
    let rank = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    let mut len = [0u8; 8];
    len.copy_from_slice(&bytes[12..HEADER]);
    if u64::from_le_bytes(len) != (bytes.len() - HEADER - SUM) as u64 {
        return Err(bad("length does not match the header"));
    }
    let (payload, sum) = bytes.split_at(bytes.len() - SUM);
    if u32::from_le_bytes([sum[0], sum[1], sum[2], sum[3]]) != dex_policy::CRC32.checksum(payload) {
        return Err(bad("checksum mismatch"));
    }
    let body = &payload[HEADER..];
    let msg = match kind {
        KIND_PUSH => {
            let p: Push = body_of(body)?;
            if !p.return_sum.is_finite() {
                return Err(bad("non-finite return"));
            }
            check_nets(net_sizes, p.nets.iter().map(|n| [&n.delta[..], &n.dv[..]]))?;
            if p.evals.iter().any(|e| {
                !(e.success_rate.is_finite()
                    && e.mean_return.is_finite()
                    && e.train_return.is_finite())
            }) {
                return Err(bad("non-finite evaluation"));
            }
            Message::Push(p)
        }
        KIND_PARAMS => {
            let p: Params = body_of(body)?;
            check_nets(
                net_sizes,
                p.nets
                    .iter()
                    .map(|n| [&n.params[..], &n.target[..], &n.v[..]]),
            )?;
            Message::Params(p)
        }
        KIND_STOP if body.is_empty() => Message::Stop,
        KIND_STOP => return Err(bad("bytes after the body")),
        _ => return Err(bad("unknown kind")),
    };
    Ok((rank, msg))
}

/// The body as `T`, all of it.
fn body_of<'a, T: Deserialize<'a>>(body: &'a [u8]) -> Result<T, DistributedError> {
    match postcard::take_from_bytes::<T>(body) {
        Ok((value, [])) => Ok(value),
        Ok(_) => Err(bad("bytes after the body")),
        Err(postcard::Error::DeserializeUnexpectedEnd) => Err(bad("ends inside the body")),
        Err(_) => Err(bad("the body does not decode")),
    }
}

/// Every network's arrays hold exactly its parameter count of finite values.
fn check_nets<'a, const K: usize>(
    net_sizes: &[usize],
    nets: impl ExactSizeIterator<Item = [&'a [f32]; K]>,
) -> Result<(), DistributedError> {
    if nets.len() != net_sizes.len() {
        return Err(bad("wrong number of networks"));
    }
    for (arrays, &size) in nets.zip(net_sizes) {
        for a in arrays {
            if a.len() != size {
                return Err(bad("array size does not match the network"));
            }
            if a.iter().any(|x| !x.is_finite()) {
                return Err(bad("non-finite value"));
            }
        }
    }
    Ok(())
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
            let b = encode(7, &m).unwrap();
            assert_eq!(decode(&b, &SIZES).ok(), Some((7, m)));
        }
    }

    #[test]
    fn header_layout_is_pinned() {
        let b = encode(2, &Message::Stop).unwrap();
        assert_eq!(&b[..4], b"DXMP");
        assert_eq!(&b[4..8], &[3, 0, 3, 0]);
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
        let mut b = encode(1, &push()).unwrap();
        b[4] = 4;
        assert_eq!(refused(&reseal(b.clone())), "wrong wire version");
        b[4] = 2;
        assert_eq!(
            refused(&reseal(b)),
            "older wire version (a rank of an older build)"
        );
    }

    #[test]
    fn wrong_length_is_refused() {
        let b = encode(1, &push()).unwrap();
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
        let b = encode(1, &push()).unwrap();
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
    fn a_body_with_bytes_after_it_is_refused() {
        for m in [push(), params(), Message::Stop] {
            let mut b = encode(1, &m).unwrap();
            b.truncate(b.len() - SUM);
            b.push(0);
            let body = (b.len() - HEADER) as u64;
            b[HEADER - 8..HEADER].copy_from_slice(&body.to_le_bytes());
            b.extend_from_slice(&[0; SUM]);
            assert_eq!(refused(&reseal(b)), "bytes after the body");
        }
    }

    #[test]
    fn flipped_bit_fails_the_checksum() {
        let mut b = encode(1, &params()).unwrap();
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
                refused(&encode(1, &Message::Push(p.clone())).unwrap()),
                "non-finite value"
            );
            p.nets[1].delta[0] = 0.0;
            p.nets[0].dv[2] = bad;
            assert_eq!(
                refused(&encode(1, &Message::Push(p)).unwrap()),
                "non-finite value"
            );
        }
        let Message::Push(mut p) = push() else {
            unreachable!()
        };
        p.evals[0].success_rate = f64::NAN;
        assert_eq!(
            refused(&encode(1, &Message::Push(p)).unwrap()),
            "non-finite evaluation"
        );
    }
}
