//! An evaluation as a record of `docs/results/` (`trainer eval --record FILE`): the JSON that
//! `scripts/results.py` turns into the generated page `docs/results.md`, so a headline figure comes
//! from the command that measured it rather than from a number typed into a document.

use std::path::Path;

use serde::Serialize;
use sha2::{Digest, Sha256};

use crate::evaluate::PolicyEval;

/// What was evaluated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Evaluated {
    /// The policy file as the command named it.
    pub policy: String,
    /// SHA-256 of the file's bytes, hex.
    pub sha256: String,
}

/// One evaluation record (the fields `scripts/results.py` requires).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ResultRecord {
    /// Section of the results page (`table2`, `main-job`, ...).
    pub section: String,
    /// Order within the section.
    pub order: i64,
    /// Row label.
    pub what: String,
    /// The policy file and its hash.
    pub evaluated: Evaluated,
    /// The command line that produced the figure.
    pub command: String,
    /// Successful episodes.
    pub successes: u32,
    /// Episodes.
    pub episodes: u32,
    /// 95% Wilson interval of the success rate, in percent, one decimal.
    pub interval_95: [f64; 2],
    /// Seed of the first start.
    pub start_seed: u64,
    /// How the figure was measured.
    pub evaluation: String,
    /// UTC date, `YYYY-MM-DD`.
    pub date: String,
    /// The machine (CPU model, architecture, logical cores).
    pub machine: String,
    /// Wall-clock and threads of the evaluation.
    pub compute: String,
    /// Where the record came from.
    pub source: String,
}

/// Everything of a record that the evaluation itself does not say.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordContext<'a> {
    /// Section of the results page.
    pub section: &'a str,
    /// Row label.
    pub what: &'a str,
    /// The policy file's path as given.
    pub policy: &'a Path,
    /// The policy file's bytes.
    pub bytes: &'a [u8],
    /// The command line.
    pub command: String,
    /// Seed of the first start.
    pub start_seed: u64,
    /// Whether observations and actions went through the CAN quantisation.
    pub can_quantisation: bool,
    /// Whether the safety envelope was applied.
    pub envelope: bool,
    /// Wall-clock seconds of the evaluation.
    pub wall_s: f64,
    /// Threads it used.
    pub threads: usize,
}

/// Rounds a fraction to a percentage with one decimal.
fn percent(x: f64) -> f64 {
    (x * 1000.0).round() / 10.0
}

/// The hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// This machine in words: CPU model (Linux: `/proc/cpuinfo`), architecture, logical cores.
pub fn machine_description() -> String {
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split_once(':'))
                .map(|(_, m)| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".to_string());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!("{model}, {}, {cores} logical cores", std::env::consts::ARCH)
}

impl ResultRecord {
    /// The record of evaluation `e` in `ctx`, dated today (UTC).
    pub fn new(e: &PolicyEval, ctx: &RecordContext<'_>) -> Self {
        let mut how = String::from("the policy file through the runtime");
        if ctx.can_quantisation {
            how.push_str(" with CAN quantisation");
        } else {
            how.push_str(" without CAN quantisation");
        }
        if ctx.envelope {
            how.push_str(" and the safety envelope");
        }
        how.push_str(" (trainer eval), 95% Wilson interval");
        let today = time::OffsetDateTime::now_utc().date();
        ResultRecord {
            section: ctx.section.to_string(),
            order: 0,
            what: ctx.what.to_string(),
            evaluated: Evaluated {
                policy: ctx.policy.display().to_string(),
                sha256: sha256_hex(ctx.bytes),
            },
            command: ctx.command.clone(),
            successes: e.successes,
            episodes: e.episodes,
            interval_95: [percent(e.ci95.0), percent(e.ci95.1)],
            start_seed: ctx.start_seed,
            evaluation: how,
            date: format!(
                "{:04}-{:02}-{:02}",
                today.year(),
                u8::from(today.month()),
                today.day()
            ),
            machine: machine_description(),
            compute: format!("{:.0} s wall, {} threads", ctx.wall_s, ctx.threads),
            source: "trainer eval --record".to_string(),
        }
    }

    /// The record as pretty JSON (what goes into `docs/results/NAME.json`).
    pub fn to_json(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string_pretty(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_carries_the_counts_interval_hash_and_date() {
        let e = PolicyEval::from_outcomes(&[(1.0, true), (0.0, false), (1.0, true), (1.0, true)]);
        let ctx = RecordContext {
            section: "table2",
            what: "Grasp",
            policy: Path::new("policies/x.dxpl"),
            bytes: b"abc",
            command: "trainer eval policies/x.dxpl".into(),
            start_seed: 3_000_000,
            can_quantisation: true,
            envelope: false,
            wall_s: 12.4,
            threads: 2,
        };
        let r = ResultRecord::new(&e, &ctx);
        assert_eq!((r.successes, r.episodes), (3, 4));
        // The known SHA-256 of "abc".
        assert_eq!(
            r.evaluated.sha256,
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(r.interval_95, [percent(e.ci95.0), percent(e.ci95.1)]);
        assert!(r.interval_95[0] < 75.0 && r.interval_95[1] > 75.0);
        assert_eq!(r.date.len(), 10);
        assert!(r.date.starts_with("20"), "{}", r.date);
        assert!(r.evaluation.contains("with CAN quantisation"));
        assert_eq!(r.compute, "12 s wall, 2 threads");
        let json = r.to_json().unwrap();
        assert!(json.contains("\"section\": \"table2\""), "{json}");
    }
}
