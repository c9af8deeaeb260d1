//! Unit tests of the fine-tune's pieces: the report line, the starts, the pools.

use std::path::PathBuf;

use super::rollouts::{Episode, HARD_STARTS};
use super::*;

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
    };
    let plain = r.line(8);
    assert!(
        plain.starts_with("iteration 1 success 82/160 with noise"),
        "{plain}"
    );
    assert!(!plain.contains("from stalls"), "{plain}");
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
        stall: None,
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
