//! Spike (session 31): brick 1's yaw relative to the pinch site (modulo the half turn, degrees) at
//! the start of each episode, `SEED EPISODE DEG` per line (the task features' `sin 2d, cos 2d`).
//!
//! ```text
//! cargo run --release -p dex-trainer --example start_yaw_spike -- SEED EPISODES
//! ```
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};

fn main() -> anyhow::Result<()> {
    let a: Vec<u64> = std::env::args()
        .skip(1)
        .map(|s| s.parse())
        .collect::<Result<_, _>>()?;
    let [seed, n] = a[..] else {
        anyhow::bail!("usage: start_yaw_spike SEED EPISODES");
    };
    let scene = Scene::load()?;
    let mut env = JacoEnv::new(&scene, EnvConfig::new(Task::Stack));
    for i in 0..n {
        let obs = env.reset(episode_seed(seed, i))?;
        let f = dex_runtime::features::task_features(&obs);
        let d = f[2].atan2(f[3]) / 2.0;
        println!("{seed} {i} {:.1}", d.to_degrees());
    }
    Ok(())
}
