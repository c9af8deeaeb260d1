//! The hand-made binary formats (checkpoints, `.dxdm` demo files, MPI messages) against `postcard`,
//! which the workspace already uses for policy files (issue #28: keep a hand-made format only
//! where a benchmark says so). The three formats are, by bytes, almost all f32 arrays: a
//! checkpoint of the Stack paper run is 167 MB of replay rows, networks and Adam moments; an MPI
//! push is a few hundred kB of parameter and second-moment deltas. So the spike times the f32
//! arrays: encoding and decoding `N` values (the 167 MB checkpoint's 41.8M by default) the way
//! `learn/checkpoint.rs` does (little-endian bytes appended; `chunks_exact(4)` back) and through
//! postcard (`Vec<f32>` via serde, each value 4 little-endian bytes after a varint length).
//!
//! ```sh
//! cargo run --release -p dex-trainer --example format_spike -- [N] [ROUNDS]
//! ```
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;
use std::time::Instant;

fn hand_encode(values: &[f32]) -> Vec<u8> {
    let mut buf = Vec::with_capacity(8 + 4 * values.len());
    buf.extend_from_slice(&(values.len() as u64).to_le_bytes());
    for v in values {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    buf
}

fn hand_decode(bytes: &[u8]) -> Vec<f32> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let body = &bytes[8..8 + 4 * n];
    body.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

fn best_of<T>(rounds: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::INFINITY;
    let mut out = None;
    for _ in 0..rounds {
        let t = Instant::now();
        let r = black_box(f());
        best = best.min(t.elapsed().as_secs_f64());
        out = Some(r);
    }
    (best, out.unwrap())
}

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().map_or(41_800_000, |a| a.parse().expect("N"));
    let rounds: usize = args.next().map_or(3, |a| a.parse().expect("ROUNDS"));
    let values: Vec<f32> = (0..n).map(|i| (i as f32 * 0.618).sin()).collect();
    let mb = 4.0 * n as f64 / 1e6;

    let (te_hand, hand) = best_of(rounds, || hand_encode(&values));
    let (td_hand, back_hand) = best_of(rounds, || hand_decode(&hand));
    let (te_pc, pc) = best_of(rounds, || postcard::to_allocvec(&values).unwrap());
    let (td_pc, back_pc) = best_of(rounds, || postcard::from_bytes::<Vec<f32>>(&pc).unwrap());
    assert!(back_hand == values && back_pc == values);
    println!("{n} f32 values ({mb:.1} MB), best of {rounds}:");
    for (name, te, td, len) in [
        ("hand-made", te_hand, td_hand, hand.len()),
        ("postcard", te_pc, td_pc, pc.len()),
    ] {
        println!(
            "  {name:<9}  encode {:7.1} ms ({:6.0} MB/s)  decode {:7.1} ms ({:6.0} MB/s)  {len} bytes",
            te * 1e3,
            mb / te,
            td * 1e3,
            mb / td
        );
    }
}
