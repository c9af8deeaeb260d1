//! `trainer power`: how many paired starts the next test needs. For every pair of a comparison
//! record (plain or pooled), the leader's and the other's discordant rates, the power the record's
//! own size had at those rates, and the starts an exact McNemar test needs to show the leader
//! better at the level named (`dex_env::paired_power`).

use std::path::PathBuf;

use clap::Args;

use dex_trainer::env::paired_power::{check_plan_settings, plan};
use dex_trainer::files::comparison_record::{ComparisonSummary, MAX_POOLED_STARTS};

/// `trainer power` flags.
#[derive(Args, Debug)]
pub struct PowerArgs {
    /// `trainer compare --json` or `trainer pool --json` records.
    #[arg(required = true)]
    records: Vec<PathBuf>,
    /// The significance level the test will be named with (two-sided, exact McNemar).
    #[arg(long, default_value_t = 0.01)]
    alpha: f64,
    /// The probability the test should have of showing the leader better, were the record's
    /// rates the true ones.
    #[arg(long, default_value_t = 0.8)]
    power: f64,
}

/// Runs `trainer power`.
pub fn power(args: &PowerArgs) -> anyhow::Result<()> {
    check_plan_settings(args.alpha, args.power)?;
    // Every record is read and checked before anything is printed.
    let records = args
        .records
        .iter()
        .map(|p| Ok((p.display().to_string(), ComparisonSummary::read(p)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    println!(
        "exact McNemar test at p < {}, power {} (rates as observed: optimistic for a candidate \
         chosen for its margin)",
        args.alpha, args.power
    );
    for (name, r) in &records {
        // Seconds per start and entry at the record's own pace (its machine and threads).
        let pace = r.wall_s / (f64::from(r.episodes) * r.entries.len().max(1) as f64);
        println!("{name}: {}, {} starts", r.task, r.episodes);
        for p in &r.pairs {
            let plan = plan(
                &p.paired,
                args.alpha,
                args.power,
                u64::from(MAX_POOLED_STARTS),
            )?;
            let (lead, other) = if plan.a_leads {
                (&p.a, &p.b)
            } else {
                (&p.b, &p.a)
            };
            println!(
                "  {} vs {}: only the first {}, only the second {}, p = {:.4}",
                p.a, p.b, p.paired.only_a, p.paired.only_b, p.paired.p_value
            );
            println!(
                "    {lead} leads: {:.3}% of the starts only it solves, {:.3}% only {other}; a \
                 test of {} starts has power {:.2} at these rates",
                100.0 * plan.rates.gain(),
                100.0 * plan.rates.loss(),
                r.episodes,
                plan.power_at_size
            );
            match plan.starts_needed {
                Some(n) => println!(
                    "    starts needed: {n} (about {:.1} h of wall for two entries at this \
                     record's pace)",
                    n as f64 * 2.0 * pace / 3600.0
                ),
                None if plan.rates.gain() <= plan.rates.loss() => {
                    println!("    starts needed: none can show it (no margin)")
                }
                None => println!("    starts needed: more than {MAX_POOLED_STARTS}"),
            }
        }
    }
    Ok(())
}
