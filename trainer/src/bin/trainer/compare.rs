//! `trainer compare`: policy files (and the task's Markov demonstrator, the clones' teacher) on the
//! same starts, with the exact McNemar test of every pair (`dex_env::paired`): what a fine-tune
//! added over its clone, measured start by start.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, bail};
use clap::Args;

use dex_trainer::cell::proposal_pair::ProposalPair;
use dex_trainer::env::evaluate::{
    demonstration_outcomes, ensemble_outcomes, episode_outcomes, teacher_outcomes,
};
use dex_trainer::files::comparison_record::{ComparedEntry, ComparedPair, ComparisonRecord};
use dex_trainer::files::result_record::sha256_hex;
use dex_trainer::pipeline::train_settings::TaskArg;

use crate::eval_flags::EvalFlags;
use crate::train::{bar, load_scene};

/// `trainer compare` flags.
#[derive(Args, Debug)]
pub struct CompareArgs {
    /// Policy files, all of one task.
    #[arg(required_unless_present_any = ["ensemble", "pair"])]
    policies: Vec<PathBuf>,
    /// Also an ensemble: the mean of these policy files' commands (comma-separated; the flag may
    /// repeat, one entry each). The controller runs one network, so an ensemble is measured to be
    /// distilled into one (`trainer imitate --teacher-policies`), not flashed.
    #[arg(long)]
    ensemble: Vec<String>,
    /// Also an IBRL run's pair (`trainer train --ibrl`): its seed folder (`checkpoint.bin`,
    /// `settings.toml`); at each state the better-rated of the run's actor and its proposal
    /// (the flag may repeat). It reads the simulation's state, as the teacher does, and is
    /// measured to be distilled into one network (`trainer imitate --teacher-pair`), not flashed.
    #[arg(long, value_name = "SEED_DIR")]
    pair: Vec<PathBuf>,
    /// Also the task's Markov demonstrator (the teacher the clones learn from), on the same
    /// starts (it reads the simulation's state: no CAN quantisation or envelope applies to it).
    #[arg(long)]
    teacher: bool,
    /// Episodes (random starts), the same for every entry.
    #[arg(long, default_value_t = 1000)]
    episodes: u32,
    /// The starts, threads and bus.
    #[command(flatten)]
    at: EvalFlags,
    /// Also write the comparison as JSON (every entry's successes, interval and failed starts
    /// (indices from `--seed`), every pair's discordant counts and p-value, the command, the wall
    /// time).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Runs `trainer compare`.
pub fn compare(args: &CompareArgs) -> anyhow::Result<()> {
    let mut files = Vec::with_capacity(args.policies.len());
    let mut task = None;
    let ensembles: Vec<Vec<PathBuf>> = args
        .ensemble
        .iter()
        .map(|list| {
            list.split(',')
                .filter(|p| !p.is_empty())
                .map(PathBuf::from)
                .collect()
        })
        .collect();
    if ensembles.iter().any(Vec::is_empty) {
        bail!("--ensemble names no policy file");
    }
    let members: Vec<&PathBuf> = ensembles.iter().flatten().collect();
    let mut member_bytes = std::collections::HashMap::new();
    for path in args.policies.iter().chain(members.iter().copied()) {
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let aligned = dex_runtime::aligned::aligned_copy(&bytes);
        let view = dex_policy::PolicyView::decode(aligned.as_bytes())
            .with_context(|| format!("{} is not a valid policy file", path.display()))?;
        let own = TaskArg::from_policy(view.body().task);
        match task {
            None => task = Some(own),
            Some(t) if t != own => bail!(
                "{} is a {own:?} policy, the first file a {t:?} one: compare policies of one task",
                path.display()
            ),
            Some(_) => {}
        }
        member_bytes.insert(path.clone(), bytes);
    }
    for path in &args.policies {
        files.push((path.display().to_string(), member_bytes[path].clone()));
    }
    let mut pairs = Vec::with_capacity(args.pair.len());
    for dir in &args.pair {
        let (pair, own) = ProposalPair::from_run(dir)?;
        match task {
            None => task = Some(own),
            Some(t) if t != own => bail!(
                "{} is a {own:?} run, the first entry a {t:?} one: compare entries of one task",
                dir.display()
            ),
            Some(_) => {}
        }
        pairs.push((dir, pair));
    }
    let Some(task) = task else {
        bail!("no policy file given");
    };
    let scene = load_scene()?;
    let settings = args.at.settings(task, args.episodes, false);
    let started = Instant::now();
    let entries = files.len() + ensembles.len() + pairs.len() + usize::from(args.teacher);
    let pb = bar(
        u64::from(args.episodes) * entries as u64,
        false,
        "compare [{elapsed_precise}] [{bar:30}] {pos}/{len} episodes",
    );
    let mut outcomes = Vec::with_capacity(entries);
    if args.teacher {
        let o = teacher_outcomes(&scene, &settings, &|| pb.inc(1))?;
        outcomes.push(("teacher (Markov demonstrator)".to_string(), None, o));
    }
    for (name, bytes) in &files {
        let o = episode_outcomes(bytes, &scene, &settings, &|| pb.inc(1))
            .with_context(|| format!("evaluating {name}"))?;
        outcomes.push((name.clone(), Some(sha256_hex(bytes)), o));
    }
    for list in &ensembles {
        let bytes: Vec<&[u8]> = list.iter().map(|p| member_bytes[p].as_slice()).collect();
        let name = format!(
            "ensemble of {} ({})",
            list.len(),
            list.iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
        let o = ensemble_outcomes(&bytes, &scene, &settings, &|| pb.inc(1))
            .with_context(|| format!("evaluating the {name}"))?;
        outcomes.push((name, None, o));
    }
    for (dir, pair) in &pairs {
        let name = format!("IBRL pair of {}", dir.display());
        let o = demonstration_outcomes(&scene, &settings, &|| Ok(pair.clone()), &|| pb.inc(1))
            .with_context(|| format!("evaluating the {name}"))?;
        outcomes.push((name, None, o));
    }
    pb.finish_and_clear();
    println!(
        "{task:?}, the same {} starts from seed {} for every entry:",
        args.episodes, args.at.seed
    );
    let wall_s = started.elapsed().as_secs_f64();
    let report = ComparisonRecord::of(
        std::env::args().collect::<Vec<_>>().join(" "),
        format!("{task:?}"),
        args.at.seed,
        !args.at.no_can_quantisation,
        &outcomes,
        wall_s,
    );
    print_comparison(&report.entries, &report.pairs);
    if let Some(path) = &args.json {
        crate::write_json(path, &report)?;
    }
    Ok(())
}

/// Prints every entry's successes with its interval, then every pair's discordant starts and
/// McNemar p-value (`trainer compare` and `trainer pool`).
pub(crate) fn print_comparison(entries: &[ComparedEntry], pairs: &[ComparedPair]) {
    for e in entries {
        println!(
            "  {}: {}/{} = {:.1}% (95% CI {:.1}-{:.1}%)",
            e.name,
            e.successes,
            e.episodes,
            100.0 * f64::from(e.successes) / f64::from(e.episodes.max(1)),
            e.interval_95.0,
            e.interval_95.1
        );
    }
    for p in pairs {
        println!(
            "  {} vs {}: only the first {}, only the second {}, McNemar p = {:.4}",
            p.a, p.b, p.paired.only_a, p.paired.only_b, p.paired.p_value
        );
    }
}
