//! Unit tests of the fine-tune's pieces: the report line, the starts, the pools.

use std::path::PathBuf;

use super::rollouts::{Episode, HARD_STARTS};
use super::*;
use crate::learn::Rng;
use crate::learn::adam::{AdamConfig, AdamLocal, AdamShared};
use dex_runtime::interface::ACT_DIM;

#[test]
fn a_report_line_counts_the_stall_episodes_by_the_replicates() {
    let mut r = IterationReport {
        iteration: 0,
        episodes: 160,
        successes: 82,
        mixed_groups: 8,
        samples: 0,
        clipped: 0.1,
        drift: 0.06,
        env_steps: 466_968,
        stall_groups: 0,
        stall_successes: 0,
        stall_pool: 0,
        close_groups: 0,
        close_successes: 0,
        failed_groups: 0,
        failed_successes: 0,
        touched: 0,
        close_touched: 0,
    };
    let plain = r.line(8);
    assert!(
        plain.starts_with("iteration 1 success 82/160 with noise"),
        "{plain}"
    );
    assert!(!plain.contains("from stalls"), "{plain}");
    assert!(!plain.contains("touched"), "{plain}");
    (r.touched, r.close_touched) = (5, 4);
    assert!(
        r.line(8)
            .ends_with("; touched brick 2 before the grasp in 5 episodes (4 from close starts)"),
        "{}",
        r.line(8)
    );
    (r.touched, r.close_touched) = (0, 0);
    (r.stall_groups, r.stall_successes, r.stall_pool) = (16, 50, 16);
    assert!(
        r.line(8)
            .ends_with("; from stalls 50/128 (16 groups, pool 16)"),
        "{}",
        r.line(8)
    );
}

fn settings(revisit: f32) -> GroupPg {
    GroupPg {
        groups: 8,
        revisit,
        ..GroupPg::new(PathBuf::from("p.dxpl"))
    }
}

#[test]
fn revisits_take_their_share_from_the_hard_starts_without_repeats() {
    let fresh = settings(0.0).starts(3, &[1, 2, 3]);
    let expected: Vec<u64> = (0..8).map(|g| settings(0.0).start_seed(3, g)).collect();
    assert_eq!(fresh, expected, "without revisits every start is fresh");
    let s = settings(0.5);
    let mixed = s.starts(3, &[11, 12, 13, 14, 15, 16]);
    assert_eq!(mixed.len(), 8);
    let (old, new) = mixed.split_at(4);
    assert!(old.iter().all(|x| (11..=16).contains(x)));
    let mut sorted = old.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    assert_eq!(
        sorted.len(),
        4,
        "a hard start is revisited once per iteration"
    );
    assert_eq!(new, &expected[4..]);
    // Fewer hard starts than the share: all of them, the rest fresh.
    let few = s.starts(3, &[11]);
    assert_eq!(few[0], 11);
    assert_eq!(&few[1..], &expected[1..]);
    assert_eq!(s.starts(3, &[11, 12, 13]), s.starts(3, &[11, 12, 13]));
}

fn ep(success: bool) -> Episode {
    Episode {
        obs: Vec::new(),
        noise: Vec::new(),
        steps: 0,
        success,
        touched: false,
        clearance: f32::INFINITY,
        stall: None,
    }
}

/// An episode of `rows` kept steps (zero observations, small noise) with its outcome and contact.
fn ep_rows(success: bool, touched: bool, rows: usize) -> Episode {
    let noise: [f32; dex_runtime::interface::ACT_DIM] = std::array::from_fn(|j| 0.01 * j as f32);
    Episode {
        obs: vec![[0.0; dex_runtime::interface::OBS_DIM]; rows],
        noise: vec![noise; rows],
        steps: rows as u64,
        success,
        touched,
        clearance: f32::INFINITY,
        stall: None,
    }
}

/// One update of the Grasp fixture's actor on `episodes` (groups of 4, none of them start-seed
/// groups); its report and whether the actor moved.
fn update_once(s: &GroupPg, episodes: &[Episode]) -> (IterationReport, bool) {
    let file = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/grasp_clone_session14.dxpl"
    ))
    .unwrap();
    let mut actor =
        crate::pipeline::file_actor::FileActor::from_file(&file, crate::env::Task::Grasp).unwrap();
    let before = actor.params.clone();
    let n = actor.params.len();
    let (mut local, mut shared) = (AdamLocal::new(n), AdamShared::new(n));
    let mut scratch = actor.net.scratch(s.minibatch as usize);
    let adam = AdamConfig {
        lr: s.lr,
        ..AdamConfig::default()
    };
    let report = super::update::update(
        s,
        &mut actor,
        episodes,
        0,
        0,
        &adam,
        &mut local,
        &mut shared,
        &mut scratch,
    )
    .unwrap();
    (report, actor.params != before)
}

#[test]
fn a_contact_cost_gives_a_gradient_to_a_group_that_succeeds_every_time() {
    let s = GroupPg {
        replicates: 4,
        minibatch: 64,
        epochs: 1,
        lr: 1e-3,
        ..GroupPg::new(PathBuf::from("p.dxpl"))
    };
    // Every episode succeeds; two of the four touched brick 2 before the grasp.
    let group = || {
        vec![
            ep_rows(true, true, 5),
            ep_rows(true, false, 5),
            ep_rows(true, true, 5),
            ep_rows(true, false, 5),
        ]
    };
    let (plain, moved) = update_once(&s, &group());
    assert_eq!(
        (plain.mixed_groups, plain.samples, plain.touched),
        (0, 0, 2)
    );
    assert!(
        !moved,
        "a group of equal outcomes moved the actor without a cost"
    );
    let charged = GroupPg {
        contact_cost: 0.5,
        ..s.clone()
    };
    let (report, moved) = update_once(&charged, &group());
    assert_eq!((report.mixed_groups, report.samples), (1, 20), "{report:?}");
    assert!(moved, "the contact cost's gradient did not move the actor");
    // A group in which every episode touched gains nothing from the cost: the baseline absorbs it.
    let all = vec![
        ep_rows(true, true, 5),
        ep_rows(true, true, 5),
        ep_rows(true, true, 5),
        ep_rows(true, true, 5),
    ];
    let (report, moved) = update_once(&charged, &all);
    assert_eq!((report.mixed_groups, report.samples), (0, 0), "{report:?}");
    assert!(!moved);
    // With a margin, a fingertip that passed within it pays its share: the group's episodes all
    // succeed and none touched, yet they differ in how near their tips came.
    let margined = GroupPg {
        contact_margin: 0.02,
        ..charged.clone()
    };
    assert_eq!(margined.contact_share(true, 0.5), 1.0);
    assert_eq!(margined.contact_share(false, 0.03), 0.0);
    assert!((margined.contact_share(false, 0.015) - 0.25).abs() < 1e-6);
    assert_eq!(
        charged.contact_share(false, 0.0),
        0.0,
        "no margin: only a contact pays"
    );
    let near = |clearance: f32| Episode {
        clearance,
        ..ep_rows(true, false, 5)
    };
    let passes = vec![near(0.005), near(0.05), near(0.015), near(f32::INFINITY)];
    let (report, moved) = update_once(&margined, &passes);
    assert_eq!((report.mixed_groups, report.samples), (1, 20), "{report:?}");
    assert!(moved);
    let passes = vec![near(0.005), near(0.05), near(0.015), near(f32::INFINITY)];
    let (report, _) = update_once(&charged, &passes);
    assert_eq!(
        report.mixed_groups, 0,
        "without a margin the passes are all equal"
    );
    for (cost, margin) in [
        (0.5f32, -0.01f32),
        (0.5, 0.06),
        (0.5, f32::NAN),
        (0.0, 0.02),
    ] {
        let s = GroupPg {
            contact_cost: cost,
            contact_margin: margin,
            ..s.clone()
        };
        assert!(
            matches!(s.validate(), Err(GroupPgError::Settings(m)) if m.contains("contact_margin")),
            "contact_margin {margin} with cost {cost} accepted"
        );
    }
    // Out of range: a contact may cost at most a failure.
    for bad in [-0.1f32, 1.5, f32::NAN, f32::INFINITY] {
        let s = GroupPg {
            contact_cost: bad,
            ..s.clone()
        };
        assert!(
            matches!(s.validate(), Err(GroupPgError::Settings(m)) if m.contains("contact_cost")),
            "contact_cost {bad} accepted"
        );
    }
}

#[test]
fn the_stall_pool_keeps_one_entry_per_seed_and_step_and_the_newest() {
    let snap = |steps: u32| {
        let json = format!("{{\"state\":[0.0],\"steps\":{steps}}}");
        serde_json::from_str::<crate::env::EnvSnapshot>(&json).unwrap()
    };
    let entry = |seed: u64, steps: u32| StallStart {
        seed,
        snapshot: snap(steps),
    };
    let mut pool = vec![entry(1, 60)];
    remember_stalls(&mut pool, vec![entry(1, 60), entry(1, 70), entry(2, 60)]);
    assert_eq!(pool, vec![entry(1, 60), entry(1, 70), entry(2, 60)]);
    let many: Vec<StallStart> = (0..STALL_POOL as u64 + 5)
        .map(|s| entry(s + 10, 60))
        .collect();
    remember_stalls(&mut pool, many);
    assert_eq!(pool.len(), STALL_POOL);
    assert_eq!(pool.last(), Some(&entry(STALL_POOL as u64 + 14, 60)));
}

#[test]
fn a_start_stays_hard_while_its_group_fails() {
    let mut hard = vec![5, 7];
    let episodes = [ep(false), ep(true), ep(true), ep(true), ep(true), ep(true)];
    remember_hard(&mut hard, &[9, 7, 5], &episodes, 2);
    // 9 failed once (kept, newest), 7 and 5 succeeded every time (dropped).
    assert_eq!(hard, vec![9]);
    let mut many: Vec<u64> = (0..HARD_STARTS as u64).collect();
    remember_hard(&mut many, &[1000], &[ep(false), ep(false)], 2);
    assert_eq!(many.len(), HARD_STARTS);
    assert_eq!(many.last(), Some(&1000));
    assert_eq!(many[0], 1, "the oldest start is dropped");
}

#[test]
fn failed_start_groups_pick_from_their_list_without_repeats_and_need_one() {
    let s = GroupPg {
        failed_groups: 3,
        failed_starts: vec![101, 102, 103, 104, 105],
        failed_noise_steps: 40,
        ..GroupPg::new(PathBuf::from("p.dxpl"))
    };
    s.validate().unwrap();
    for iteration in 0..20 {
        let mut picks = s.failed_picks(iteration);
        assert_eq!(picks.len(), 3);
        assert!(picks.iter().all(|p| (101..=105).contains(p)));
        picks.sort_unstable();
        picks.dedup();
        assert_eq!(picks.len(), 3, "no start twice in one iteration");
    }
    assert_ne!(
        (0..8).map(|i| s.failed_picks(i)).collect::<Vec<_>>(),
        vec![s.failed_picks(0); 8],
        "the picks change with the iteration"
    );
    let more = GroupPg {
        failed_groups: 6,
        ..s.clone()
    };
    let why = more.validate().unwrap_err().to_string();
    assert!(
        why.contains("failed_groups (6)") && why.contains("(5)"),
        "{why}"
    );
    let stray = GroupPg {
        failed_groups: 0,
        failed_starts: Vec::new(),
        ..s
    };
    let why = stray.validate().unwrap_err().to_string();
    assert!(why.contains("failed_noise_steps"), "{why}");
}

#[test]
fn the_episode_noise_is_the_white_stream_or_a_drift_of_the_same_spread() {
    let white = GroupPg::new("x.dxpl".into());
    // White: exactly the plain Gaussian draws, joint by joint, so runs without a correlation
    // are those of before it existed.
    let (mut a, mut b) = (Rng::derive(7, 3), Rng::derive(7, 3));
    let mut noise = white.exploration_noise(&mut a);
    for _ in 0..20 {
        let mut e = [0.0f32; ACT_DIM];
        noise.draw(&mut a, &mut e);
        for (j, x) in e.iter().enumerate() {
            assert_eq!(*x, b.normal(0.0, white.sigma(j)));
        }
    }
    // Correlated: each joint keeps its spread and has the lag-one correlation.
    let s = GroupPg {
        noise_correlation: 0.9,
        ..white.clone()
    };
    let steps = 20_000;
    let mut rng = Rng::derive(7, 4);
    let mut noise = s.exploration_noise(&mut rng);
    let mut rows = Vec::with_capacity(steps);
    for _ in 0..steps {
        let mut e = [0.0f32; ACT_DIM];
        noise.draw(&mut rng, &mut e);
        rows.push(e);
    }
    for j in [0, ACT_DIM - 1] {
        let x: Vec<f64> = rows.iter().map(|r| f64::from(r[j])).collect();
        let var = x.iter().map(|v| v * v).sum::<f64>() / steps as f64;
        let cov = x.windows(2).map(|w| w[0] * w[1]).sum::<f64>() / (steps - 1) as f64;
        let sd = f64::from(s.sigma(j));
        assert!(
            (var.sqrt() - sd).abs() < 0.1 * sd,
            "joint {j}: spread {}",
            var.sqrt()
        );
        assert!(
            (cov / var - 0.9).abs() < 0.03,
            "joint {j}: lag one {}",
            cov / var
        );
    }
    for bad in [-0.1f32, 1.0, f32::NAN] {
        let s = GroupPg {
            noise_correlation: bad,
            ..white.clone()
        };
        assert!(
            matches!(s.validate(), Err(GroupPgError::Settings(m)) if m.contains("noise_correlation")),
            "noise_correlation {bad} accepted"
        );
    }
}
