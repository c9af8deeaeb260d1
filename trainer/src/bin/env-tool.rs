//! `env-tool`: run the scripted demonstrator and measure the Jaco environment's speed.
//!
//! ```text
//! env-tool demo  --task grasp|stack|stack-in-hand|reach [--episodes 200] [--seed 0] [--verbose] [--markov]
//! env-tool bench [--threads 1] [--steps 3000] [--mode random|demo]
//! env-tool record --task stack [--seed 0] [--out runs/demo]   # for scripts/render-demo.py
//! env-tool trace --task reach [--reward NAME] [--seed 0] [--steps N] [--noise 0.3] --out FILE.json
//! ```
//!
//! Flags take the defaults shown; `env-tool --help` and `env-tool COMMAND --help` describe them. An
//! unknown command or flag, or a bad value, exits 2 with a usage message.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::{Parser, Subcommand};

use dex_trainer::env::{Demonstrator, EnvConfig, JacoEnv, Scene, Task};

#[derive(Parser)]
#[command(
    name = "env-tool",
    about = "Run the scripted demonstrators and measure the Jaco environment's speed"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scripted demonstrator over episodes and report its success rate.
    Demo {
        /// Task: grasp, stack-in-hand, stack or reach.
        #[arg(long, default_value = "grasp")]
        task: Task,
        /// Episodes, from seeds SEED, SEED+1, ...
        #[arg(long, default_value_t = 200)]
        episodes: u64,
        /// First episode seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// One line per control step, and one per episode.
        #[arg(long)]
        verbose: bool,
        /// The Markov demonstrator (its phase at the end of failed episodes) instead.
        #[arg(long)]
        markov: bool,
    },
    /// Environment speed: control steps per second over threads (Grasp, resets every episode).
    Bench {
        /// Threads, each with its own environment.
        #[arg(long, default_value_t = 1)]
        threads: usize,
        /// Control steps per thread.
        #[arg(long, default_value_t = 3000)]
        steps: u64,
        /// Actions: uniform random, or the scripted demonstrator's.
        #[arg(long, default_value = "random", value_parser = ["random", "demo"])]
        mode: String,
    },
    /// scene.xml + qpos.csv of a demonstrator episode (for scripts/render-demo.py).
    Record {
        /// Task: grasp, stack-in-hand, stack or reach.
        #[arg(long, default_value = "stack")]
        task: Task,
        /// Episode seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output folder.
        #[arg(long, default_value = "runs/demo")]
        out: PathBuf,
    },
    /// One noisy demonstrator episode as a JSON trace (for tests/test_dexstack_trace.py).
    Trace {
        /// Task: grasp, stack-in-hand, stack or reach.
        #[arg(long, default_value = "reach")]
        task: Task,
        /// Reward (a `dex_env::Reward` name); the task's default when not given.
        #[arg(long)]
        reward: Option<String>,
        /// Episode seed.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Control steps; the episode's length when not given.
        #[arg(long)]
        steps: Option<u32>,
        /// Amplitude of the uniform noise added to the demonstrator's actions.
        #[arg(long, default_value_t = 0.3)]
        noise: f64,
        /// Output JSON file.
        #[arg(long)]
        out: PathBuf,
    },
}

fn main() -> ExitCode {
    // Unknown commands and flags, and bad values, exit 2 with a usage message (clap).
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo {
            task,
            episodes,
            seed,
            verbose,
            markov,
        } => {
            if markov {
                markov_demo(task, episodes, seed)
            } else {
                demo(task, episodes, seed, verbose)
            }
        }
        Command::Bench {
            threads,
            steps,
            mode,
        } => bench(threads, steps, &mode),
        Command::Record { task, seed, out } => record(task, seed, &out),
        Command::Trace {
            task,
            reward,
            seed,
            steps,
            noise,
            out,
        } => trace(task, reward.as_deref(), seed, steps, noise, &out),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("env-tool: {e}");
            ExitCode::FAILURE
        }
    }
}

type BoxError = Box<dyn std::error::Error + Send + Sync>;

/// `demo`: success of the scripted demonstrator, and the environment's speed with it.
fn demo(task: Task, episodes: u64, seed: u64, verbose: bool) -> Result<(), BoxError> {
    let scene = Scene::load()?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(task));
    let start = Instant::now();
    let mut successes = 0;
    let mut steps = 0u64;
    for ep in 0..episodes {
        env.reset(seed + ep)?;
        let mut demo = Demonstrator::new(task);
        let mut ret = 0.0;
        loop {
            let a = demo.act(&env);
            let out = env.step(&a)?;
            steps += 1;
            ret += out.reward;
            if verbose {
                let s = env.reward_state();
                println!(
                    "ep {ep} t {:3} {:?} pinch {:.3?} b1 {:.3?} off {:.4?} r {:.3}",
                    env.steps_taken(),
                    demo.phase(),
                    s.pinch,
                    s.brick1_pos,
                    s.stack_offset(),
                    out.reward
                );
            }
            if out.done {
                successes += u32::from(out.success);
                if !out.success || verbose {
                    println!(
                        "episode {ep} (seed {}): success {} return {ret:.2} phase {:?}",
                        seed + ep,
                        out.success,
                        demo.phase()
                    );
                }
                break;
            }
        }
    }
    let secs = start.elapsed().as_secs_f64();
    println!(
        "task {task:?}: {successes}/{episodes} successes ({:.1}%), {steps} control steps in {secs:.1} s ({:.0} steps/s incl. resets)",
        100.0 * f64::from(successes) / episodes as f64,
        steps as f64 / secs
    );
    Ok(())
}

/// `demo --markov`: success of the Markov demonstrator (its phase at the end of failed episodes).
fn markov_demo(task: Task, episodes: u64, seed: u64) -> Result<(), BoxError> {
    let scene = Scene::load()?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(task));
    let demo = dex_trainer::env::MarkovDemonstrator::new(task);
    let start = Instant::now();
    let mut successes = 0;
    for ep in 0..episodes {
        env.reset(seed + ep)?;
        loop {
            let out = env.step(&demo.act(&env))?;
            if out.done {
                successes += u32::from(out.success);
                if !out.success {
                    println!(
                        "episode {ep} (seed {}): failed in phase {:?}",
                        seed + ep,
                        demo.phase(&env)
                    );
                }
                break;
            }
        }
    }
    println!(
        "task {task:?} (Markov demonstrator): {successes}/{episodes} successes ({:.1}%) in {:.1} s",
        100.0 * f64::from(successes) / episodes as f64,
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Writes the composed scene as one MJCF file and the demonstrator's qpos at every control step.
fn record(task: Task, seed: u64, dir: &std::path::Path) -> Result<(), BoxError> {
    use std::fmt::Write;
    std::fs::create_dir_all(dir)?;
    let mut spec = dex_trainer::env::scene::compose_spec(&dex_trainer::env::AssetPaths::locate())?;
    spec.compile()?;
    spec.save_xml(dir.join("scene.xml"))?;
    let scene = Scene::load()?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(task));
    env.reset(seed)?;
    let mut demo = Demonstrator::new(task);
    let mut csv = String::new();
    let mut write_row = |env: &JacoEnv| -> std::fmt::Result {
        let row: Vec<String> = env
            .data()
            .qpos()
            .iter()
            .map(|q| format!("{q:.6}"))
            .collect();
        writeln!(csv, "{}", row.join(","))
    };
    write_row(&env)?;
    let mut success = false;
    for _ in 0..env.config().episode_steps {
        let out = env.step(&demo.act(&env))?;
        write_row(&env)?;
        success = out.success;
    }
    dex_trainer::files::atomic_write::write_atomic(&dir.join("qpos.csv"), csv.as_bytes())?;
    println!(
        "recorded {task:?} seed {seed} (success {success}) into {}",
        dir.display()
    );
    Ok(())
}

/// `bench`: control steps per second of `threads` environments stepping at once.
fn bench(threads: usize, steps: u64, mode: &str) -> Result<(), BoxError> {
    let demo_mode = match mode {
        "random" => false,
        "demo" => true,
        other => return Err(format!("unknown --mode {other}").into()),
    };
    let scene = Scene::load()?;
    let start = Instant::now();
    let results: Vec<Result<(u64, f64), String>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                let scene = &scene;
                s.spawn(move || {
                    bench_worker(scene, t as u64, steps, demo_mode).map_err(|e| e.to_string())
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|_| Err("worker panicked".into())))
            .collect()
    });
    let wall = start.elapsed().as_secs_f64();
    let mut total = 0;
    let mut physics = 0.0;
    for r in results {
        let (n, p) = r?;
        total += n;
        physics += p;
    }
    println!(
        "mode {mode} threads {threads}: {total} control steps in {wall:.2} s = {:.0} steps/s ({:.0} per thread), {:.1} simulated s per wall s, step-only time {:.1} us/step",
        total as f64 / wall,
        total as f64 / wall / threads as f64,
        total as f64 * 0.05 / wall,
        physics / total as f64 * 1e6
    );
    Ok(())
}

/// Steps `steps` control steps with resets every episode; returns steps and seconds spent in `step`.
fn bench_worker(
    scene: &Scene,
    worker: u64,
    steps: u64,
    demo_mode: bool,
) -> Result<(u64, f64), BoxError> {
    let task = Task::Grasp;
    let mut env = JacoEnv::new(scene, EnvConfig::new(task));
    let mut rng = dex_trainer::env::rng::SeedRng::new(1000 + worker);
    let mut demo = Demonstrator::new(task);
    let mut ep = worker * 1_000_000;
    env.reset(ep)?;
    let mut in_step = 0.0;
    for _ in 0..steps {
        let a = if demo_mode {
            demo.act(&env)
        } else {
            std::array::from_fn(|_| rng.uniform(-1.0, 1.0) as f32)
        };
        let t = Instant::now();
        let out = env.step(&a)?;
        in_step += t.elapsed().as_secs_f64();
        if out.done {
            ep += 1;
            env.reset(ep)?;
            demo.restart();
        }
    }
    Ok((steps, in_step))
}

/// Writes one episode as JSON for `tests/test_dexstack_trace.py`: the scripted demonstrator's action
/// at every step, the action applied (that plus uniform noise of amplitude `--noise`, from a fixed
/// generator, so some components leave [-1, 1] and are clipped), and the observation, reward,
/// success and predicates after it. Floats are written as their IEEE-754 bits (`u32`), so the
/// comparison on the Python side is bit for bit.
fn trace(
    task: Task,
    reward_name: Option<&str>,
    seed: u64,
    steps: Option<u32>,
    noise: f64,
    out: &std::path::Path,
) -> Result<(), BoxError> {
    let mut config = EnvConfig::new(task);
    if let Some(reward_name) = reward_name.filter(|r| !r.is_empty()) {
        let reward: dex_trainer::env::Reward =
            serde_json::from_value(serde_json::Value::String(reward_name.to_owned()))
                .map_err(|e| format!("--reward {reward_name}: {e}"))?;
        config = config.with_reward(reward);
    }
    let steps = steps.unwrap_or(config.episode_steps);
    let scene = Scene::load()?;
    let mut env = JacoEnv::new(&scene, config);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    let first = env.reset(seed)?;
    let mut demo = Demonstrator::new(task);
    let mut rng = dex_trainer::env::rng::SeedRng::new(seed ^ 0x7124_CE00);
    let mut records = Vec::new();
    for _ in 0..steps {
        let planned = demo.act(&env);
        let action: [f32; 9] =
            std::array::from_fn(|i| planned[i] + rng.uniform(-noise, noise) as f32);
        let o = env.step(&action)?;
        records.push(serde_json::json!({
            "demo": bits(&planned),
            "action": bits(&action),
            "obs": bits(&o.observation),
            "reward": o.reward.to_bits(),
            "done": o.done,
            "success": o.success,
            "reach": o.predicates.reach,
            "grasp": o.predicates.grasp,
            "stack": o.predicates.stack,
        }));
    }
    let doc = serde_json::json!({
        "task": task,
        "reward": config.reward,
        "seed": seed,
        "reset": bits(&first),
        "steps": records,
    });
    dex_trainer::files::atomic_write::write_atomic(out, serde_json::to_string(&doc)?.as_bytes())?;
    println!(
        "wrote {steps} steps of {task:?} from seed {seed} to {}",
        out.display()
    );
    Ok(())
}
