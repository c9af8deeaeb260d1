//! Spike driver of the group-relative policy gradient (`trainer::pipeline::group_pg`):
//! `cargo run --release -p dex-trainer --example group_pg_spike -- POLICY OUT_DIR
//! [--iterations N] [--groups G] [--replicates K] [--lr LR] [--anchor B] [--threads T]
//! [--noise ARM FINGER] [--epochs E] [--seed S] [--save-every M]` (Stack).

use anyhow::{Context, Result, bail};
use dex_trainer::env::{Scene, Task};
use dex_trainer::pipeline::group_pg::{GroupPg, run};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        bail!("usage: group_pg_spike POLICY OUT_DIR [flags]");
    }
    let mut s = GroupPg::new(args[0].clone().into());
    let out = std::path::PathBuf::from(&args[1]);
    let (mut threads, mut save_every, mut task) = (2usize, 10u32, Task::Stack);
    let mut i = 2;
    while i < args.len() {
        let v = |k: usize| args.get(i + k).context("missing value");
        match args[i].as_str() {
            "--iterations" => s.iterations = v(1)?.parse()?,
            "--groups" => s.groups = v(1)?.parse()?,
            "--replicates" => s.replicates = v(1)?.parse()?,
            "--lr" => s.lr = v(1)?.parse()?,
            "--anchor" => s.anchor = v(1)?.parse()?,
            "--epochs" => s.epochs = v(1)?.parse()?,
            "--clip" => s.clip = v(1)?.parse()?,
            "--seed" => s.seed = v(1)?.parse()?,
            "--revisit" => s.revisit = v(1)?.parse()?,
            "--threads" => threads = v(1)?.parse()?,
            "--save-every" => save_every = v(1)?.parse()?,
            "--grasp" => {
                task = Task::Grasp;
                i -= 1;
            }
            "--noise" => {
                s.arm_noise = v(1)?.parse()?;
                s.finger_noise = v(2)?.parse()?;
                i += 1;
            }
            other => bail!("unknown flag {other}"),
        }
        i += 2;
    }
    let scene = Scene::load().context("cannot build the MuJoCo scene")?;
    let t0 = std::time::Instant::now();
    run(&s, &scene, task, &out, threads, save_every, &mut |r| {
        println!(
            "it {:3} success {:3}/{:3} mixed {:2} samples {:6} clipped {:.3} drift {:.4} steps {} wall {:.0}s",
            r.iteration,
            r.successes,
            r.episodes,
            r.mixed_groups,
            r.samples,
            r.clipped,
            r.drift,
            r.env_steps,
            t0.elapsed().as_secs_f64()
        );
    })?;
    Ok(())
}
