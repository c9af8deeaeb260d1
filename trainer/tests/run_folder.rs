//! One trainer per seed of a run folder, and `kill -9` at any moment loses nothing: a second
//! `trainer train` on a seed being trained is refused at once naming the holder's pid (another
//! seed of the same run, one job per core, is not); a run killed 20 times at random
//! moments and resumed each time ends with the log and the exported policy of an uninterrupted run
//! (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn trainer_cmd(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_trainer"));
    c.args(args).stdout(Stdio::null()).stderr(Stdio::piped());
    c
}

mod common;
use common::{text, trainer as output};

fn tmp(name: &str) -> PathBuf {
    let d = common::fresh_path("run-folder", name);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A small Reach run: tiny networks, an evaluation every 4 episodes, a checkpoint every 200
/// transitions, no selection.
fn config(dir: &Path, transitions: u64) -> PathBuf {
    let path = dir.join("run.toml");
    std::fs::write(
        &path,
        format!(
            "task = \"reach\"\ntransitions = {transitions}\ncheckpoint_every = 200\n\
             final_eval_episodes = 2\nselect_best_episodes = 0\neval_threads = 1\n\
             [run]\nlearning_starts = 200\n[run.eval]\nevery_episodes = 4\nepisodes = 2\n\
             [run.ddpg]\nactor_hidden = [16, 16]\ncritic_hidden = [16, 16]\n"
        ),
    )
    .unwrap();
    path
}

fn spawn(cfg: &Path, out: &Path, resume: bool) -> Child {
    let mut args = vec![
        "train",
        "--config",
        cfg.to_str().unwrap(),
        "--quiet",
        "--out",
        out.to_str().unwrap(),
    ];
    if resume {
        args.push("--resume");
    }
    trainer_cmd(&args).spawn().expect("spawn trainer")
}

/// The evaluation records without their wall-clock times.
fn records(out: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(out.join("seed-0/eval.jsonl")).unwrap();
    text.lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            v.as_object_mut().unwrap().remove("wall_s");
            v
        })
        .collect()
}

/// Waits until `child` holds the run lock `lock` (its pid is in the file): the event that says it
/// was not refused. Fails if it exits first or takes more than a minute.
fn holds_lock(child: &mut std::process::Child, lock: &Path, who: &str) {
    let pid = child.id().to_string();
    let t0 = Instant::now();
    while std::fs::read_to_string(lock).map_or(true, |s| s.trim() != pid) {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("{who} ended ({status}) without taking {}", lock.display());
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{who}: no lock taken"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_second_trainer_on_a_busy_run_folder_is_refused_at_once() {
    let dir = tmp("lock");
    let cfg = config(&dir, 1_000_000);
    let out = dir.join("run");
    let mut first = spawn(&cfg, &out, false);
    // Wait until the first holds the lock (it writes its pid into the lock file).
    let lock = out.join("seed-0/.lock");
    holds_lock(&mut first, &lock, "the first run");
    let args = [
        "train",
        "--config",
        cfg.to_str().unwrap(),
        "--quiet",
        "--resume",
        "--out",
        out.to_str().unwrap(),
    ];
    let started = Instant::now();
    let second = output(&args);
    let msg = text(&second);
    assert!(!second.status.success(), "{msg}");
    assert!(
        msg.contains("in use") && msg.contains(&format!("pid {}", first.id())),
        "{msg}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "refused at once"
    );
    // Another seed of the same run (one job per core) is not refused.
    let mut other_seed = trainer_cmd(&[
        "train",
        "--config",
        cfg.to_str().unwrap(),
        "--quiet",
        "--seeds",
        "1",
        "--out",
        out.to_str().unwrap(),
    ])
    .spawn()
    .expect("spawn trainer");
    holds_lock(
        &mut other_seed,
        &out.join("seed-1/.lock"),
        "a job on another seed of the run",
    );
    other_seed.kill().unwrap();
    other_seed.wait().unwrap();
    // kill -9 leaves no stale lock: the next run takes the folder.
    first.kill().unwrap();
    first.wait().unwrap();
    let mut third = spawn(&cfg, &out, true);
    holds_lock(&mut third, &lock, "the resumed run after kill -9");
    third.kill().unwrap();
    third.wait().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn twenty_kills_at_random_moments_leave_the_log_and_policy_of_an_uninterrupted_run() {
    let dir = tmp("kill");
    let cfg = config(&dir, 3_000);
    let whole = dir.join("whole");
    let status = spawn(&cfg, &whole, false).wait().unwrap();
    assert!(status.success());
    let killed = dir.join("killed");
    // Kill moments from a fixed generator (reproducible), 0.2-1.5 s after each start.
    let mut rng = dex_policy::synth::SplitMix64::new(1);
    let mut kills = 0;
    let mut resume = false;
    while kills < 20 {
        let mut child = spawn(&cfg, &killed, resume);
        std::thread::sleep(Duration::from_millis(200 + rng.next_u64() % 1300));
        if child.try_wait().unwrap().is_some() {
            break; // finished before the kill: nothing left to interrupt
        }
        child.kill().unwrap();
        child.wait().unwrap();
        kills += 1;
        resume = true;
    }
    let finish = output(&[
        "train",
        "--config",
        cfg.to_str().unwrap(),
        "--quiet",
        "--resume",
        "--out",
        killed.to_str().unwrap(),
    ]);
    assert!(finish.status.success(), "{}", text(&finish));
    assert!(kills >= 5, "only {kills} kills landed inside the run");
    let (a, b) = (records(&whole), records(&killed));
    assert_eq!(
        a.len(),
        b.len(),
        "{kills} kills: evaluation records differ in number"
    );
    assert_eq!(a, b, "{kills} kills: evaluation records differ");
    let pa = std::fs::read(whole.join("seed-0/policy.dxpl")).unwrap();
    let pb = std::fs::read(killed.join("seed-0/policy.dxpl")).unwrap();
    assert_eq!(pa, pb, "the exported policies differ");
    for plot in ["success.svg", "return.png"] {
        assert!(killed.join(plot).exists(), "{plot} missing");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
