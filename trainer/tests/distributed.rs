//! `trainer train --distributed` under `mpirun` on loopback (feature `mpi`; needs Open MPI and
//! MuJoCo): three ranks learn the point-mass task and Reach; a worker rank killed (SIGKILL) or
//! stopped (SIGSTOP) mid-run ends the run with a fresh checkpoint and an error naming the rank,
//! and the run resumes from it with two ranks to the end.

#![cfg(feature = "mpi")]
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use dex_trainer::learn::Trainer;

/// One mpirun at a time: the four tests' three ranks each, run at once on two cores, starve the
/// ranks (a point-mass run then stops before it has learned); alone each takes seconds.
static ONE_JOB: Mutex<()> = Mutex::new(());

fn one_job() -> MutexGuard<'static, ()> {
    ONE_JOB
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// `mpirun` over loopback TCP with `np` ranks of the trainer binary. `keep_going`: a rank's
/// death does not tear the job down, so rank 0 sees it (docs/distributed.md, "Faults").
fn mpirun(np: usize, keep_going: bool, args: &[&str]) -> Command {
    let mut c = Command::new("mpirun");
    c.env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .args(["--oversubscribe", "--mca", "btl", "tcp,self"]);
    if keep_going {
        c.args(["--mca", "orte_abort_on_non_zero_status", "0"]);
    }
    c.args(["-np", &np.to_string(), env!("CARGO_BIN_EXE_trainer")])
        .args(args);
    c
}

mod common;
use common::text;

fn tmp(name: &str) -> PathBuf {
    common::fresh_path("distributed", name)
}

fn json(path: &Path) -> serde_json::Value {
    let t = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&t).unwrap()
}

#[test]
fn three_ranks_learn_point_mass() {
    let _one = one_job();
    let t0 = Instant::now();
    let o = mpirun(
        3,
        false,
        &["distributed-point-mass", "--transitions", "20000"],
    )
    .output()
    .unwrap();
    let log = text(&o);
    eprintln!(
        "{log}\npoint mass over 3 ranks: {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert!(o.status.success(), "{log}");
    let line = log
        .lines()
        .find(|l| l.contains("point mass over 3 ranks: success"))
        .expect("rank 0's result line");
    let field = |name: &str| -> f64 {
        line.split(name)
            .nth(1)
            .and_then(|r| r.split(',').next())
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{name} in {line}"))
    };
    let (last, best) = (field("ranks: success "), field("best in-training success "));
    // An actor that the exchanges never moved scores 0 here; one rank alone learns it to 1.0.
    // The in-training evaluations run on the worker ranks with their actors rebased on rank 0's
    // state, so a high one needs the exchanges. The final actor's figure is printed, not
    // asserted: an asynchronous run's last exchanges can still move it (10 runs under load:
    // nine at 0.97-1.0, one at 0.36 after evaluations at 1.0).
    assert!(
        best >= 0.9,
        "best in-training success {best} (final {last}): {line}"
    );
    // Each rank writes its counters line in one write (bin/trainer/distributed.rs,
    // `line_to_stderr`), so mpirun's forwarding cannot split it.
    for r in 1..3 {
        let l = log
            .lines()
            .find(|l| l.contains(&format!("rank {r}: ")) && l.contains("exchanges"))
            .expect("worker rank line");
        assert!(l.contains(" 0 refused"), "{l}");
        assert!(!l.contains(" 0 exchanges"), "{l}");
    }
}

#[test]
fn three_ranks_learn_reach() {
    let _one = one_job();
    let out = tmp("reach");
    let t0 = Instant::now();
    let o = mpirun(
        3,
        false,
        &[
            "train",
            "--distributed",
            "--config",
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../experiments/reach-ddpgfd.toml"
            ),
            "--transitions",
            "2000",
            "--checkpoint-every",
            "1000",
            "--record-demos",
            "30",
            "--pretrain-updates",
            "1500",
            "--select-best-episodes",
            "20",
            "--final-eval-episodes",
            "50",
            "--seeds",
            "0",
            "--quiet",
            "--out",
            out.to_str().unwrap(),
        ],
    )
    .output()
    .unwrap();
    let log = text(&o);
    eprintln!(
        "{log}\nreach over 3 ranks: {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert!(o.status.success(), "{log}");
    let seed = out.join("seed-0");
    // The run folder of a local run: policy, final evaluation, checkpoint, selection.
    for f in [
        "policy.dxpl",
        "checkpoint.bin",
        "best.json",
        "settings.toml",
    ] {
        assert!(seed.join(f).exists(), "{f} missing: {log}");
    }
    let fin = json(&seed.join("final_eval.json"));
    let rate = fin["success_rate"].as_f64().unwrap();
    // Measured 54% (27/50); an untrained actor scores 0%.
    assert!(rate >= 0.3, "Reach over 3 ranks: {rate}");
    let stats = json(&seed.join("distributed.json"));
    assert_eq!(stats["refused"], 0, "{stats}");
    assert!(stats["exchanges"].as_u64().unwrap() > 0, "{stats}");
    let t = Trainer::load(&seed.join("checkpoint.bin")).unwrap();
    assert!(t.progress().transitions >= 2000);
    // The result is the exchanges', not the pre-training's: rank 0 counts its 1,500 pre-training
    // updates and then only the updates the worker ranks pushed and it applied to the shared
    // parameters (measured: 549 over 26 exchanges). A run whose pushes were dropped or refused
    // would stop at 1,500, its actor the pre-trained one.
    let applied = t.progress().updates;
    assert!(
        applied >= 1500 + 100,
        "rank 0 applied {applied} updates, pre-training's 1,500 included: {stats}"
    );
    let _ = std::fs::remove_dir_all(&out);
}

/// The pid of the process with rank `rank` of the trainer job writing into `out`.
fn rank_pid(rank: usize, out: &str) -> Option<u32> {
    let want = format!("OMPI_COMM_WORLD_RANK={rank}");
    for e in std::fs::read_dir("/proc").ok()?.flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
        if !String::from_utf8_lossy(&cmd).contains(out) {
            continue;
        }
        let env = std::fs::read(e.path().join("environ")).unwrap_or_default();
        if env.split(|&b| b == 0).any(|v| v == want.as_bytes()) {
            return Some(pid);
        }
    }
    None
}

/// A spawned job whose stdout and stderr are read as they come, so a job that prints a lot (Open
/// MPI's reports of a lost peer, repeated per connection) never blocks on a full pipe. (Reading
/// them only after the job ended let a 64 KiB pipe fill while the test waited, and the job hung.)
struct Drained {
    child: Child,
    out: std::thread::JoinHandle<Vec<u8>>,
    err: std::thread::JoinHandle<Vec<u8>>,
}

impl Drained {
    fn spawn(mut c: Command) -> Self {
        use std::io::Read;
        let mut child = c
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut so = child.stdout.take().unwrap();
        let mut se = child.stderr.take().unwrap();
        let out = std::thread::spawn(move || {
            let mut b = Vec::new();
            let _ = so.read_to_end(&mut b);
            b
        });
        let err = std::thread::spawn(move || {
            let mut b = Vec::new();
            let _ = se.read_to_end(&mut b);
            b
        });
        Drained { child, out, err }
    }

    /// The exit status within `limit`, or None (the job is then killed).
    fn wait(&mut self, limit: Duration) -> Option<std::process::ExitStatus> {
        let t0 = Instant::now();
        while t0.elapsed() < limit {
            if let Some(s) = self.child.try_wait().unwrap() {
                return Some(s);
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let _ = self.child.kill();
        None
    }

    /// Everything the job printed (after it ended or was killed).
    fn log(self) -> String {
        let mut child = self.child;
        let _ = child.wait();
        format!(
            "{}{}",
            String::from_utf8_lossy(&self.out.join().unwrap()),
            String::from_utf8_lossy(&self.err.join().unwrap())
        )
    }
}

/// A run with `signal` sent to rank 2 after the first checkpoint: rank 0 must time it out,
/// write a checkpoint and fail naming rank 2; then two ranks resume it to the end.
fn lost_rank(name: &str, signal: &str) {
    let _one = one_job();
    let out = tmp(name);
    let out_s = out.to_str().unwrap().to_string();
    let common = [
        "train",
        "--distributed",
        "--task",
        "reach",
        "--preset",
        "paper",
        "--hidden",
        "64,64",
        "--checkpoint-every",
        "400",
        "--select-best-episodes",
        "0",
        "--final-eval-episodes",
        "10",
        "--seeds",
        "0",
        "--quiet",
        "--rank-timeout",
        "5",
        "--out",
        &out_s,
    ];
    let t0 = Instant::now();
    let mut job = mpirun(3, true, &common);
    job.args(["--transitions", "1000000"]);
    let mut child = Drained::spawn(job);
    let ckpt = out.join("seed-0/checkpoint.bin");
    let first = loop {
        if let Ok(m) = std::fs::metadata(&ckpt).and_then(|m| m.modified()) {
            break m;
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "no checkpoint");
        assert!(
            child.child.try_wait().unwrap().is_none(),
            "the run ended early"
        );
        std::thread::sleep(Duration::from_millis(100));
    };
    let before = Trainer::load(&ckpt).unwrap().progress().transitions;
    let pid = rank_pid(2, &out_s).expect("rank 2's process");
    let killed = Command::new("kill")
        .args([signal, &pid.to_string()])
        .status()
        .unwrap();
    assert!(killed.success());
    let status = child.wait(Duration::from_secs(90));
    let log = child.log();
    let status = status.unwrap_or_else(|| panic!("the run did not end: {log}"));
    eprintln!(
        "{log}\n{name}: {:.1} s to the failure",
        t0.elapsed().as_secs_f64()
    );
    assert!(!status.success(), "{log}");
    assert!(log.contains("worker rank 2 did not answer"), "{log}");
    let last = std::fs::metadata(&ckpt).unwrap().modified().unwrap();
    assert!(last > first, "no checkpoint written at the failure: {log}");
    let at = Trainer::load(&ckpt).unwrap().progress().transitions;
    assert!(at >= before, "{at} < {before}");
    // Two ranks (one worker rank) continue it to a budget beyond the checkpoint.
    let budget = (at + 300).to_string();
    let t1 = Instant::now();
    let o = mpirun(2, false, &common)
        .args(["--transitions", &budget, "--resume"])
        .output()
        .unwrap();
    let log = text(&o);
    eprintln!(
        "{log}\n{name}: resume with 2 ranks {:.1} s",
        t1.elapsed().as_secs_f64()
    );
    assert!(o.status.success(), "{log}");
    let fin = json(&out.join("seed-0/final_eval.json"));
    assert!(fin["transitions"].as_u64().unwrap() >= at + 300, "{fin}");
    assert!(out.join("seed-0/policy.dxpl").exists());
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn killed_rank_checkpoints_and_resumes_with_two_ranks() {
    lost_rank("kill", "-KILL");
}

#[test]
fn stopped_rank_times_out_checkpoints_and_resumes() {
    lost_rank("stop", "-STOP");
}
