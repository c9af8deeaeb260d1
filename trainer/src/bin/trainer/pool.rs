//! `trainer pool`: `trainer compare` records of disjoint starts pooled into one comparison, so
//! that a long paired test can run as chunks a stopped session loses at most one of
//! (`dex_trainer::files::comparison_record`).

use std::path::PathBuf;

use clap::Args;

use dex_trainer::files::comparison_record::{ComparisonRecord, pool as pool_records};

use crate::compare::print_comparison;

/// `trainer pool` flags.
#[derive(Args, Debug)]
pub struct PoolArgs {
    /// `trainer compare --json` records of the same entries on disjoint starts (two or more).
    #[arg(required = true, num_args = 2..)]
    records: Vec<PathBuf>,
    /// Also write the pooled comparison as JSON (the chunks, every entry's successes and
    /// interval, every pair's discordant starts and p-value over all the chunks' starts).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Runs `trainer pool`.
pub fn pool(args: &PoolArgs) -> anyhow::Result<()> {
    let records = args
        .records
        .iter()
        .map(|p| Ok((p.display().to_string(), ComparisonRecord::read(p)?)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let pooled = pool_records(&records, std::env::args().collect::<Vec<_>>().join(" "))?;
    println!(
        "{}, {} starts in {} chunks (start seeds {}):",
        pooled.task,
        pooled.episodes,
        pooled.chunks.len(),
        pooled
            .chunks
            .iter()
            .map(|c| format!("{} x {}", c.start_seed, c.episodes))
            .collect::<Vec<_>>()
            .join(", ")
    );
    print_comparison(&pooled.entries, &pooled.pairs);
    if let Some(path) = &args.json {
        crate::write_json(path, &pooled)?;
    }
    Ok(())
}
