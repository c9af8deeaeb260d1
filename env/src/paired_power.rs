//! How large a paired test must be: the power of the exact McNemar test of [`crate::paired`] to
//! show a candidate better than its base.
//!
//! The model is the test's own: each start is, independently, one only the candidate solves
//! (probability `gain`), one only the base solves (`loss`), or one both solve or both fail. Over
//! `n` starts the discordant count is `D ~ Binomial(n, gain + loss)`, and of those the
//! candidate's are `X ~ Binomial(D, gain / (gain + loss))`. The test rejects at level `alpha` in the
//! candidate's favour when `X` reaches the critical count `c(D)`, the smallest `x > D / 2` whose
//! exact two-sided p-value `2 P(Bin(D, 1/2) <= D - x)` is below `alpha`. The power is
//! `sum_D P(D) P(X >= c(D) | D)`, summed exactly over the discordant counts that carry the mass.
//!
//! Rates read off a comparison are estimates, and those of a candidate chosen for its margin are
//! optimistic (the selection's winner's curse): a plan from them is the size a test needs *if*
//! the margin is real, a lower bound for the test to name.

use statrs::distribution::{Binomial, Discrete, DiscreteCDF};

use crate::paired::{Paired, mcnemar_exact};

/// Why a power or a plan cannot be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PowerError {
    /// The discordant rates are not probabilities of disjoint outcomes.
    #[error(
        "the discordant rates must be in [0, 1] and sum to at most 1, got {gain} (only the \
         candidate) and {loss} (only the base)"
    )]
    Rates {
        /// The rate of starts only the candidate solves.
        gain: f64,
        /// The rate of starts only the base solves.
        loss: f64,
    },
    /// The significance level is not in (0, 1).
    #[error("the significance level must be in (0, 1), got {0}")]
    Alpha(f64),
    /// The wanted power is not in (0, 1).
    #[error("the power must be in (0, 1), got {0}")]
    Power(f64),
    /// The comparison has no starts to read rates from.
    #[error("the comparison has no starts")]
    NoStarts,
}

/// The per-start probabilities of the two discordant outcomes, checked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscordantRates {
    gain: f64,
    loss: f64,
}

impl DiscordantRates {
    /// `gain`: a start only the candidate solves; `loss`: one only the base solves.
    pub fn new(gain: f64, loss: f64) -> Result<Self, PowerError> {
        let ok = |r: f64| (0.0..=1.0).contains(&r);
        if !ok(gain) || !ok(loss) || gain + loss > 1.0 {
            return Err(PowerError::Rates { gain, loss });
        }
        Ok(Self { gain, loss })
    }

    /// Only the candidate's share of the starts.
    pub fn gain(&self) -> f64 {
        self.gain
    }

    /// Only the base's share of the starts.
    pub fn loss(&self) -> f64 {
        self.loss
    }
}

fn check_level(alpha: f64) -> Result<(), PowerError> {
    if alpha > 0.0 && alpha < 1.0 {
        Ok(())
    } else {
        Err(PowerError::Alpha(alpha))
    }
}

/// Checks a plan's level and wanted power before any record is read.
pub fn check_plan_settings(alpha: f64, wanted: f64) -> Result<(), PowerError> {
    check_level(alpha)?;
    if wanted > 0.0 && wanted < 1.0 {
        Ok(())
    } else {
        Err(PowerError::Power(wanted))
    }
}

/// Whether `x` of `d` discordant starts for the candidate reject at `alpha`: `x > d / 2` and the
/// test's p-value ([`mcnemar_exact`]) is below `alpha`.
fn rejects(d: u64, x: u64, alpha: f64) -> bool {
    let (x, rest) = (x as u32, (d - x) as u32);
    x > rest && mcnemar_exact(x, rest) < alpha
}

/// The probability that an exact McNemar test of `starts` paired starts rejects at level `alpha`
/// in the candidate's favour (it has more of the discordant starts and p < `alpha`), when each
/// start is discordant at `rates`.
pub fn power(starts: u64, rates: DiscordantRates, alpha: f64) -> Result<f64, PowerError> {
    check_level(alpha)?;
    let q = rates.gain + rates.loss;
    if starts == 0 || rates.gain == 0.0 {
        return Ok(0.0);
    }
    let share = rates.gain / q;
    let discordant = Binomial::new(q.min(1.0), starts).map_err(|_| PowerError::Rates {
        gain: rates.gain,
        loss: rates.loss,
    })?;
    // The discordant counts that carry the mass: 12 standard deviations either side of the mean
    // leave out less than 1e-30 of it.
    let n = starts as f64;
    let (mean, sd) = (n * q, (n * q * (1.0 - q)).sqrt());
    let lo = (mean - 12.0 * sd - 12.0).floor().max(0.0) as u64;
    let hi = ((mean + 12.0 * sd + 12.0).ceil() as u64).min(starts);
    let mut total = 0.0;
    // c(d) never falls as d grows and rises by at most one a step, so the search for the next
    // count's critical value starts from the last one.
    let mut critical = 0u64;
    for d in lo..=hi {
        let p_d = discordant.pmf(d);
        if p_d == 0.0 || d == 0 {
            continue;
        }
        critical = critical.max(d / 2 + 1);
        while critical <= d && !rejects(d, critical, alpha) {
            critical += 1;
        }
        if critical > d {
            // Too few discordant starts for any split to reach the level.
            critical = 0;
            continue;
        }
        let mine = Binomial::new(share, d).map_err(|_| PowerError::Rates {
            gain: rates.gain,
            loss: rates.loss,
        })?;
        total += p_d * mine.sf(critical - 1);
    }
    Ok(total.clamp(0.0, 1.0))
}

/// The fewest paired starts (at most `max_starts`) at which the test of [`power`] reaches
/// `wanted`, or `None` when the candidate is not ahead (`gain <= loss`) or more than `max_starts`
/// are needed. The exact test's power saws by a fraction of a point as the size grows (its
/// critical count moves in whole starts), so this is the crossing a bisection finds, not
/// necessarily the first size above `wanted`.
pub fn starts_needed(
    rates: DiscordantRates,
    alpha: f64,
    wanted: f64,
    max_starts: u64,
) -> Result<Option<u64>, PowerError> {
    check_plan_settings(alpha, wanted)?;
    if rates.gain <= rates.loss {
        return Ok(None);
    }
    let mut hi = 16u64;
    while power(hi, rates, alpha)? < wanted {
        if hi >= max_starts {
            return Ok(None);
        }
        hi = (hi * 2).min(max_starts);
    }
    let mut lo = hi / 2;
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if power(mid, rates, alpha)? >= wanted {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Ok(Some(hi))
}

/// A paired comparison read as the plan of the test that would show its leader better.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TestPlan {
    /// Whether A leads (has at least as many starts only it solves as B).
    pub a_leads: bool,
    /// The leader's and the other's discordant rates, per start.
    pub rates: DiscordantRates,
    /// The power a test of the comparison's own size has at these rates.
    pub power_at_size: f64,
    /// The paired starts a test needs for the wanted power ([`starts_needed`]).
    pub starts_needed: Option<u64>,
}

/// The plan for `paired`'s leader at level `alpha` and power `wanted`, its rates the observed
/// ones (see the module's caveat on rates of a selected candidate).
pub fn plan(
    paired: &Paired,
    alpha: f64,
    wanted: f64,
    max_starts: u64,
) -> Result<TestPlan, PowerError> {
    if paired.episodes == 0 {
        return Err(PowerError::NoStarts);
    }
    let a_leads = paired.only_a >= paired.only_b;
    let (lead, other) = if a_leads {
        (paired.only_a, paired.only_b)
    } else {
        (paired.only_b, paired.only_a)
    };
    let n = f64::from(paired.episodes);
    let rates = DiscordantRates::new(f64::from(lead) / n, f64::from(other) / n)?;
    Ok(TestPlan {
        a_leads,
        rates,
        power_at_size: power(u64::from(paired.episodes), rates, alpha)?,
        starts_needed: starts_needed(rates, alpha, wanted, max_starts)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The power by brute force: every (only the candidate, only the base) split of `n` starts,
    /// weighted by its trinomial probability, through the test itself.
    fn enumerated(n: u32, gain: f64, loss: f64, alpha: f64) -> f64 {
        let ln_fact = |k: u32| (1..=k).map(|i| f64::from(i).ln()).sum::<f64>();
        let mut total = 0.0;
        for x in 0..=n {
            for y in 0..=(n - x) {
                if x > y && mcnemar_exact(x, y) < alpha {
                    let ln_p = ln_fact(n) - ln_fact(x) - ln_fact(y) - ln_fact(n - x - y)
                        + f64::from(x) * gain.ln()
                        + f64::from(y) * loss.ln()
                        + f64::from(n - x - y) * (1.0 - gain - loss).ln();
                    total += ln_p.exp();
                }
            }
        }
        total
    }

    #[test]
    fn the_power_is_the_tests_own_rejection_probability() {
        for (n, gain, loss, alpha) in [
            (40, 0.2, 0.05, 0.05),
            (60, 0.1, 0.08, 0.01),
            (25, 0.3, 0.01, 0.01),
        ] {
            let rates = DiscordantRates::new(gain, loss).unwrap();
            let exact = power(u64::from(n), rates, alpha).unwrap();
            let brute = enumerated(n, gain, loss, alpha);
            assert!(
                (exact - brute).abs() < 1e-9,
                "n {n}, gain {gain}, loss {loss}: {exact} against {brute}"
            );
        }
    }

    #[test]
    fn equal_rates_reject_for_the_candidate_at_most_half_the_level() {
        let rates = DiscordantRates::new(0.005, 0.005).unwrap();
        for n in [2_000, 20_000, 200_000] {
            let p = power(n, rates, 0.01).unwrap();
            assert!(p > 0.0 && p <= 0.005, "n {n}: {p}");
        }
        assert_eq!(starts_needed(rates, 0.01, 0.8, 10_000_000).unwrap(), None);
    }

    #[test]
    fn large_tests_agree_with_the_normal_approximation() {
        // Connor (1987): n = (z_{a/2} sqrt(psi) + z_b sqrt(psi - delta^2))^2 / delta^2 with psi =
        // gain + loss and delta = gain - loss; for 0.35% against 0.24% at 0.01 and power 0.8,
        // (2.5758 * 0.076811 + 0.8416 * 0.076803)^2 / 0.0011^2 = 56,943 starts.
        let rates = DiscordantRates::new(0.0035, 0.0024).unwrap();
        let n = starts_needed(rates, 0.01, 0.8, 10_000_000)
            .unwrap()
            .unwrap();
        assert!((54_000..60_000).contains(&n), "{n}");
        let at = power(n, rates, 0.01).unwrap();
        assert!((0.8..0.81).contains(&at), "{at}");
        // Twice the margin needs about a quarter of the starts; more starts, more power.
        let wider = DiscordantRates::new(0.0046, 0.0024).unwrap();
        let m = starts_needed(wider, 0.01, 0.8, 10_000_000)
            .unwrap()
            .unwrap();
        assert!(m < n / 3, "{m} against {n}");
        assert!(power(n / 2, rates, 0.01).unwrap() < power(2 * n, rates, 0.01).unwrap());
    }

    #[test]
    fn a_plan_reads_the_leader_and_its_rates_off_a_comparison() {
        let p = Paired {
            episodes: 10_000,
            a_successes: 9929,
            b_successes: 9938,
            only_a: 17,
            only_b: 26,
            p_value: mcnemar_exact(17, 26),
        };
        let plan = plan(&p, 0.01, 0.8, 10_000_000).unwrap();
        assert!(!plan.a_leads);
        assert_eq!((plan.rates.gain(), plan.rates.loss()), (0.0026, 0.0017));
        let rates = DiscordantRates::new(0.0026, 0.0017).unwrap();
        assert_eq!(plan.power_at_size, power(10_000, rates, 0.01).unwrap());
        let n = plan.starts_needed.unwrap();
        assert!(n > 10_000 && power(n, rates, 0.01).unwrap() >= 0.8);
        // A cap below what is needed gives none; a tie has no leader to plan for.
        assert_eq!(starts_needed(rates, 0.01, 0.8, 10_000).unwrap(), None);
        let tie = Paired {
            only_a: 5,
            only_b: 5,
            ..p
        };
        assert_eq!(
            super::plan(&tie, 0.01, 0.8, 10_000_000)
                .unwrap()
                .starts_needed,
            None
        );
    }

    #[test]
    fn bad_levels_rates_and_sizes_are_refused() {
        let rates = DiscordantRates::new(0.01, 0.0).unwrap();
        for alpha in [0.0, 1.0, -0.5, f64::NAN] {
            assert!(matches!(
                power(100, rates, alpha),
                Err(PowerError::Alpha(_))
            ));
        }
        for wanted in [0.0, 1.0, f64::NAN] {
            assert!(matches!(
                starts_needed(rates, 0.01, wanted, 1000),
                Err(PowerError::Power(_))
            ));
        }
        for (gain, loss) in [(-0.1, 0.1), (0.6, 0.5), (f64::NAN, 0.0), (0.1, 1.5)] {
            assert!(matches!(
                DiscordantRates::new(gain, loss),
                Err(PowerError::Rates { .. })
            ));
        }
        let none = Paired::of(&[], &[]);
        assert_eq!(plan(&none, 0.01, 0.8, 1000), Err(PowerError::NoStarts));
        // No candidate-only start: no power at any size.
        let nothing = DiscordantRates::new(0.0, 0.01).unwrap();
        assert_eq!(power(1_000_000, nothing, 0.01).unwrap(), 0.0);
    }
}
