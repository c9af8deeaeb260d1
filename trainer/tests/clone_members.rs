//! The clone stage with members (`[[clone.members]]`) at toy size: the member clones side by side,
//! their distillation, and the fine-tune from the distilled file (guarded against it); a resumed
//! finished run redoes nothing; runs killed (SIGKILL) during the members and during the
//! distillation resume to the same files as an uninterrupted run, and so does a run of one member
//! at a time; changed members on resume are refused before any work (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant, SystemTime};

mod common;
use common::{fresh_path, text, trainer};

const CONFIG: &str = r#"
task = "reach"
seeds = [1]
transitions = 300
checkpoint_every = 150
final_eval_episodes = 3
select_best_episodes = 3
guard_episodes = 4
features = true
record_demos = 4

[clone]
demo_episodes = 4
dart_episodes = 4
bc_steps = 200
select_episodes = 3
distil_episodes_per_round = 2

[[clone.members]]
name = "a"
seeds = [0, 1]

[[clone.members]]
name = "b"
seeds = [0]
close_bursts = 0.02

[run]
updates_per_step = 1
critic_warmup_updates = 100

[run.ddpg]
actor_hidden = [32, 32]

[run.demos]
fraction = 0.25
bc_weight = 5.0
q_filter = false
"#;

/// The member runs' folders, in the order of the teacher's mean.
const MEMBERS: [&str; 3] = ["a-s0", "a-s1", "b-s0"];

/// `trainer train --config CONFIG --quiet --out OUT EXTRA` as arguments.
fn args(config: &Path, out: &Path, extra: &[&str]) -> Vec<String> {
    let mut v: Vec<String> = ["train", "--config", config.to_str().unwrap(), "--quiet"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    v.extend(["--out".to_string(), out.to_str().unwrap().to_string()]);
    v.extend(extra.iter().map(|s| s.to_string()));
    v
}

fn run(config: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let a = args(config, out, extra);
    trainer(&a.iter().map(String::as_str).collect::<Vec<_>>())
}

/// Every file under `dir` but the run locks, with its modification time.
fn files(dir: &Path) -> BTreeMap<PathBuf, SystemTime> {
    let mut all = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let e = e.unwrap();
            let p = e.path();
            if p.is_dir() {
                todo.push(p);
            } else if e.file_name() != ".lock" {
                all.insert(p, e.metadata().unwrap().modified().unwrap());
            }
        }
    }
    all
}

/// The clone stage's policy files of run folder `out`, by path under it.
fn stage_policies(out: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    files(&out.join("clone"))
        .into_keys()
        .filter(|p| p.extension().is_some_and(|e| e == "dxpl"))
        .map(|p| {
            (
                p.strip_prefix(out).unwrap().to_path_buf(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect()
}

/// Starts the run in the background and kills it (SIGKILL) once `marker` exists; false if the run
/// ended first.
fn kill_when(config: &Path, out: &Path, marker: &Path) -> bool {
    let mut child = Command::new(env!("CARGO_BIN_EXE_trainer"))
        .args(args(config, out, &["--resume"]))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            return false;
        }
        if marker.exists() {
            child.kill().unwrap();
            child.wait().unwrap();
            return true;
        }
        assert!(started.elapsed() < Duration::from_secs(300), "run hangs");
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
fn members_are_distilled_the_fine_tune_starts_from_it_and_every_stage_resumes() {
    let dir = fresh_path("clone-members", "run");
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("run.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let out = dir.join("a");

    let o = run(&config, &out, &[]);
    let log = text(&o);
    assert!(o.status.success(), "{log}");
    let stage = out.join("clone/seed-1");
    for m in MEMBERS {
        assert!(stage.join(m).join("policy.dxpl").exists(), "{m}: {log}");
        assert!(log.contains(&format!("member {m} done")), "{log}");
    }
    assert!(log.contains("3 member clones, 2 at a time"), "{log}");
    let distilled = stage.join("distil/policy-1.dxpl");
    assert!(distilled.exists(), "{log}");
    // The members keep their tweaks; the distillation is taught by their files, in order.
    let member: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(stage.join("b-s0/settings.json")).unwrap())
            .unwrap();
    assert_eq!(
        (member["seed"].as_u64(), member["eval_threads"].as_u64()),
        (Some(0), Some(1))
    );
    assert!((member["close_bursts"].as_f64().unwrap() - 0.02).abs() < 1e-6);
    let distil: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(stage.join("distil/settings.json")).unwrap())
            .unwrap();
    let teachers: Vec<PathBuf> = distil["teacher_policies"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| PathBuf::from(t.as_str().unwrap()))
        .collect();
    let abs = std::fs::canonicalize(&stage).unwrap();
    let want: Vec<PathBuf> = MEMBERS
        .iter()
        .map(|m| abs.join(m).join("policy.dxpl"))
        .collect();
    assert_eq!(teachers, want);
    assert_eq!(
        (distil["seed"].as_u64(), distil["rounds"].as_u64()),
        (Some(1), Some(1))
    );
    // The fine-tune starts from the distilled file and is guarded against it.
    let seed = std::fs::read_to_string(out.join("seed-1/settings.toml")).unwrap();
    assert!(
        seed.contains("clone/seed-1/distil/policy-1.dxpl") && !seed.contains("[clone]"),
        "{seed}"
    );
    let guard: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("seed-1/guard.json")).unwrap())
            .unwrap();
    assert_eq!(
        PathBuf::from(guard["init_policy"].as_str().unwrap()),
        distilled
    );
    assert!(out.join("seed-1/policy.dxpl").exists(), "{log}");

    // Resumed when finished: the clone stage redoes nothing and rewrites no file.
    let before = files(&out.join("clone"));
    let o = run(&config, &out, &["--resume"]);
    let log = text(&o);
    assert!(o.status.success(), "{log}");
    assert!(
        !log.contains("recording") && !log.contains(": 200 cloning steps"),
        "work was done again: {log}"
    );
    assert_eq!(files(&out.join("clone")), before);

    // Killed during the members, then during the distillation: the resumed run makes the files
    // of the uninterrupted one, bit for bit, and keeps the members it had finished.
    let killed = dir.join("b");
    let stage_b = killed.join("clone/seed-1");
    assert!(kill_when(
        &config,
        &killed,
        &stage_b.join("a-s0/settings.json")
    ));
    let first = stage_b.join("a-s0/policy.dxpl");
    assert!(kill_when(
        &config,
        &killed,
        &stage_b.join("distil/settings.json")
    ));
    assert!(first.exists());
    let kept = std::fs::metadata(&first).unwrap().modified().unwrap();
    let o = run(&config, &killed, &["--resume"]);
    let log = text(&o);
    assert!(o.status.success(), "{log}");
    assert_eq!(std::fs::metadata(&first).unwrap().modified().unwrap(), kept);
    assert_eq!(stage_policies(&killed), stage_policies(&out));

    // One member at a time (one evaluation thread in all): the same files.
    let serial_config = dir.join("serial.toml");
    std::fs::write(&serial_config, format!("eval_threads = 1\n{CONFIG}")).unwrap();
    let serial = dir.join("c");
    let o = run(&serial_config, &serial, &[]);
    let log = text(&o);
    assert!(o.status.success() && log.contains("1 at a time"), "{log}");
    assert_eq!(stage_policies(&serial), stage_policies(&out));

    // Changed members are refused on resume before any work: a member's tweak (its own folder
    // differs), or another member (the distillation's teachers differ; the new member's run does
    // not start).
    let before = files(&out.join("clone"));
    for changed in [
        CONFIG.replace("close_bursts = 0.02", "close_bursts = 0.03"),
        CONFIG.replace(
            "\n[run]\n",
            "\n[[clone.members]]\nname = \"c\"\nseeds = [0]\n\n[run]\n",
        ),
    ] {
        let changed_config = dir.join("changed.toml");
        std::fs::write(&changed_config, changed).unwrap();
        let o = run(&changed_config, &out, &["--resume"]);
        let log = text(&o);
        assert!(!o.status.success(), "{log}");
        assert!(
            log.contains("clone stage in") && log.contains("holds a run with other settings"),
            "{log}"
        );
        assert!(!stage.join("c-s0").exists(), "{log}");
        assert_eq!(files(&out.join("clone")), before);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
