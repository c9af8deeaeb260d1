//! Spike (issue #26, session 25): does an advantage-parameterised critic order actions where the
//! learner's `Q(s, a)` network does not? Critics are trained apart from a finished run, on its
//! replay buffer, for its frozen actor `mu`, then rated on the states of a `trainer critic-rank
//! --json` report of the same run (true values from simulator rollouts):
//!
//! - `plain`: the run's critic network, fresh: `Q(s, a)`, TD targets `r + gamma Q'(s', mu(s'))`;
//! - `advantage`: `Q(s, a) = V(s) + c (A(s, a) - A(s, mu(s)))`, two networks; the target is
//!   `r + gamma V'(s')` (the advantage of `mu` is zero by construction), and only `A` orders
//!   the candidates (Baird's advantage updating; Tallec et al. 2019 scale `A` by the time step).
//!
//! ```text
//! cargo run --release -p dex-trainer --example advantage_critic_spike -- SEED_DIR REPORT.json \
//!     [--updates 100000] [--scale 1.0] [--variants plain,advantage]
//! ```

use anyhow::{Context, bail};
use clap::Parser;
use dex_runtime::interface::ACT_DIM;
use dex_trainer::cell::critic_ranking::{StateRanking, rate};
use dex_trainer::cell::run_folder::load_run;
use dex_trainer::learn::adam::{AdamLocal, AdamShared, adam_step};
use dex_trainer::learn::nets::{Activation, Mlp, MlpScratch, MlpSpec};
use dex_trainer::learn::replay::{Batch, Replay};
use dex_trainer::learn::{AdamConfig, Rng};

#[derive(Parser)]
struct Args {
    seed_dir: std::path::PathBuf,
    report: std::path::PathBuf,
    #[arg(long, default_value_t = 100_000)]
    updates: u64,
    /// The advantage's output scale `c`.
    #[arg(long, default_value_t = 1.0)]
    scale: f32,
    #[arg(long, value_delimiter = ',', default_value = "plain,advantage")]
    variants: Vec<String>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Train on held actions instead of the run's replay: this many environment steps of the
    /// run's actor where every `--hold` steps an action (the actor's plus noise `--collect-noise`,
    /// or with probability 0.2 the actor's own) is held for `--hold` steps; the critic's target
    /// is the held steps' discounted reward plus `gamma^hold Q'(s', mu(s'))`. Rate it on a report
    /// made with `critic-rank --hold` of the same length.
    #[arg(long)]
    collect: Option<u64>,
    #[arg(long, default_value_t = 5)]
    hold: u32,
    #[arg(long, default_value_t = 0.3)]
    collect_noise: f32,
}

/// One trainable network with its target and Adam state.
struct Net {
    mlp: Mlp,
    p: Vec<f32>,
    target: Vec<f32>,
    g: Vec<f32>,
    g2: Vec<f32>,
    m: AdamLocal,
    v: AdamShared,
    s: MlpScratch,
    s2: MlpScratch,
}

impl Net {
    fn new(
        spec: MlpSpec,
        engine: dex_trainer::learn::Engine,
        rng: &mut Rng,
        batch: usize,
    ) -> anyhow::Result<Self> {
        let mlp = Mlp::new(spec, engine)?;
        let p = mlp.init_params(rng, 3e-3);
        let n = p.len();
        Ok(Net {
            s: mlp.scratch(batch),
            s2: mlp.scratch(batch),
            mlp,
            target: p.clone(),
            p,
            g: vec![0.0; n],
            g2: vec![0.0; n],
            m: AdamLocal::new(n),
            v: AdamShared::new(n),
        })
    }

    fn step(&mut self, adam: &AdamConfig, tau: f32) {
        adam_step(adam, &mut self.p, &self.g, &mut self.m, &mut self.v);
        for (t, &o) in self.target.iter_mut().zip(&self.p) {
            *t += tau * (o - *t);
        }
    }
}

fn concat(obs: &[f32], act: &[f32], n: usize, od: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(n * (od + ACT_DIM));
    for i in 0..n {
        out.extend_from_slice(&obs[i * od..(i + 1) * od]);
        out.extend_from_slice(&act[i * ACT_DIM..(i + 1) * ACT_DIM]);
    }
    out
}

/// Transitions of held actions: `(x, a, sum_{i<hold} gamma^i r, x', gamma^(hold - 1))`.
fn collect_held(
    nets: &dex_trainer::learn::Networks,
    actor: &[f32],
    settings: &dex_trainer::pipeline::train_settings::TrainSettings,
    steps: u64,
    args: &Args,
    gamma: f32,
) -> anyhow::Result<Replay> {
    use dex_runtime::features::{INPUT_MAX, policy_input};
    let scene = dex_trainer::env::Scene::load()?;
    let mut env =
        dex_trainer::env::JacoEnv::new(&scene, settings.reward.env_config(settings.task.task()));
    let od = nets.obs_dim;
    let mut replay = Replay::new(steps as usize / args.hold as usize + 1, od, ACT_DIM);
    let mut rng = Rng::derive(args.seed, 7);
    let mut scratch = nets.actor.scratch(1);
    let mut taken = 0u64;
    let mut episode = 0u64;
    while taken < steps {
        let seed = dex_trainer::env::seeds::episode_seed(
            dex_trainer::env::seeds::RANKING_SEED + 500_000,
            episode,
        );
        episode += 1;
        env.reset(seed)?;
        let mut done = false;
        while !done && taken < steps {
            let mut buf = [0.0f32; INPUT_MAX];
            let x = policy_input(env.observation(), od, &mut buf).to_vec();
            let mut a = [0.0f32; ACT_DIM];
            a.copy_from_slice(&nets.actor.forward(actor, &x, 1, &mut scratch)?[..ACT_DIM]);
            if rng.uniform_f64() >= 0.2 {
                for v in &mut a {
                    *v = (*v + rng.normal(0.0, args.collect_noise)).clamp(-1.0, 1.0);
                }
            }
            let (mut r, mut discount) = (0.0f32, 1.0f32);
            for _ in 0..args.hold {
                let out = env.step(&a)?;
                r += discount * out.reward;
                discount *= gamma;
                taken += 1;
                if out.done {
                    done = true;
                    break;
                }
            }
            let mut buf2 = [0.0f32; INPUT_MAX];
            let x2 = policy_input(env.observation(), od, &mut buf2).to_vec();
            // The time limit is not terminal: bootstrap over it.
            replay.push_discounted(&x, &a, r, &x2, discount / gamma);
        }
    }
    println!(
        "collected {} held transitions over {episode} episodes",
        replay.len()
    );
    Ok(replay)
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    let (settings, t) = load_run(&args.seed_dir)?;
    let cfg = t.config().clone();
    let nets = t.networks().clone();
    let (od, ad) = (nets.obs_dim, nets.act_dim);
    if ad != ACT_DIM {
        bail!("action size {ad}");
    }
    let actor = t.actor().1.to_vec();
    let gamma = cfg.ddpg.gamma;
    let collected;
    let replays: Vec<&Replay> = t.replays();
    let replay = match args.collect {
        None => *replays.first().context("the run stores no transitions")?,
        Some(steps) => {
            collected = collect_held(&nets, &actor, &settings, steps, &args, gamma)?;
            &collected
        }
    };
    if replay.dims() != (od, ad) {
        bail!("replay dims {:?}", replay.dims());
    }
    println!("replay: {} transitions", replay.len());
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&args.report).context("report")?)?;
    let quartiles: [f64; 3] = serde_json::from_value(report["gap_quartiles"].clone())?;
    let states: Vec<StateRanking> = report["per_state"]
        .as_array()
        .context("per_state")?
        .iter()
        .map(|st| -> anyhow::Result<StateRanking> {
            Ok(StateRanking {
                start_seed: serde_json::from_value(st["start_seed"].clone())?,
                step: serde_json::from_value(st["step"].clone())?,
                true_q: serde_json::from_value(st["true_q"].clone())?,
                replicate_q: serde_json::from_value(st["replicate_q"].clone())?,
                rated: serde_json::from_value(st["rated"].clone())?,
                input: serde_json::from_value(st["input"].clone())?,
                candidates: serde_json::from_value(st["candidates"].clone())?,
            })
        })
        .collect::<anyhow::Result<_>>()?;
    let own = rate(
        "the run's critic",
        &states,
        &states.iter().map(|s| &s.rated[0][..]).collect::<Vec<_>>(),
        &quartiles,
    )?;
    println!("{own:?}");

    let n = cfg.ddpg.batch_size;
    let tau = match cfg.ddpg.target {
        dex_trainer::learn::TargetUpdate::Polyak { tau } => tau,
        dex_trainer::learn::TargetUpdate::Copy { .. } => 0.005,
    };
    let adam = cfg.critic_adam;
    let hidden = &cfg.ddpg.critic_hidden;
    let ln = cfg.ddpg.critic_layer_norm;
    let engine = cfg.ddpg.engine;
    let mut actor_s = nets.actor.scratch(n);
    for variant in &args.variants {
        let start = std::time::Instant::now();
        let mut rng = Rng::derive(args.seed, 1);
        let mut batch = Batch::new(n, od, ad);
        let q_spec = MlpSpec::stack(od + ad, hidden, Activation::Relu, ln, 1, Activation::Linear);
        let v_spec = MlpSpec::stack(od, hidden, Activation::Relu, ln, 1, Activation::Linear);
        let advantage = match variant.as_str() {
            "plain" => false,
            "advantage" => true,
            other => bail!("unknown variant {other}"),
        };
        // plain: q = Q; advantage: q = V, a = A.
        let mut q = Net::new(
            if advantage { v_spec } else { q_spec.clone() },
            engine,
            &mut rng,
            n,
        )?;
        let mut a = Net::new(q_spec, engine, &mut rng, n)?;
        let c = args.scale;
        let mut loss_sum = 0.0f64;
        for u in 0..args.updates {
            replay.sample(&mut rng, n, &mut batch);
            let mu_next = nets
                .actor
                .forward(&actor, &batch.next_obs, n, &mut actor_s)?[..n * ad]
                .to_vec();
            let y: Vec<f32> = if advantage {
                let v_next = q.mlp.forward(&q.target, &batch.next_obs, n, &mut q.s2)?;
                (0..n)
                    .map(|i| batch.reward[i] + gamma * batch.not_done[i] * v_next[i])
                    .collect()
            } else {
                let x = concat(&batch.next_obs, &mu_next, n, od);
                let q_next = q.mlp.forward(&q.target, &x, n, &mut q.s2)?;
                (0..n)
                    .map(|i| batch.reward[i] + gamma * batch.not_done[i] * q_next[i])
                    .collect()
            };
            let mut dq = vec![0.0f32; n];
            let mut loss = 0.0f32;
            if advantage {
                let mu =
                    nets.actor.forward(&actor, &batch.obs, n, &mut actor_s)?[..n * ad].to_vec();
                let x_a = concat(&batch.obs, &batch.act, n, od);
                let x_mu = concat(&batch.obs, &mu, n, od);
                let v = q.mlp.forward(&q.p, &batch.obs, n, &mut q.s)?[..n].to_vec();
                let aa = a.mlp.forward(&a.p, &x_a, n, &mut a.s)?[..n].to_vec();
                let am = a.mlp.forward(&a.p, &x_mu, n, &mut a.s2)?[..n].to_vec();
                for i in 0..n {
                    let e = v[i] + c * (aa[i] - am[i]) - y[i];
                    loss += 0.5 * e * e / n as f32;
                    dq[i] = e / n as f32;
                }
                q.mlp
                    .backward(&q.p, &batch.obs, &mut q.s, &dq, Some(&mut q.g), None)?;
                let da: Vec<f32> = dq.iter().map(|d| c * d).collect();
                let dm: Vec<f32> = dq.iter().map(|d| -c * d).collect();
                a.mlp
                    .backward(&a.p, &x_a, &mut a.s, &da, Some(&mut a.g), None)?;
                a.mlp
                    .backward(&a.p, &x_mu, &mut a.s2, &dm, Some(&mut a.g2), None)?;
                for (g, g2) in a.g.iter_mut().zip(&a.g2) {
                    *g += g2;
                }
                q.step(&adam, tau);
                a.step(&adam, tau);
            } else {
                let x = concat(&batch.obs, &batch.act, n, od);
                let qv = q.mlp.forward(&q.p, &x, n, &mut q.s)?[..n].to_vec();
                for i in 0..n {
                    let e = qv[i] - y[i];
                    loss += 0.5 * e * e / n as f32;
                    dq[i] = e / n as f32;
                }
                q.mlp
                    .backward(&q.p, &x, &mut q.s, &dq, Some(&mut q.g), None)?;
                q.step(&adam, tau);
            }
            loss_sum += f64::from(loss);
            if (u + 1) % (args.updates / 5).max(1) == 0 {
                let rated: Vec<Vec<f32>> = states
                    .iter()
                    .map(|st| -> anyhow::Result<Vec<f32>> {
                        let k = st.candidates.len();
                        let acts: Vec<f32> = st.candidates.iter().flatten().copied().collect();
                        let obs: Vec<f32> = (0..k).flat_map(|_| st.input.iter().copied()).collect();
                        let x = concat(&obs, &acts, k, od);
                        let mut s = if advantage {
                            a.mlp.scratch(k)
                        } else {
                            q.mlp.scratch(k)
                        };
                        let net = if advantage { &a } else { &q };
                        Ok(net.mlp.forward(&net.p, &x, k, &mut s)?[..k].to_vec())
                    })
                    .collect::<anyhow::Result<_>>()?;
                let r: Vec<&[f32]> = rated.iter().map(|v| &v[..]).collect();
                let st = rate(variant, &states, &r, &quartiles)?;
                println!(
                    "{variant} after {} updates ({:.0} s): loss {:.4}, agreement {:.3} by gap {:.2?}, best {:.3} (chance {:.3}), within-state r {:.3}",
                    u + 1,
                    start.elapsed().as_secs_f64(),
                    loss_sum / (args.updates / 5).max(1) as f64,
                    st.agreement,
                    st.agreement_by_gap,
                    st.best_match,
                    st.best_chance,
                    st.within_state_correlation
                );
                loss_sum = 0.0;
            }
        }
    }
    Ok(())
}
