//! `trainer figure FIGURE.toml`: one command per figure of the paper. A figure file names the runs
//! (each a `trainer train` config file) drawn as curves of one plot; the command trains what is not
//! trained yet (resuming, so it can be stopped and re-run, or re-run with a larger budget), then
//! draws mean and min-max band over seeds of every run into one PNG/SVG pair per metric.
//!
//! ```toml
//! title = "Stack, original starts"
//! out = "docs/figures/stack-rewards-original"   # writes ..._return.{png,svg}, ..._success.{png,svg}
//! [[runs]]
//! label = "sparse"
//! config = "experiments/stack-sparse-original.toml"
//! [[marks]]                                     # optional: the paper's figures, dashed
//! label = "paper: 95.5% (Table II)"
//! success = 0.955                               # a level on the success plots
//! transitions = 1000000                         # a budget on the plots against transitions
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::Deserialize;

use dex_trainer::pipeline::plot::{Condition, Mark};
use dex_trainer::pipeline::run_plots::{plot_conditions, read_run};
use dex_trainer::pipeline::train_settings::{self, TrainSettings};

use crate::TrainArgs;
use crate::train;

/// One curve of a figure.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FigureRun {
    /// Legend label.
    pub label: String,
    /// `trainer train` config file (relative paths are relative to the working directory).
    pub config: PathBuf,
}

/// A figure file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Figure {
    /// Plot title.
    pub title: String,
    /// Output stem of the plots.
    pub out: PathBuf,
    /// The curves.
    pub runs: Vec<FigureRun>,
    /// Published figures drawn over the curves (the paper's success, its budget).
    #[serde(default)]
    pub marks: Vec<Mark>,
}

/// Reads and checks a figure file: every run's config must load and validate; returns the figure
/// and each run's settings (in the order of `runs`).
pub fn load(path: &Path) -> anyhow::Result<(Figure, Vec<TrainSettings>)> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let fig: Figure = toml::from_str(&text)
        .with_context(|| format!("{} is not a figure file", path.display()))?;
    if fig.runs.is_empty() {
        bail!(
            "{}: a figure needs at least one [[runs]] entry",
            path.display()
        );
    }
    for m in &fig.marks {
        m.validate()
            .map_err(|why| anyhow::anyhow!("{}: {why}", path.display()))?;
    }
    let settings = fig
        .runs
        .iter()
        .map(|r| {
            train_settings::load(Some(&r.config))
                .and_then(|s| s.validate().map(|()| s))
                .with_context(|| format!("run `{}` of {}", r.label, path.display()))
        })
        .collect::<anyhow::Result<_>>()?;
    Ok((fig, settings))
}

/// `trainer figure`: trains the figure's runs (unless `plot_only`), then plots them together.
/// `overrides` carries command-line flags (e.g. a smaller `--transitions` or other `--seeds`)
/// applied to every run; each run keeps its config's output folder.
pub fn figure(path: &Path, overrides: &TrainArgs, plot_only: bool) -> anyhow::Result<()> {
    if overrides.out.is_some() || overrides.config.is_some() {
        bail!("a figure's runs keep their own config files and output folders");
    }
    let (fig, settings) = load(path)?;
    if !plot_only {
        let stop = train::stop_flag()?;
        for r in &fig.runs {
            println!("figure `{}`: run `{}`", fig.title, r.label);
            let mut args = overrides.clone();
            args.config = Some(r.config.clone());
            args.resume = true;
            if !train::train_with(&args, &stop)? {
                println!("stopped; re-run the same command to continue");
                return Ok(());
            }
        }
    }
    let mut conditions = Vec::new();
    let mut per_worker = false;
    for (r, s) in fig.runs.iter().zip(&settings) {
        per_worker |= s.run.workers > 1;
        match read_run(&s.out, &mut train::warn_malformed) {
            Ok(run) => conditions.push(Condition {
                label: r.label.clone(),
                seeds: run.seeds,
            }),
            Err(e) => eprintln!(
                "run `{}` left out of the plot: {:#}",
                r.label,
                anyhow::Error::from(e)
            ),
        }
    }
    if conditions.is_empty() {
        bail!("none of the figure's runs has evaluations yet");
    }
    let dir = fig.out.parent().unwrap_or(Path::new("."));
    let stem = fig
        .out
        .file_name()
        .with_context(|| format!("figure `out` {} names no file", fig.out.display()))?
        .to_string_lossy();
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    for f in plot_conditions(
        dir,
        &format!("{stem}_"),
        &fig.title,
        &conditions,
        &fig.marks,
        per_worker,
    )? {
        println!("wrote {}", f.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use dex_trainer::learn::EvalRecord;

    fn repo() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
    }

    #[test]
    fn every_figure_and_experiment_file_loads_and_validates() {
        let dir = repo();
        let mut n = 0;
        for e in std::fs::read_dir(dir.join("experiments/figures")).unwrap() {
            let p = e.unwrap().path();
            let fig: Figure = toml::from_str(&std::fs::read_to_string(&p).unwrap())
                .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            assert!(fig.out.starts_with("docs/figures"), "{}", p.display());
            assert!(!fig.runs.is_empty());
            for r in &fig.runs {
                assert!(
                    dir.join(&r.config).exists(),
                    "{}: {:?}",
                    p.display(),
                    r.config
                );
            }
            n += 1;
        }
        for e in std::fs::read_dir(dir.join("experiments")).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "toml") {
                train_settings::load(Some(&p))
                    .and_then(|s| s.validate())
                    .unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
            }
        }
        assert!(n >= 6, "{n} figure files");
    }

    #[test]
    fn a_figure_plots_every_run_as_one_curve_and_bad_files_are_refused() {
        let tmp = std::env::temp_dir().join(format!("dex-fig-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        std::fs::create_dir_all(&tmp).unwrap();
        let mut runs = String::new();
        for (k, label) in ["alpha-run", "beta-run"].iter().enumerate() {
            let out = tmp.join(format!("run-{label}"));
            let cfg = tmp.join(format!("{label}.toml"));
            std::fs::write(
                &cfg,
                format!("task = \"grasp\"\nout = \"{}\"\n", out.display()),
            )
            .unwrap();
            for seed in 0..2u64 {
                let d = out.join(format!("seed-{seed}"));
                std::fs::create_dir_all(&d).unwrap();
                let lines: Vec<String> = (1..=5u64)
                    .map(|i| {
                        EvalRecord {
                            eval_index: i,
                            episodes: 30 * i,
                            transitions: 4500 * i,
                            transitions_per_worker: vec![4500 * i],
                            updates: 9000 * i,
                            wall_s: i as f64,
                            mean_return: (i + seed) as f64 * (k + 1) as f64,
                            success_rate: 0.1 * i as f64,
                            train_return: 0.0,
                            worker: 0,
                            proposal_share: None,
                        }
                        .to_json_line()
                    })
                    .collect();
                std::fs::write(d.join("eval.jsonl"), lines.join("\n")).unwrap();
            }
            runs.push_str(&format!(
                "[[runs]]\nlabel = \"{label}\"\nconfig = \"{}\"\n",
                cfg.display()
            ));
        }
        let stem = tmp.join("figs/fig");
        let fig = tmp.join("fig.toml");
        std::fs::write(
            &fig,
            format!(
                "title = \"t\"\nout = \"{}\"\n{runs}[[marks]]\nlabel = \"paper-mark\"\n\
                 success = 0.955\ntransitions = 1000000\n",
                stem.display()
            ),
        )
        .unwrap();
        figure(&fig, &TrainArgs::default(), true).unwrap();
        for f in [
            "fig_return.png",
            "fig_return.svg",
            "fig_success.png",
            "fig_success.svg",
        ] {
            let p = tmp.join("figs").join(f);
            assert!(
                std::fs::metadata(&p).unwrap().len() > 1000,
                "{}",
                p.display()
            );
        }
        let svg = std::fs::read_to_string(tmp.join("figs/fig_return.svg")).unwrap();
        assert!(
            svg.contains("alpha-run") && svg.contains("beta-run"),
            "legend labels"
        );
        // The paper's mark: its budget on the plots against transitions (whose axis then reaches
        // 1M), its level on the success plots, nothing on the return against wall-clock.
        let read = |f: &str| std::fs::read_to_string(tmp.join("figs").join(f)).unwrap();
        assert!(read("fig_success.svg").contains("paper-mark") && svg.contains("1.000"));
        assert!(svg.contains("paper-mark") && read("fig_success_wall.svg").contains("paper-mark"));
        assert!(!read("fig_return_wall.svg").contains("paper-mark"));
        // A mark that draws nothing, or a success off the axis, is refused.
        for bad in ["", "success = 1.5\n"] {
            std::fs::write(
                &fig,
                format!("title = \"t\"\nout = \"x\"\n{runs}[[marks]]\nlabel = \"m\"\n{bad}"),
            )
            .unwrap();
            assert!(format!("{:#}", load(&fig).unwrap_err()).contains("mark `m`"));
        }
        // A figure without runs, or naming a broken config, is refused with the culprit named.
        std::fs::write(&fig, "title = \"t\"\nout = \"x\"\nruns = []\n").unwrap();
        assert!(format!("{:#}", load(&fig).unwrap_err()).contains("at least one"));
        std::fs::write(tmp.join("bad.toml"), "task = \"juggle\"\n").unwrap();
        std::fs::write(
            &fig,
            format!(
                "title = \"t\"\nout = \"x\"\n[[runs]]\nlabel = \"bad\"\nconfig = \"{}\"\n",
                tmp.join("bad.toml").display()
            ),
        )
        .unwrap();
        assert!(format!("{:#}", load(&fig).unwrap_err()).contains("run `bad`"));
        let _ = std::fs::remove_dir_all(&tmp);
    }
}
