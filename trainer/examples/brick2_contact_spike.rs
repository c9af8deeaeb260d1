//! Does the hand touch brick 2 before it grasps brick 1, and does that go with failure? Over
//! `EPISODES` starts from `SEED` the policy runs noise-free through the runtime with CAN
//! quantisation (as `trainer eval` runs it); for each episode it prints one CSV row: the start
//! index, success, the bricks' initial centre spacing, the steps with a contact between brick 2 and
//! anything but brick 1 and the world before the grasp predicate first holds, the first such step,
//! brick 2's largest horizontal displacement before the grasp and over the episode, and the
//! nearest the fingers came to brick 2 before the grasp (`JacoEnv::finger_clearance_to_brick2`, capped at 5 cm).
//! A summary by contact and by spacing follows on stderr. With `close`, the starts are drawn with
//! the bricks' centres at most 9.5 cm apart (`JacoEnv::reset_close`).
//!
//! ```text
//! cargo run --release -p dex-trainer --example brick2_contact_spike -- POLICY SEED EPISODES THREADS [close] > rows.csv
//! ```

use anyhow::Context;
use dex_runtime::Mlp;
use dex_trainer::env::seeds::episode_seed;
use dex_trainer::env::{EnvConfig, JacoEnv, Scene, Task};
use dex_trainer::evaluate::{controller_command, physical_to_env_action};

struct Row {
    success: bool,
    spacing: f64,
    contact_steps: u32,
    first_contact: Option<u32>,
    disp_pre: f64,
    disp_all: f64,
    clearance: f64,
    others: Vec<String>,
}

fn main() -> anyhow::Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if !(4..=5).contains(&a.len()) || a.get(4).is_some_and(|c| c != "close") {
        anyhow::bail!("usage: brick2_contact_spike POLICY SEED EPISODES THREADS [close]");
    }
    let close = a.len() == 5;
    let file = std::fs::read(&a[0]).context("policy")?;
    let (seed, n, threads): (u64, usize, usize) = (a[1].parse()?, a[2].parse()?, a[3].parse()?);
    let aligned = dex_runtime::testkit::aligned_copy(&file);
    let view = dex_trainer::evaluate::decode_jaco_policy(aligned.as_bytes())?;
    let task = Task::from(view.body().task);
    let scene = Scene::load()?;
    let rows = dex_trainer::env::parallel::map_in_order(
        n,
        threads,
        || -> anyhow::Result<_> {
            Ok((
                Mlp::<1024>::new(&view)?,
                JacoEnv::new(&scene, EnvConfig::new(task)),
            ))
        },
        |(mlp, env), i| -> anyhow::Result<Row> {
            let start = episode_seed(seed, i as u64);
            let mut o = if close {
                env.reset_close(start, 0.095)?
            } else {
                env.reset(start)?
            };
            let s0 = env.reward_state();
            let start2 = s0.brick2_pos;
            let spacing = ((s0.brick1_pos[0] - start2[0]).powi(2)
                + (s0.brick1_pos[1] - start2[1]).powi(2))
            .sqrt();
            let mut row = Row {
                success: false,
                spacing,
                contact_steps: 0,
                first_contact: None,
                disp_pre: 0.0,
                disp_all: 0.0,
                clearance: f64::INFINITY,
                others: Vec::new(),
            };
            let mut grasped = false;
            loop {
                let act = physical_to_env_action(&controller_command(mlp, &o, true, None)?);
                let out = env.step(&act)?;
                grasped |= out.predicates.grasp;
                let s = env.reward_state();
                let d = ((s.brick2_pos[0] - start2[0]).powi(2)
                    + (s.brick2_pos[1] - start2[1]).powi(2))
                .sqrt();
                row.disp_all = row.disp_all.max(d);
                if !grasped {
                    row.disp_pre = row.disp_pre.max(d);
                    row.clearance = row.clearance.min(env.finger_clearance_to_brick2(0.05));
                    let body_of = |g: i32| env.body_name_of_geom(g).unwrap_or("?").to_owned();
                    let mut touched = false;
                    for c in env.data().contact().iter() {
                        let (b0, b1) = (body_of(c.geom[0]), body_of(c.geom[1]));
                        let other = if b0 == "brick2" {
                            b1
                        } else if b1 == "brick2" {
                            b0
                        } else {
                            continue;
                        };
                        if other != "brick1" && other != "world" {
                            touched = true;
                            if !row.others.contains(&other) {
                                row.others.push(other);
                            }
                        }
                    }
                    if touched {
                        row.contact_steps += 1;
                        row.first_contact.get_or_insert(env.steps_taken());
                    }
                }
                o = out.observation;
                if out.done {
                    row.success = out.success;
                    return Ok(row);
                }
            }
        },
        &|| {},
    )?;
    println!(
        "start,success,spacing,contact_steps,first_contact,disp_pre,disp_all,clearance,bodies"
    );
    for (i, r) in rows.iter().enumerate() {
        println!(
            "{i},{},{:.4},{},{},{:.4},{:.4},{:.4},{}",
            u8::from(r.success),
            r.spacing,
            r.contact_steps,
            r.first_contact.map_or(-1, i64::from),
            r.disp_pre,
            r.disp_all,
            r.clearance,
            r.others.join("|")
        );
    }
    let count = |f: &dyn Fn(&Row) -> bool| {
        let sel: Vec<&Row> = rows.iter().filter(|r| f(r)).collect();
        let fails = sel.iter().filter(|r| !r.success).count();
        (sel.len(), fails)
    };
    for (name, f) in [
        ("all", &(|_: &Row| true) as &dyn Fn(&Row) -> bool),
        ("touched brick 2 before the grasp", &|r: &Row| {
            r.contact_steps > 0
        }),
        ("did not", &|r: &Row| r.contact_steps == 0),
        ("moved brick 2 > 5 mm before the grasp", &|r: &Row| {
            r.disp_pre > 0.005
        }),
        ("spacing < 9.5 cm", &|r: &Row| r.spacing < 0.095),
        ("spacing >= 9.5 cm", &|r: &Row| r.spacing >= 0.095),
        ("spacing < 9.5 cm and touched", &|r: &Row| {
            r.spacing < 0.095 && r.contact_steps > 0
        }),
    ] {
        let (k, fails) = count(f);
        eprintln!("{name}: {k} episodes, {fails} failed");
    }
    Ok(())
}
