//! `trainer compare`: policy files and the teacher on the same starts, every pair's McNemar test,
//! the JSON report; files of different tasks are refused (needs MuJoCo).

#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;
use common::{REACH_FIXTURE, fresh_path, text, trainer};

const INT8: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/fixtures/reach_int8_seed0.dxpl"
);

#[test]
fn compare_runs_every_entry_on_the_same_starts_and_tests_every_pair() {
    let dir = fresh_path("compare", "reach");
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("compare.json");
    let o = trainer(&[
        "compare",
        "--teacher",
        REACH_FIXTURE,
        INT8,
        "--episodes",
        "12",
        "--seed",
        "9000000",
        "--threads",
        "2",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let entries = r["entries"].as_array().unwrap();
    assert_eq!(entries.len(), 3);
    assert!(entries[0]["name"].as_str().unwrap().starts_with("teacher"));
    let successes: Vec<u64> = entries
        .iter()
        .map(|e| e["successes"].as_u64().unwrap())
        .collect();
    // Each entry lists the starts it failed, as many as its failures, in order.
    for e in entries {
        let failed: Vec<u64> = e["failed_starts"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i.as_u64().unwrap())
            .collect();
        assert_eq!(failed.len() as u64, 12 - e["successes"].as_u64().unwrap());
        assert!(failed.windows(2).all(|w| w[0] < w[1]) && failed.iter().all(|&i| i < 12));
    }
    // The file's own count is what `trainer eval` reports on the same starts.
    let eval = trainer(&[
        "eval",
        REACH_FIXTURE,
        "--episodes",
        "12",
        "--seed",
        "9000000",
    ]);
    assert!(
        text(&eval).contains(&format!("success {}/12", successes[1])),
        "{}",
        text(&eval)
    );
    // Three pairs (teacher-f32, teacher-int8, f32-int8), each consistent with the entries' counts.
    let pairs = r["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 3);
    for (pair, (a, b)) in pairs.iter().zip([(0, 1), (0, 2), (1, 2)]) {
        let p = &pair["paired"];
        assert_eq!(p["a_successes"].as_u64().unwrap(), successes[a]);
        assert_eq!(p["b_successes"].as_u64().unwrap(), successes[b]);
        assert_eq!(
            successes[a] - p["only_a"].as_u64().unwrap(),
            successes[b] - p["only_b"].as_u64().unwrap(),
            "the starts both solve"
        );
        let pv = p["p_value"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&pv));
    }
    assert!(text(&o).contains("McNemar p ="), "{}", text(&o));
    // Files of two tasks are refused before any episode runs.
    let stack = concat!(env!("CARGO_MANIFEST_DIR"), "/../policies/stack.dxpl");
    let o = trainer(&["compare", REACH_FIXTURE, stack, "--episodes", "2"]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("compare policies of one task"),
        "{}",
        text(&o)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_ensemble_of_one_file_is_that_file_and_mixed_tasks_are_refused() {
    let dir = fresh_path("compare", "ensemble");
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("compare.json");
    let pair = format!("{REACH_FIXTURE},{INT8}");
    let o = trainer(&[
        "compare",
        REACH_FIXTURE,
        "--ensemble",
        REACH_FIXTURE,
        "--ensemble",
        &pair,
        "--episodes",
        "12",
        "--seed",
        "9000000",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let entries = r["entries"].as_array().unwrap();
    assert_eq!(entries.len(), 3);
    assert!(
        entries[1]["name"]
            .as_str()
            .unwrap()
            .starts_with("ensemble of 1"),
        "{}",
        entries[1]["name"]
    );
    assert!(
        entries[2]["name"]
            .as_str()
            .unwrap()
            .starts_with("ensemble of 2")
    );
    // The one-file ensemble takes the controller's path exactly: the same start-by-start outcome.
    let p = &r["pairs"].as_array().unwrap()[0]["paired"];
    assert_eq!(
        (p["only_a"].as_u64(), p["only_b"].as_u64()),
        (Some(0), Some(0))
    );
    assert_eq!(entries[0]["successes"], entries[1]["successes"]);
    // An ensemble of two tasks is refused before any episode runs.
    let stack = concat!(env!("CARGO_MANIFEST_DIR"), "/../policies/stack.dxpl");
    let mixed = format!("{REACH_FIXTURE},{stack}");
    let o = trainer(&["compare", "--ensemble", &mixed, "--episodes", "2"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("one task"), "{}", text(&o));
}

#[test]
fn pool_adds_chunks_of_disjoint_starts_and_refuses_shared_ones() {
    let dir = fresh_path("compare", "pool");
    std::fs::create_dir_all(&dir).unwrap();
    let chunk = |seed: &str| {
        let json = dir.join(format!("chunk-{seed}.json"));
        let o = trainer(&[
            "compare",
            REACH_FIXTURE,
            INT8,
            "--episodes",
            "8",
            "--seed",
            seed,
            "--json",
            json.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", text(&o));
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        (json, r)
    };
    let (a, ra) = chunk("9000000");
    let (b, rb) = chunk("9000500");
    // Each file's entry carries its hash, so that pooled chunks are of the same files.
    let sha = dex_trainer::files::result_record::sha256_hex(&std::fs::read(INT8).unwrap());
    assert_eq!(ra["entries"][1]["sha256"].as_str(), Some(sha.as_str()));
    let pooled = dir.join("pooled.json");
    let o = trainer(&[
        "pool",
        a.to_str().unwrap(),
        b.to_str().unwrap(),
        "--json",
        pooled.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(text(&o).contains("16 starts in 2 chunks"), "{}", text(&o));
    let p: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&pooled).unwrap()).unwrap();
    assert_eq!(p["episodes"].as_u64(), Some(16));
    for k in 0..2 {
        let sum = ra["entries"][k]["successes"].as_u64().unwrap()
            + rb["entries"][k]["successes"].as_u64().unwrap();
        assert_eq!(p["entries"][k]["successes"].as_u64(), Some(sum));
    }
    for field in ["only_a", "only_b"] {
        let sum = ra["pairs"][0]["paired"][field].as_u64().unwrap()
            + rb["pairs"][0]["paired"][field].as_u64().unwrap();
        assert_eq!(p["pairs"][0]["paired"][field].as_u64(), Some(sum));
    }
    // The same chunk twice is the same starts twice: refused, and nothing is written.
    let again = dir.join("again.json");
    let o = trainer(&[
        "pool",
        a.to_str().unwrap(),
        a.to_str().unwrap(),
        "--json",
        again.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("share starts"), "{}", text(&o));
    assert!(!again.exists());
    // One record is not a pool; a file that is not a record is named.
    let o = trainer(&["pool", a.to_str().unwrap()]);
    assert!(!o.status.success());
    let o = trainer(&["pool", a.to_str().unwrap(), INT8]);
    assert!(!o.status.success());
    assert!(text(&o).contains("reach_int8_seed0.dxpl"), "{}", text(&o));
    let _ = std::fs::remove_dir_all(&dir);
}
