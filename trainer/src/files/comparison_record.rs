//! A `trainer compare` record (`--json`), and the pooling of records of disjoint starts into one
//! comparison (`trainer pool`).
//!
//! A long paired test runs as chunks of starts, so that a stopped session loses at most one
//! chunk. Each chunk is an ordinary comparison of the same entries on its own starts; the chunks'
//! starts are disjoint, so their successes and discordant starts add up and the exact McNemar
//! test of the sums is the test of the whole sample. [`pool`] checks that the records can be
//! pooled (one task, the same entries in the same order, the same files where the records name
//! their hashes, the same bus, no start in two chunks) before it adds anything.

use std::collections::HashMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::env::evaluate::{episode_seed, wilson_interval};
use crate::env::paired::{Paired, mcnemar_exact};

/// One entry's outcomes for [`ComparisonRecord::of`]: its name, its file's SHA-256 (hex; `None`
/// for an entry that is not one file) and its (return, success) outcomes, start by start.
pub type EntryOutcomes = (String, Option<String>, Vec<(f64, bool)>);

/// One compared entry: a policy file, an ensemble, a pair or the teacher.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComparedEntry {
    /// What was compared (a file's path as given, or a description).
    pub name: String,
    /// The SHA-256 of the policy file (hex); absent for entries that are not one file, and in
    /// records written before the field existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
    /// Starts solved.
    pub successes: u32,
    /// Starts run.
    pub episodes: u32,
    /// Wilson 95% interval of the success rate, in percent.
    pub interval_95: (f64, f64),
    /// The starts it failed, ascending: index `i` is the start `episode_seed(start_seed, i)`, so
    /// a failure can be set beside what the start holds (the bricks' spacing, say). Absent in a
    /// pooled record (its starts come from several seeds) and in records written before the
    /// field existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub failed_starts: Option<Vec<u32>>,
}

impl ComparedEntry {
    /// An entry of `successes` of `episodes`, with its Wilson interval.
    pub fn new(name: String, sha256: Option<String>, successes: u32, episodes: u32) -> Self {
        let (lo, hi) = wilson_interval(successes, episodes);
        Self {
            name,
            sha256,
            successes,
            episodes,
            interval_95: (100.0 * lo, 100.0 * hi),
            failed_starts: None,
        }
    }
}

/// One compared pair: entry A against entry B on the same starts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComparedPair {
    /// Entry A's name.
    pub a: String,
    /// Entry B's name.
    pub b: String,
    /// The paired counts and the exact McNemar p-value.
    pub paired: Paired,
}

/// A `trainer compare --json` record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComparisonRecord {
    /// The command line that made it.
    pub command: String,
    /// The task (`Grasp`, `StackInHand`, `Stack`).
    pub task: String,
    /// Episode `i` starts from `episode_seed(start_seed, i)`.
    pub start_seed: u64,
    /// Starts, the same for every entry.
    pub episodes: u32,
    /// Whether observations and actions went through the CAN bus's quantisation.
    pub can_quantisation: bool,
    /// Every entry's successes.
    pub entries: Vec<ComparedEntry>,
    /// Every pair of entries, in the order of the entries.
    pub pairs: Vec<ComparedPair>,
    /// Wall-clock seconds the comparison took.
    pub wall_s: f64,
}

/// Why a record cannot be read, or records cannot be pooled.
#[derive(Debug, thiserror::Error)]
pub enum ComparisonError {
    /// The file cannot be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not a comparison record.
    #[error("{path} is not a `trainer compare --json` record: {source}")]
    Parse {
        /// The file.
        path: String,
        /// The JSON error.
        source: serde_json::Error,
    },
    /// Fewer than two records.
    #[error("pooling needs at least two records, got {0}")]
    TooFew(usize),
    /// A record's task, bus or entries differ from the first record's.
    #[error("{record} cannot be pooled with {first}: {what}")]
    Mismatch {
        /// The record that differs.
        record: String,
        /// The first record.
        first: String,
        /// What differs.
        what: String,
    },
    /// Two records share a start.
    #[error(
        "{a} and {b} share starts (start seeds {seed_a} and {seed_b}): pooled chunks must be \
         disjoint"
    )]
    SharedStarts {
        /// One record.
        a: String,
        /// The other.
        b: String,
        /// Its start seed.
        seed_a: u64,
        /// The other's start seed.
        seed_b: u64,
    },
    /// The record holds no entry of the file, or that entry lists no failed starts.
    #[error("{record}: {what}")]
    NoFailedStarts {
        /// The record.
        record: String,
        /// What is missing.
        what: String,
    },
    /// A record's counts contradict themselves (successes above episodes, or discordant starts
    /// the entries' successes cannot give).
    #[error("{record}: {what}")]
    Inconsistent {
        /// The record.
        record: String,
        /// What is wrong.
        what: String,
    },
}

impl ComparisonRecord {
    /// The start seeds (`episode_seed(start_seed, i)`) that the entry of the file with SHA-256
    /// `sha256` (hex) failed, in start order; `record` names the record in errors. Refused when no
    /// entry is that file (a list of another file's failures would aim a fine-tune at the wrong
    /// starts) or the entry lists no failed starts (a pooled or older record).
    pub fn failed_seeds_of(&self, sha256: &str, record: &str) -> Result<Vec<u64>, ComparisonError> {
        let missing = |what: String| ComparisonError::NoFailedStarts {
            record: record.to_owned(),
            what,
        };
        let entry = self
            .entries
            .iter()
            .find(|e| e.sha256.as_deref() == Some(sha256))
            .ok_or_else(|| missing(format!("no entry is the file of SHA-256 {sha256}")))?;
        let failed = entry.failed_starts.as_ref().ok_or_else(|| {
            missing(format!(
                "entry {} lists no failed starts (a pooled record, or one written before \
                 the list existed)",
                entry.name
            ))
        })?;
        Ok(failed
            .iter()
            .map(|&i| episode_seed(self.start_seed, u64::from(i)))
            .collect())
    }

    /// Reads a record written by `trainer compare --json`.
    pub fn read(path: &Path) -> Result<Self, ComparisonError> {
        read_record(path)
    }

    /// The record of `outcomes`: per entry its name, its file's hash (if it is one file) and its
    /// (return, success) outcomes on the same starts in the same order (episode `i` from
    /// `episode_seed(start_seed, i)`); every pair of entries in order.
    pub fn of(
        command: String,
        task: String,
        start_seed: u64,
        can_quantisation: bool,
        outcomes: &[EntryOutcomes],
        wall_s: f64,
    ) -> Self {
        let episodes = outcomes.first().map_or(0, |(_, _, o)| o.len() as u32);
        let entries = outcomes
            .iter()
            .map(|(name, sha, o)| {
                let successes = o.iter().filter(|(_, s)| *s).count() as u32;
                let failed = (0..o.len() as u32).filter(|&i| !o[i as usize].1).collect();
                ComparedEntry {
                    failed_starts: Some(failed),
                    ..ComparedEntry::new(name.clone(), sha.clone(), successes, o.len() as u32)
                }
            })
            .collect();
        let mut pairs = Vec::new();
        for (i, (a, _, oa)) in outcomes.iter().enumerate() {
            for (b, _, ob) in &outcomes[i + 1..] {
                pairs.push(ComparedPair {
                    a: a.clone(),
                    b: b.clone(),
                    paired: Paired::of(oa, ob),
                });
            }
        }
        Self {
            command,
            task,
            start_seed,
            episodes,
            can_quantisation,
            entries,
            pairs,
            wall_s,
        }
    }

    /// Checks the record's own counts: no entry solves more starts than it ran, every pair is of
    /// two entries of the record, over its starts, with discordant counts its entries allow.
    fn check(&self, name: &str) -> Result<(), ComparisonError> {
        let bad = |what: String| ComparisonError::Inconsistent {
            record: name.to_string(),
            what,
        };
        for e in &self.entries {
            if e.episodes != self.episodes || e.successes > e.episodes {
                return Err(bad(format!(
                    "entry {} has {} of {} starts in a record of {}",
                    e.name, e.successes, e.episodes, self.episodes
                )));
            }
            if let Some(f) = &e.failed_starts {
                let listed = f.len() as u64 == u64::from(e.episodes - e.successes)
                    && f.windows(2).all(|w| w[0] < w[1])
                    && f.last().is_none_or(|&i| i < e.episodes);
                if !listed {
                    return Err(bad(format!(
                        "entry {}'s failed starts do not match its {} failures of {}",
                        e.name,
                        e.episodes - e.successes,
                        e.episodes
                    )));
                }
            }
        }
        for p in &self.pairs {
            let find = |n: &str| self.entries.iter().find(|e| e.name == n);
            let (Some(a), Some(b)) = (find(&p.a), find(&p.b)) else {
                return Err(bad(format!("pair {} vs {} names no entry", p.a, p.b)));
            };
            let q = &p.paired;
            let consistent = q.episodes == self.episodes
                && q.a_successes == a.successes
                && q.b_successes == b.successes
                && q.only_a <= q.a_successes
                && q.only_b <= q.b_successes
                && i64::from(q.a_successes) - i64::from(q.only_a)
                    == i64::from(q.b_successes) - i64::from(q.only_b);
            if !consistent {
                return Err(bad(format!(
                    "pair {} vs {}: its counts do not match its entries",
                    p.a, p.b
                )));
            }
        }
        Ok(())
    }
}

/// The most starts a pooled comparison holds (a bound on the work and memory of the check
/// that no start is in two chunks; 10 million starts are some 500 CPU-hours of episodes).
pub const MAX_POOLED_STARTS: u32 = 10_000_000;

/// A JSON record of type `T` from `path`, the path named in either error.
fn read_record<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, ComparisonError> {
    let name = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ComparisonError::Read {
        path: name.clone(),
        source,
    })?;
    serde_json::from_str(&text).map_err(|source| ComparisonError::Parse { path: name, source })
}

/// What every comparison record holds, plain (`trainer compare --json`) or pooled (`trainer pool
/// --json`): enough to plan the next test from it (`trainer power`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct ComparisonSummary {
    /// The task.
    pub task: String,
    /// Starts, the same for every entry.
    pub episodes: u32,
    /// Every entry's successes.
    pub entries: Vec<ComparedEntry>,
    /// Every pair of entries.
    pub pairs: Vec<ComparedPair>,
    /// Wall-clock seconds the comparison (or its chunks, summed) took.
    pub wall_s: f64,
}

impl ComparisonSummary {
    /// Reads a plain or pooled record; its pairs' counts must fit its starts.
    pub fn read(path: &Path) -> Result<Self, ComparisonError> {
        let name = path.display().to_string();
        let s: Self = read_record(path)?;
        for p in &s.pairs {
            let d = &p.paired;
            if d.episodes != s.episodes || d.only_a.saturating_add(d.only_b) > d.episodes {
                return Err(ComparisonError::Inconsistent {
                    record: name,
                    what: format!(
                        "pair {} vs {}: {} and {} discordant starts of {} (the record has {})",
                        p.a, p.b, d.only_a, d.only_b, d.episodes, s.episodes
                    ),
                });
            }
        }
        Ok(s)
    }
}

/// One chunk of a pooled comparison.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PooledChunk {
    /// The chunk's record, as given.
    pub record: String,
    /// Its start seed.
    pub start_seed: u64,
    /// Its starts.
    pub episodes: u32,
    /// Its wall-clock seconds.
    pub wall_s: f64,
}

/// Records of disjoint starts pooled into one comparison: the entries' successes and the pairs'
/// discordant starts summed, the intervals and McNemar p-values of the sums.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PooledComparison {
    /// The command line that pooled them.
    pub command: String,
    /// The task.
    pub task: String,
    /// Whether observations and actions went through the CAN bus's quantisation.
    pub can_quantisation: bool,
    /// The chunks, in the order given.
    pub chunks: Vec<PooledChunk>,
    /// Starts in all chunks.
    pub episodes: u32,
    /// Every entry over all chunks.
    pub entries: Vec<ComparedEntry>,
    /// Every pair over all chunks.
    pub pairs: Vec<ComparedPair>,
    /// The chunks' wall-clock seconds, summed.
    pub wall_s: f64,
}

/// Pools `records` (each with the name it is reported under, usually its path): see the module's
/// documentation for what is checked.
pub fn pool(
    records: &[(String, ComparisonRecord)],
    command: String,
) -> Result<PooledComparison, ComparisonError> {
    let [(first_name, first), _, ..] = records else {
        return Err(ComparisonError::TooFew(records.len()));
    };
    for (name, r) in records {
        r.check(name)?;
        let mismatch = |what: String| ComparisonError::Mismatch {
            record: name.clone(),
            first: first_name.clone(),
            what,
        };
        if r.task != first.task {
            return Err(mismatch(format!("task {} against {}", r.task, first.task)));
        }
        if r.can_quantisation != first.can_quantisation {
            return Err(mismatch(
                "one used the CAN quantisation, the other not".into(),
            ));
        }
        let names = |r: &ComparisonRecord| -> Vec<String> {
            r.entries.iter().map(|e| e.name.clone()).collect()
        };
        if names(r) != names(first) {
            return Err(mismatch(format!(
                "entries {:?} against {:?}",
                names(r),
                names(first)
            )));
        }
        let pairs = |r: &ComparisonRecord| -> Vec<(String, String)> {
            r.pairs.iter().map(|p| (p.a.clone(), p.b.clone())).collect()
        };
        if pairs(r) != pairs(first) {
            return Err(mismatch("the pairs differ".into()));
        }
    }
    // One file per entry: the hashes the records carry (records of older builds carry none).
    for i in 0..first.entries.len() {
        let mut known: Option<(&str, &str)> = None;
        for (name, r) in records {
            let Some(sha) = r.entries[i].sha256.as_deref() else {
                continue;
            };
            match known {
                None => known = Some((name, sha)),
                Some((other, k)) if k != sha => {
                    return Err(ComparisonError::Mismatch {
                        record: name.clone(),
                        first: other.to_string(),
                        what: format!(
                            "{} is another file (sha256 {sha} against {k})",
                            r.entries[i].name
                        ),
                    });
                }
                Some(_) => {}
            }
        }
    }
    let mut episodes: u32 = 0;
    for (name, r) in records {
        episodes = episodes
            .checked_add(r.episodes)
            .filter(|&n| n <= MAX_POOLED_STARTS)
            .ok_or_else(|| ComparisonError::Inconsistent {
                record: name.clone(),
                what: format!("the pooled starts exceed {MAX_POOLED_STARTS}"),
            })?;
    }
    // No start in two chunks: the starts are hashed from (seed, index), so distinct seeds do not
    // guarantee it by construction; it is checked start by start (within one record the starts
    // are distinct: the hash is a bijection of the index).
    let mut owner: HashMap<u64, usize> = HashMap::with_capacity(episodes as usize);
    for (k, (_, r)) in records.iter().enumerate() {
        for i in 0..r.episodes {
            if let Some(j) = owner.insert(episode_seed(r.start_seed, u64::from(i)), k) {
                return Err(ComparisonError::SharedStarts {
                    a: records[j].0.clone(),
                    b: records[k].0.clone(),
                    seed_a: records[j].1.start_seed,
                    seed_b: r.start_seed,
                });
            }
        }
    }
    let entries = first
        .entries
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let successes = records.iter().map(|(_, r)| r.entries[i].successes).sum();
            ComparedEntry::new(e.name.clone(), e.sha256.clone(), successes, episodes)
        })
        .collect();
    let pairs = first
        .pairs
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let sum = |f: fn(&Paired) -> u32| -> u32 {
                records.iter().map(|(_, r)| f(&r.pairs[i].paired)).sum()
            };
            let (only_a, only_b) = (sum(|q| q.only_a), sum(|q| q.only_b));
            ComparedPair {
                a: p.a.clone(),
                b: p.b.clone(),
                paired: Paired {
                    episodes,
                    a_successes: sum(|q| q.a_successes),
                    b_successes: sum(|q| q.b_successes),
                    only_a,
                    only_b,
                    p_value: mcnemar_exact(only_a, only_b),
                },
            }
        })
        .collect();
    Ok(PooledComparison {
        command,
        task: first.task.clone(),
        can_quantisation: first.can_quantisation,
        chunks: records
            .iter()
            .map(|(name, r)| PooledChunk {
                record: name.clone(),
                start_seed: r.start_seed,
                episodes: r.episodes,
                wall_s: r.wall_s,
            })
            .collect(),
        episodes,
        entries,
        pairs,
        wall_s: records.iter().map(|(_, r)| r.wall_s).sum(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Outcomes of three entries on `n` starts, drawn from a fixed generator.
    fn outcomes(n: usize, salt: u64) -> Vec<EntryOutcomes> {
        let rates = [0.97, 0.95, 0.9];
        rates
            .iter()
            .enumerate()
            .map(|(k, &rate)| {
                let o = (0..n)
                    .map(|i| {
                        let u = episode_seed(salt + k as u64, i as u64) as f64 / u64::MAX as f64;
                        (u, u < rate)
                    })
                    .collect();
                (format!("p{k}.dxpl"), Some(format!("{k:064x}")), o)
            })
            .collect()
    }

    fn record(seed: u64, o: &[EntryOutcomes]) -> ComparisonRecord {
        ComparisonRecord::of("c".into(), "Stack".into(), seed, true, o, 1.5)
    }

    #[test]
    fn the_failed_seeds_are_the_files_own_failures_as_start_seeds() {
        let o = outcomes(200, 11);
        let r = record(9_000_000, &o);
        let file = format!("{:064x}", 1);
        let seeds = r.failed_seeds_of(&file, "r.json").unwrap();
        let expected: Vec<u64> = (0..200u64)
            .filter(|&i| !o[1].2[i as usize].1)
            .map(|i| episode_seed(9_000_000, i))
            .collect();
        assert!(!expected.is_empty());
        assert_eq!(seeds, expected);
        let other = r.failed_seeds_of(&"f".repeat(64), "r.json").unwrap_err();
        assert!(
            other.to_string().contains("no entry is the file"),
            "{other}"
        );
        let mut pooled = r.clone();
        pooled.entries[1].failed_starts = None;
        let none = pooled.failed_seeds_of(&file, "r.json").unwrap_err();
        assert!(
            none.to_string().contains("lists no failed starts"),
            "{none}"
        );
    }

    fn named(records: Vec<ComparisonRecord>) -> Vec<(String, ComparisonRecord)> {
        records
            .into_iter()
            .enumerate()
            .map(|(i, r)| (format!("r{i}.json"), r))
            .collect()
    }

    #[test]
    fn pooled_chunks_are_the_comparison_of_all_their_starts() {
        let whole = outcomes(3000, 11);
        // Three chunks of the same entries: starts 0..1000, 1000..2500, 2500..3000.
        let cut = |lo: usize, hi: usize| -> Vec<_> {
            whole
                .iter()
                .map(|(n, h, o)| (n.clone(), h.clone(), o[lo..hi].to_vec()))
                .collect()
        };
        let chunks = vec![
            record(100, &cut(0, 1000)),
            record(200, &cut(1000, 2500)),
            record(300, &cut(2500, 3000)),
        ];
        let pooled = pool(&named(chunks), "pool".into()).unwrap();
        let mut direct = record(0, &whole);
        assert_eq!(pooled.episodes, 3000);
        // A pooled entry lists no failed starts: its indices would be of several seeds.
        assert!(pooled.entries.iter().all(|e| e.failed_starts.is_none()));
        for e in &mut direct.entries {
            e.failed_starts = None;
        }
        assert_eq!(pooled.entries, direct.entries);
        assert_eq!(pooled.pairs, direct.pairs);
        assert_eq!(pooled.pairs.len(), 3);
        assert!(pooled.pairs[2].paired.only_a > 0 && pooled.pairs[2].paired.p_value < 0.01);
        assert_eq!(
            pooled
                .chunks
                .iter()
                .map(|c| c.start_seed)
                .collect::<Vec<_>>(),
            [100, 200, 300]
        );
        assert!((pooled.wall_s - 4.5).abs() < 1e-12);
    }

    #[test]
    fn records_that_cannot_be_pooled_are_refused() {
        let o = outcomes(200, 5);
        let ok = || vec![record(1, &o), record(2, &o)];
        assert!(pool(&named(ok()), String::new()).is_ok());
        assert!(matches!(
            pool(&named(vec![record(1, &o)]), String::new()),
            Err(ComparisonError::TooFew(1))
        ));
        let mut rs = ok();
        rs[1].task = "Grasp".into();
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Mismatch { .. })
        ));
        let mut rs = ok();
        rs[1].can_quantisation = false;
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Mismatch { .. })
        ));
        let mut rs = ok();
        rs[1].entries.swap(0, 1);
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Mismatch { .. })
        ));
        // Another file under the same name; a record without hashes pools with either.
        let mut rs = ok();
        rs[1].entries[0].sha256 = Some("f".repeat(64));
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Mismatch { .. })
        ));
        let mut rs = ok();
        rs[0].entries[0].sha256 = None;
        assert!(pool(&named(rs), String::new()).is_ok());
        // The same starts twice.
        let rs = vec![record(1, &o), record(2, &o), record(1, &o)];
        let err = pool(&named(rs), String::new()).unwrap_err();
        assert!(
            matches!(err, ComparisonError::SharedStarts { ref a, ref b, .. } if a == "r0.json" && b == "r2.json"),
            "{err}"
        );
        // Counts that contradict themselves.
        let mut rs = ok();
        rs[1].pairs[0].paired.only_a += 1;
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Inconsistent { .. })
        ));
        // A failed start missing from an entry's list, or listed twice.
        let mut rs = ok();
        rs[1].entries[0].failed_starts.as_mut().unwrap().pop();
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Inconsistent { .. })
        ));
        let mut rs = ok();
        let f = rs[1].entries[0].failed_starts.as_mut().unwrap();
        f[1] = f[0];
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Inconsistent { .. })
        ));
        let mut rs = ok();
        rs[0].entries[2].successes = 201;
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Inconsistent { .. })
        ));
        let mut rs = ok();
        for r in &mut rs {
            r.episodes = MAX_POOLED_STARTS;
            for e in &mut r.entries {
                e.episodes = MAX_POOLED_STARTS;
            }
            for p in &mut r.pairs {
                p.paired.episodes = MAX_POOLED_STARTS;
            }
        }
        assert!(matches!(
            pool(&named(rs), String::new()),
            Err(ComparisonError::Inconsistent { .. })
        ));
    }

    #[test]
    fn records_of_earlier_builds_read_without_hashes() {
        let json = r#"{"command": "trainer compare a b", "task": "Stack", "start_seed": 6055000,
            "episodes": 20000, "can_quantisation": true,
            "entries": [{"name": "a", "successes": 19777, "episodes": 20000,
                         "interval_95": [98.7, 99.0]},
                        {"name": "b", "successes": 19750, "episodes": 20000,
                         "interval_95": [98.6, 98.9]}],
            "pairs": [{"a": "a", "b": "b", "paired": {"episodes": 20000, "a_successes": 19777,
                       "b_successes": 19750, "only_a": 75, "only_b": 48,
                       "p_value": 0.0187}}],
            "wall_s": 3045.0}"#;
        let r: ComparisonRecord = serde_json::from_str(json).unwrap();
        assert_eq!(r.entries[0].sha256, None);
        r.check("r").unwrap();
        // Written back, an absent hash stays absent.
        assert!(!serde_json::to_string(&r).unwrap().contains("sha256"));
    }
}
