//! int8 against f32 for one trained policy: weight bytes, action error on held-out observations
//! and closed-loop success on the same start seeds, everything through the `dex-runtime` evaluator.
//!
//! ```text
//! cargo run --release -p dex-trainer --example int8_compare -- POLICY.dxpl \
//!     [--int8 POLICY-int8.dxpl] [--episodes 100] [--heldout-episodes 20] [--threads 2] [--write OUT]
//! ```
//!
//! - int8 file: `--int8 FILE`, or the post-training quantisation of POLICY (what
//!   `trainer export --int8` writes; `--write OUT` saves it): equalised first on the observations of
//!   `CALIBRATION_EPISODES` f32 episodes from `CALIBRATION_SEED` (8,000,000), unless
//!   `--no-equalise` (plain per-output-channel quantisation, the exporter before equalisation).
//! - held-out observations: every observation of `--heldout-episodes` episodes driven by the f32
//!   policy and as many driven by the int8 policy, from start seeds `HELDOUT_SEED` (7,000,000; no
//!   training or evaluation uses them); the error is `max |a_int8 - a_f32| / (max - min)` per joint.
//! - closed loop: `trainer eval`'s episodes (start seed 1,000,000, CAN quantisation on) for both,
//!   and start by start which outcomes differ.
//!
//! Exit status 0 when both goals hold (error <= 1% of every joint's range, success within 2
//! points), 1 otherwise.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;
use dex_policy::PolicyView;
use dex_runtime::interface::ACTION_JOINTS;
use dex_runtime::testkit::aligned_copy;
use dex_trainer::env::seeds::EVAL_SEED;
use dex_trainer::env::{EnvConfig, Scene, Task};
use dex_trainer::evaluate::{
    EvalSettings, HELDOUT_SEED, PolicyEval, action_error, action_errors, episode_outcomes,
    heldout_observations_of_both,
};
use dex_trainer::files::export::{
    CALIBRATION_EPISODES, CALIBRATION_SEED, calibration_observations, equalise_policy_file,
    quantise_policy_file,
};

#[derive(Parser)]
struct Args {
    /// The f32 policy file.
    policy: PathBuf,
    /// An int8 policy file to compare (default: quantise POLICY).
    #[arg(long)]
    int8: Option<PathBuf>,
    /// Closed-loop episodes per policy.
    #[arg(long, default_value_t = 100)]
    episodes: u32,
    /// Held-out episodes per policy whose observations are compared.
    #[arg(long, default_value_t = 20)]
    heldout_episodes: u32,
    /// Worker threads of the closed-loop evaluation.
    #[arg(long, default_value_t = 2)]
    threads: usize,
    /// Keep the first `N` layers f32 (mixed precision) when quantising POLICY.
    #[arg(long, default_value_t = 0)]
    keep_f32: usize,
    /// Quantise POLICY without equalisation (input folding, cross-layer equalisation).
    #[arg(long)]
    no_equalise: bool,
    /// Write the quantised policy here.
    #[arg(long)]
    write: Option<PathBuf>,
    /// Also run the control: the f32 policy with every weight moved by one ulp, a change far below
    /// any quantisation, start by start against the f32 policy (how chaotic the outcomes are).
    #[arg(long)]
    control: bool,
}

/// `f32_file` with every f32 layer weight moved one ulp away from zero (biases and normalisation
/// kept).
fn nudged(f32_file: &[u8]) -> anyhow::Result<Vec<u8>> {
    let aligned = aligned_copy(f32_file);
    let view = PolicyView::decode(aligned.as_bytes())?;
    let mut values = view.values().as_slice()?.to_vec();
    for l in view.layers() {
        for w in &mut values[l.weights..l.weights + l.inputs * l.outputs] {
            *w = f32::from_bits(w.to_bits() + 1);
        }
    }
    Ok(dex_policy::encode_to_vec(view.body(), &values)?)
}

/// Start-by-start outcome counts of two policies: (both, first only, second only, neither).
fn paired(a: &[(f64, bool)], b: &[(f64, bool)]) -> [usize; 4] {
    let count = |x: bool, y: bool| {
        a.iter()
            .zip(b)
            .filter(|(p, q)| (p.1, q.1) == (x, y))
            .count()
    };
    [
        count(true, true),
        count(true, false),
        count(false, true),
        count(false, false),
    ]
}

fn task_of(view: &PolicyView<'_>) -> Task {
    Task::from(view.body().task)
}

fn main() -> anyhow::Result<ExitCode> {
    let args = Args::parse();
    let f32_file = std::fs::read(&args.policy)
        .with_context(|| format!("cannot read {}", args.policy.display()))?;
    let scene = Scene::load().context("cannot build the MuJoCo scene (scripts/setup-mujoco.sh)")?;
    let env = {
        let aligned = aligned_copy(&f32_file);
        EnvConfig::new(task_of(&PolicyView::decode(aligned.as_bytes())?))
    };
    let int8_file = match &args.int8 {
        Some(p) => std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?,
        None => {
            let source = if args.no_equalise {
                f32_file.clone()
            } else {
                let calibration = calibration_observations(&f32_file, &scene, env)?;
                let eq = equalise_policy_file(&f32_file, &calibration)?;
                println!(
                    "equalised on {} calibration observations ({CALIBRATION_EPISODES} episodes from seed {CALIBRATION_SEED}); f32 function change {:.2e} of a joint's range",
                    calibration.len(),
                    eq.max_f32_change
                );
                eq.file
            };
            if args.keep_f32 == 0 {
                quantise_policy_file(&source, None)?
            } else {
                let aligned = aligned_copy(&source);
                let view = PolicyView::decode(aligned.as_bytes())?;
                dex_policy::int8::quantise_policy(&view, |l| l >= args.keep_f32, None)?
            }
        }
    };
    if let Some(out) = &args.write {
        std::fs::write(out, &int8_file)
            .with_context(|| format!("cannot write {}", out.display()))?;
        println!("wrote {}", out.display());
    }
    let (fa, fb) = (aligned_copy(&f32_file), aligned_copy(&int8_file));
    let (va, vb) = (
        PolicyView::decode(fa.as_bytes())?,
        PolicyView::decode(fb.as_bytes())?,
    );
    let task = task_of(&va);
    println!(
        "policy {} ({:?}), format versions f32 {} / int8 {}",
        args.policy.display(),
        task,
        va.header().version,
        vb.header().version
    );
    println!(
        "weight bytes: f32 {} / int8 {} ({:.2}x smaller); file bytes f32 {} / int8 {}",
        va.weight_bytes(),
        vb.weight_bytes(),
        va.weight_bytes() as f64 / vb.weight_bytes().max(1) as f64,
        f32_file.len(),
        int8_file.len()
    );

    let observations =
        heldout_observations_of_both(&f32_file, &int8_file, &scene, env, args.heldout_episodes)?;
    let error = action_error(&f32_file, &int8_file, &observations)?;
    let worst = error.iter().copied().fold(0.0f64, f64::max);
    println!(
        "held-out observations: {} ({} episodes per policy from seed {HELDOUT_SEED})",
        observations.len(),
        args.heldout_episodes
    );
    println!("max |a_int8 - a_f32| per joint, % of the joint's command range:");
    for (j, e) in ACTION_JOINTS.iter().zip(&error) {
        println!("  {:<24} {:.3}%", j.name, e * 100.0);
    }
    println!(
        "  worst                    {:.3}% (goal <= 1%)",
        worst * 100.0
    );
    let mut all = action_errors(&f32_file, &int8_file, &observations)?;
    all.sort_by(f64::total_cmp);
    let pct = |q: f64| all[((all.len() - 1) as f64 * q) as usize] * 100.0;
    println!(
        "  all (observation, joint) pairs: median {:.3}%, p90 {:.3}%, p99 {:.3}%; share over 1%: {:.1}%",
        pct(0.5),
        pct(0.9),
        pct(0.99),
        all.iter().filter(|&&e| e > 0.01).count() as f64 * 100.0 / all.len().max(1) as f64
    );

    let settings = EvalSettings {
        env,
        episodes: args.episodes,
        seed: EVAL_SEED,
        threads: args.threads,
        can_quantisation: true,
        envelope: false,
    };
    let oa = episode_outcomes(&f32_file, &scene, &settings, &|| {})?;
    let ob = episode_outcomes(&int8_file, &scene, &settings, &|| {})?;
    let (ea, eb) = (
        PolicyEval::from_outcomes(&oa),
        PolicyEval::from_outcomes(&ob),
    );
    let diff = (eb.success_rate() - ea.success_rate()) * 100.0;
    // Start by start: the episodes whose outcome the int8 weights changed.
    let [both, f32_only, int8_only, neither] = paired(&oa, &ob);
    println!(
        "closed loop, {} episodes from seed {EVAL_SEED} (CAN quantisation on):",
        args.episodes
    );
    println!("  f32  {ea}");
    println!("  int8 {eb}");
    println!("  difference {diff:+.1} points (goal within 2)");
    println!(
        "  start by start: both succeed {both}, f32 only {f32_only}, int8 only {int8_only}, neither {neither}"
    );
    if args.control {
        let control = nudged(&f32_file)?;
        let change = action_error(&f32_file, &control, &observations)?
            .iter()
            .copied()
            .fold(0.0, f64::max);
        let oc = episode_outcomes(&control, &scene, &settings, &|| {})?;
        let [both, f32_only, nudged_only, neither] = paired(&oa, &oc);
        println!(
            "control, f32 with every weight one ulp away from zero: worst action change {:.4}% of a joint's range, {}",
            change * 100.0,
            PolicyEval::from_outcomes(&oc)
        );
        println!(
            "  start by start: both succeed {both}, f32 only {f32_only}, nudged only {nudged_only}, neither {neither}"
        );
    }
    let ok = worst <= 0.01 && diff.abs() <= 2.0;
    println!("goals {}", if ok { "met" } else { "MISSED" });
    Ok(if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    })
}
