//! `trainer critic-rank SEED_DIR`: does a run's critic order actions as the simulator does
//! (`dex_trainer::cell::critic_ranking`)? Prints each rater's agreement with the rollouts and
//! writes the whole measurement as JSON when asked.

use std::path::PathBuf;

use clap::Args;

use dex_trainer::cell::critic_ranking::{RankedRun, RankingSettings};
use dex_trainer::env::seeds::RANKING_SEED;

use crate::train::{bar, load_scene};

/// `trainer critic-rank` flags.
#[derive(Args, Debug)]
pub struct CriticRankArgs {
    /// A `trainer train` seed folder (`OUT/seed-S`: settings.toml, checkpoint.bin).
    run: PathBuf,
    /// States measured (one per start, at a uniformly drawn step of the actor's episode).
    #[arg(long, default_value_t = 200)]
    states: u32,
    /// Candidate actions per state: the actor's, and the actor's plus noise.
    #[arg(long, default_value_t = 5)]
    candidates: u32,
    /// Standard deviation of the candidates' noise, in action units.
    #[arg(long, default_value_t = 0.1)]
    noise: f32,
    /// Steps of each candidate's rollout (the candidate, then the actor).
    #[arg(long, default_value_t = 200)]
    horizon: u32,
    /// Start seed of the states.
    #[arg(long, default_value_t = RANKING_SEED)]
    seed: u64,
    /// Threads.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Rollouts per candidate: the candidate as drawn, then with `--jitter` noise on its first
    /// action; the true value is their mean, and the second rollout's order against the first's
    /// is printed (the ceiling of any rater when the outcome is chaotic).
    #[arg(long, default_value_t = 1)]
    replicates: u32,
    /// Noise on the replicate rollouts' first action, in action units.
    #[arg(long, default_value_t = 0.01)]
    jitter: f32,
    /// Steps each candidate is held for before the actor takes over (the values of held
    /// actions; the run's critic rates one step's).
    #[arg(long, default_value_t = 1)]
    hold: u32,
    /// Write the measurement (every state's values too) here as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs `trainer critic-rank`.
pub fn critic_rank(args: &CriticRankArgs) -> anyhow::Result<()> {
    let run = RankedRun::from_run(&args.run)?;
    let scene = load_scene()?;
    let settings = RankingSettings {
        states: args.states,
        candidates: args.candidates,
        noise: args.noise,
        horizon: args.horizon,
        seed: args.seed,
        threads: args.threads,
        replicates: args.replicates,
        jitter: args.jitter,
        hold: args.hold,
    };
    let pb = bar(
        u64::from(args.states),
        args.quiet,
        "ranking {bar:30} {pos}/{len} states ({elapsed}, eta {eta})",
    );
    let report = run.measure(&scene, &settings, &|| pb.inc(1))?;
    pb.finish_and_clear();
    println!(
        "{}: {} states x {} candidates (noise {}, held {} steps), rollouts of {} steps at gamma {}",
        args.run.display(),
        report.states,
        report.candidates,
        report.noise,
        report.hold,
        report.horizon,
        report.gamma
    );
    println!(
        "  the actor's action: mean true value {:.3}; a noisy candidate is truly better at {:.1}% of states",
        report.mean_actor_q,
        100.0 * report.actor_beaten
    );
    println!(
        "  {:.1}% of candidate pairs have equal true values; {} of {} states have a gap; gaps' quartiles {:.4} / {:.4} / {:.4}",
        100.0 * report.tied_pairs,
        report.states_with_gap,
        report.states,
        report.gap_quartiles[0],
        report.gap_quartiles[1],
        report.gap_quartiles[2]
    );
    if let Some(a) = report.rollout_agreement {
        println!(
            "  {} rollouts per candidate (jitter {}): one rollout orders {:.1}% of another's pairs the same way (ties half); the true values are their mean",
            report.replicates,
            report.jitter,
            100.0 * a
        );
    }
    for s in &report.stats {
        println!(
            "  {:<12} pairs ordered right {:.1}% of {} (by gap quarter {:.1} / {:.1} / {:.1} / {:.1}%), a best candidate found {:.1}% (chance {:.1}%), within-state correlation {:.3}",
            s.rater,
            100.0 * s.agreement,
            s.pairs,
            100.0 * s.agreement_by_gap[0],
            100.0 * s.agreement_by_gap[1],
            100.0 * s.agreement_by_gap[2],
            100.0 * s.agreement_by_gap[3],
            100.0 * s.best_match,
            100.0 * s.best_chance,
            s.within_state_correlation
        );
    }
    if let Some(path) = &args.json {
        crate::write_json(path, &report)?;
    }
    Ok(())
}
