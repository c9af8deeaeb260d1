//! Which worker ranks the parameter server counts as present: a rank silent for the rank timeout
//! is lost (the run goes on with the others), a lost rank that is heard from again is
//! re-admitted, and a rank lost for long enough may be replaced by a newly started one (which
//! then counts as a rank of its own, the next number after every rank so far). Each change is recorded with the wall-clock time and the run's transition count,
//! for the log and the run folder's `distributed.json` (docs/distributed.md, "Faults").

use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// What happened to a worker rank.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RankChangeKind {
    /// The rank sent nothing, or did not take a send, for longer than the rank timeout.
    Lost,
    /// A lost rank was heard from again and gets the server's state.
    Readmitted,
    /// A new worker rank ([`RankChange::by`]) was started in place of the lost rank.
    Replaced,
    /// Starting a replacement for the lost rank failed; the run goes on without one.
    ReplacementFailed,
}

/// One change of a worker rank's membership.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RankChange {
    /// The worker rank.
    pub rank: usize,
    /// Lost or re-admitted.
    pub kind: RankChangeKind,
    /// Seconds since the Unix epoch when the server noticed it.
    pub unix_s: f64,
    /// Seconds the rank had been silent (when lost) or away (when re-admitted).
    pub silent_s: f64,
    /// The run's transitions (applied pushes) at that moment.
    pub transitions: u64,
    /// The replacement's rank ([`RankChangeKind::Replaced`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub by: Option<usize>,
    /// Why no replacement could be started ([`RankChangeKind::ReplacementFailed`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
}

impl std::fmt::Display for RankChange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.kind {
            RankChangeKind::Lost => write!(
                f,
                "worker rank {} lost (silent {:.1} s) at unix {:.3}, {} transitions: going on \
                 without it",
                self.rank, self.silent_s, self.unix_s, self.transitions
            ),
            RankChangeKind::Readmitted => write!(
                f,
                "worker rank {} re-admitted (away {:.1} s) at unix {:.3}, {} transitions",
                self.rank, self.silent_s, self.unix_s, self.transitions
            ),
            RankChangeKind::Replaced => write!(
                f,
                "worker rank {} replaced by a new worker rank {} (lost {:.1} s) at unix {:.3}, {} \
                 transitions",
                self.rank,
                self.by.map_or_else(|| "?".to_string(), |b| b.to_string()),
                self.silent_s,
                self.unix_s,
                self.transitions
            ),
            RankChangeKind::ReplacementFailed => write!(
                f,
                "worker rank {}: no replacement could be started (lost {:.1} s) at unix {:.3}, {} \
                 transitions: going on without it ({})",
                self.rank,
                self.silent_s,
                self.unix_s,
                self.transitions,
                self.why.as_deref().unwrap_or("no reason given")
            ),
        }
    }
}

/// The server's view of which worker ranks are present, and the changes so far.
#[derive(Debug, Clone, Default)]
pub struct Membership {
    /// Per rank (index 0, the server, never lost): the serve-clock time it was lost at.
    lost_at: Vec<Option<Duration>>,
    /// Per rank: a replacement was tried for it (once per rank, whatever the outcome).
    replaced: Vec<bool>,
    changes: Vec<RankChange>,
}

fn unix_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

impl Membership {
    /// `ranks` ranks, all present.
    pub fn new(ranks: usize) -> Self {
        Membership {
            lost_at: vec![None; ranks],
            replaced: vec![false; ranks],
            changes: Vec::new(),
        }
    }

    /// Counts one more rank (a replacement, numbered after every rank so far), present; returns
    /// its number.
    pub fn add_rank(&mut self) -> usize {
        self.lost_at.push(None);
        self.replaced.push(false);
        self.lost_at.len() - 1
    }

    /// Number of ranks counted (the server and every worker rank so far, lost or not).
    pub fn ranks(&self) -> usize {
        self.lost_at.len()
    }

    /// How long `rank` has been lost at serve-clock `now` (None when it is present).
    pub fn lost_for(&self, rank: usize, now: Duration) -> Option<Duration> {
        let at = (*self.lost_at.get(rank)?)?;
        Some(now.saturating_sub(at))
    }

    /// Whether a replacement was tried for `rank`.
    pub fn was_replaced(&self, rank: usize) -> bool {
        self.replaced.get(rank).copied().unwrap_or(false)
    }

    /// Records the replacement of the lost `rank` by rank `by` (`Err`: why it could not be
    /// started) at serve-clock `now`; returns the change. The rank stays lost (it may still come
    /// back: then it is re-admitted beside its replacement) and is never replaced again.
    pub fn replace(
        &mut self,
        rank: usize,
        by: Result<usize, String>,
        now: Duration,
        transitions: u64,
    ) -> RankChange {
        if let Some(r) = self.replaced.get_mut(rank) {
            *r = true;
        }
        let lost = self.lost_for(rank, now).unwrap_or_default();
        match by {
            Ok(b) => self.record(
                rank,
                RankChangeKind::Replaced,
                lost,
                transitions,
                (Some(b), None),
            ),
            Err(why) => self.record(
                rank,
                RankChangeKind::ReplacementFailed,
                lost,
                transitions,
                (None, Some(why)),
            ),
        }
    }

    /// Whether `rank` is counted as lost.
    pub fn is_lost(&self, rank: usize) -> bool {
        self.lost_at.get(rank).is_some_and(Option::is_some)
    }

    /// The worker ranks (1..) still present.
    pub fn present(&self) -> usize {
        self.lost_at.iter().skip(1).filter(|l| l.is_none()).count()
    }

    /// The worker ranks lost now, in rank order.
    pub fn lost_now(&self) -> Vec<usize> {
        (1..self.lost_at.len())
            .filter(|&r| self.is_lost(r))
            .collect()
    }

    /// Every change so far, oldest first.
    pub fn changes(&self) -> &[RankChange] {
        &self.changes
    }

    /// Marks `rank` lost at serve-clock `now` after `silent` of silence; returns the change.
    pub fn lose(
        &mut self,
        rank: usize,
        now: Duration,
        silent: Duration,
        transitions: u64,
    ) -> RankChange {
        if let Some(l) = self.lost_at.get_mut(rank) {
            *l = Some(now);
        }
        self.record(
            rank,
            RankChangeKind::Lost,
            silent,
            transitions,
            (None, None),
        )
    }

    /// Marks the lost `rank` present again at serve-clock `now`; returns the change (None when it
    /// was not lost).
    pub fn readmit(&mut self, rank: usize, now: Duration, transitions: u64) -> Option<RankChange> {
        let since = self.lost_at.get_mut(rank)?.take()?;
        Some(self.record(
            rank,
            RankChangeKind::Readmitted,
            now.saturating_sub(since),
            transitions,
            (None, None),
        ))
    }

    fn record(
        &mut self,
        rank: usize,
        kind: RankChangeKind,
        silent: Duration,
        transitions: u64,
        (by, why): (Option<usize>, Option<String>),
    ) -> RankChange {
        let c = RankChange {
            rank,
            kind,
            unix_s: unix_now(),
            silent_s: silent.as_secs_f64(),
            transitions,
            by,
            why,
        };
        self.changes.push(c.clone());
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lost_rank_is_readmitted_once() {
        let mut m = Membership::new(3);
        assert_eq!(m.present(), 2);
        let c = m.lose(2, Duration::from_secs(10), Duration::from_secs(5), 100);
        assert_eq!((c.rank, c.kind), (2, RankChangeKind::Lost));
        assert!(m.is_lost(2) && !m.is_lost(1));
        assert_eq!((m.present(), m.lost_now()), (1, vec![2]));
        // A rank that is present is not re-admitted.
        assert!(m.readmit(1, Duration::from_secs(11), 100).is_none());
        let c = m
            .readmit(2, Duration::from_secs(14), 120)
            .expect("re-admitted");
        assert_eq!(c.kind, RankChangeKind::Readmitted);
        assert!((c.silent_s - 4.0).abs() < 1e-9, "{c:?}");
        assert!(m.readmit(2, Duration::from_secs(15), 120).is_none());
        assert_eq!(m.present(), 2);
        assert_eq!(m.changes().len(), 2);
        assert!(m.changes()[0].to_string().contains("worker rank 2 lost"));
    }

    #[test]
    fn a_replaced_rank_stays_lost_and_its_replacement_counts() {
        let mut m = Membership::new(3);
        m.lose(2, Duration::from_secs(10), Duration::from_secs(3), 100);
        assert_eq!(
            m.lost_for(2, Duration::from_secs(12)),
            Some(Duration::from_secs(2))
        );
        assert_eq!(m.lost_for(1, Duration::from_secs(12)), None);
        assert!(!m.was_replaced(2));
        let by = m.add_rank();
        assert_eq!((by, m.ranks()), (3, 4));
        let c = m.replace(2, Ok(by), Duration::from_secs(13), 150);
        assert_eq!(
            (c.rank, c.kind, c.by),
            (2, RankChangeKind::Replaced, Some(3))
        );
        assert!((c.silent_s - 3.0).abs() < 1e-9, "{c:?}");
        assert_eq!(m.changes().last(), Some(&c));
        assert!(m.was_replaced(2) && m.is_lost(2) && !m.is_lost(3));
        assert_eq!((m.present(), m.lost_now()), (2, vec![2]));
        let line = c.to_string();
        assert!(
            line.contains("worker rank 2 replaced by a new worker rank 3"),
            "{line}"
        );
        let f = m.replace(1, Err("no slot".into()), Duration::from_secs(14), 150);
        assert_eq!((f.kind, f.by), (RankChangeKind::ReplacementFailed, None));
        assert_eq!(m.changes().last(), Some(&f));
        let line = f.to_string();
        assert!(line.contains("no replacement could be started") && line.contains("(no slot)"));
    }
}
