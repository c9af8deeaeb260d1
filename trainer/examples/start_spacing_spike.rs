//! Spike (session 36): the horizontal distance between the bricks' centres at the start of each
//! episode, `SEED EPISODE METRES` per line, to set beside a file's failed starts.
//!
//! ```text
//! cargo run --release -p dex-trainer --example start_spacing_spike -- SEED EPISODES [MAX_MM]
//! ```
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};

fn main() -> anyhow::Result<()> {
    let a: Vec<u64> = std::env::args()
        .skip(1)
        .map(|s| s.parse())
        .collect::<Result<_, _>>()?;
    let (seed, n, close) = match a[..] {
        [seed, n] => (seed, n, None),
        // MAX_MM: the starts of `JacoEnv::reset_close` with the bricks at most MAX_MM mm apart.
        [seed, n, max_mm] => (seed, n, Some(max_mm as f64 / 1000.0)),
        _ => anyhow::bail!("usage: start_spacing_spike SEED EPISODES [MAX_MM]"),
    };
    let scene = Scene::load()?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
    for i in 0..n {
        let obs = match close {
            None => env.reset(episode_seed(seed, i))?,
            Some(max) => env.reset_close(episode_seed(seed, i), max)?,
        };
        let (b1, b2) = (&obs[24..27], &obs[31..34]);
        let d = (b1[0] - b2[0]).hypot(b1[1] - b2[1]);
        println!("{seed} {i} {d:.4}");
    }
    Ok(())
}
