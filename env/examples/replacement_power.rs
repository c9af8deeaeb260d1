//! What a file must score to replace one that fails `F` of `N` paired starts under the project's
//! rule (more successes and an exact McNemar p < 0.01, `dex_env::paired::mcnemar_exact`): for
//! each count `b` of starts the new file fails where the old one succeeds, the fewest of the old
//! file's failures it must fix (`c`), and the success it then has. Also the chance of passing when
//! the new file's failures are a re-roll: each start fails independently with probability `q`.
//!
//! ```text
//! cargo run --release -p dex-env --example replacement_power -- [N 1000] [F 12] [P 0.01]
//! ```

use dex_env::paired::mcnemar_exact;
use statrs::distribution::{Binomial, Discrete};

fn main() {
    let arg = |i: usize, d: f64| {
        std::env::args()
            .nth(i)
            .and_then(|s| s.parse::<f64>().ok())
            .unwrap_or(d)
    };
    let n = arg(1, 1000.0) as u32;
    let f = arg(2, 12.0) as u32;
    let alpha = arg(3, 0.01);
    println!(
        "old file: {} / {n} ({f} failures); rule: more successes, p < {alpha}",
        n - f
    );
    println!(
        "| new failures where the old succeeds (b) | old failures fixed needed (c) | new file at best |"
    );
    println!("|---:|---:|---|");
    for b in 0..=8u32 {
        match (0..=f).find(|&c| c > b && mcnemar_exact(b, c) < alpha) {
            Some(c) => println!(
                "| {b} | {c} | {} / {n} (p = {:.4}) |",
                n - (f - c) - b,
                mcnemar_exact(b, c)
            ),
            None => println!("| {b} | more than the {f} there are | - |"),
        }
    }
    // Exact chance of passing for a new file whose starts fail independently with probability q
    // (the old file's failures and successes alike): b ~ Bin(N - F, q), c ~ Bin(F, 1 - q).
    println!("\n| new file's failure rate q | chance of passing the rule |");
    println!("|---:|---:|");
    for q in [0.012, 0.008, 0.006, 0.004, 0.002, 0.001] {
        let pb = binom(n - f, q);
        let pc = binom(f, 1.0 - q);
        let mut pass = 0.0;
        for (b, &wb) in pb.iter().enumerate().take(40) {
            for (c, &wc) in pc.iter().enumerate() {
                if c > b && mcnemar_exact(b as u32, c as u32) < alpha {
                    pass += wb * wc;
                }
            }
        }
        println!("| {q} | {pass:.3} |");
    }
}

/// The probabilities of 0..=n successes of Binomial(n, p) (statrs' pmf).
fn binom(n: u32, p: f64) -> Vec<f64> {
    match Binomial::new(p, u64::from(n)) {
        Ok(b) => (0..=u64::from(n)).map(|k| b.pmf(k)).collect(),
        Err(_) => vec![0.0; n as usize + 1],
    }
}
