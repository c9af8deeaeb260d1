//! Two policies on the same starts: the starts only one of them solves, and the exact McNemar test
//! of whether they differ (the two-sided binomial test on those discordant starts). The outcomes
//! come from [`crate::evaluate::episode_outcomes`], whose episode `i` starts from the same seed for
//! every policy file.

use statrs::distribution::{Binomial, DiscreteCDF};

/// The comparison of policy A with policy B on the same starts.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Paired {
    /// Starts compared.
    pub episodes: u32,
    /// Starts A solves.
    pub a_successes: u32,
    /// Starts B solves.
    pub b_successes: u32,
    /// Starts A solves and B does not.
    pub only_a: u32,
    /// Starts B solves and A does not.
    pub only_b: u32,
    /// Exact two-sided McNemar p-value: the probability, were A and B equally good, of a split of
    /// the discordant starts at least this uneven.
    pub p_value: f64,
}

impl Paired {
    /// Compares two lists of (return, success) outcomes, start by start; they must be of the same
    /// starts in the same order (a shorter list cuts the longer).
    pub fn of(a: &[(f64, bool)], b: &[(f64, bool)]) -> Self {
        let mut p = Paired {
            episodes: 0,
            a_successes: 0,
            b_successes: 0,
            only_a: 0,
            only_b: 0,
            p_value: 1.0,
        };
        for (&(_, sa), &(_, sb)) in a.iter().zip(b) {
            p.episodes += 1;
            p.a_successes += u32::from(sa);
            p.b_successes += u32::from(sb);
            p.only_a += u32::from(sa && !sb);
            p.only_b += u32::from(sb && !sa);
        }
        p.p_value = mcnemar_exact(p.only_a, p.only_b);
        p
    }
}

/// The exact two-sided McNemar p-value of `b` and `c` discordant pairs: `min(1, 2 P(X <= min(b,
/// c)))` for `X ~ Binomial(b + c, 1/2)`; 1 when there is none. The tail comes from statrs'
/// binomial CDF (the regularised incomplete beta function), so any count costs the same.
pub fn mcnemar_exact(b: u32, c: u32) -> f64 {
    let n = u64::from(b) + u64::from(c);
    match Binomial::new(0.5, n) {
        Ok(half) if n > 0 => (2.0 * half.cdf(u64::from(b.min(c)))).min(1.0),
        _ => 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values_of_the_exact_test() {
        // 13 against 2 (session 14's Grasp pair): 2 P(X <= 2), X ~ Bin(15, 1/2) = 2 * 121 / 32768.
        assert!((mcnemar_exact(13, 2) - 242.0 / 32768.0).abs() < 1e-12);
        assert!((mcnemar_exact(2, 13) - mcnemar_exact(13, 2)).abs() < 1e-15);
        assert_eq!(mcnemar_exact(0, 0), 1.0);
        assert_eq!(mcnemar_exact(5, 5), 1.0);
        // 0 against 10: 2 / 1024.
        assert!((mcnemar_exact(0, 10) - 2.0 / 1024.0).abs() < 1e-15);
        // Large counts neither underflow to 0 nor exceed 1.
        let p = mcnemar_exact(600, 400);
        assert!(p > 0.0 && p < 1e-9, "{p}");
        assert!((mcnemar_exact(2000, 2000) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn pairs_count_the_starts_only_one_solves() {
        let a = [(1.0, true), (0.0, false), (1.0, true), (0.0, false)];
        let b = [(1.0, true), (1.0, true), (0.0, false), (1.0, true)];
        let p = Paired::of(&a, &b);
        assert_eq!(
            (p.episodes, p.a_successes, p.b_successes, p.only_a, p.only_b),
            (4, 2, 3, 1, 2)
        );
        assert_eq!(p.p_value, 1.0);
    }
}
