//! The learning check CI runs: `trainer train` learns the Jaco Reach task from a fixed seed,
//! measured on the exported policy file through the controller's runtime (50 random starts, CAN
//! quantisation on). Uses the tuned configuration `experiments/reach-g90-ln-clr1e-3.toml` (60k
//! transitions; 180 s in CI on 2 cores since the test profile builds dependencies like release, see
//! docs/benchmarks.md). Seed 0's exported file (the best checkpoint on the selection starts) scores
//! 43/50 = 86% on the Intel machine with AVX-512 the earlier sessions ran on (one worker, fixed
//! seed: deterministic for a given CPU); seeds 0-2 give 82.5-87.5% over 200 episodes there. On an
//! AMD EPYC without AVX-512 (session 4) the GEMM kernels round differently, training takes another
//! path and seed 0 scores 39/50 = 78%. The assertion is 70% so the check stays meaningful (an
//! untrained actor scores 0%) on either CPU without resting on one lucky episode count.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::process::Command;

#[test]
fn trainer_learns_reach() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
    let out = std::env::temp_dir().join(format!("dex-learn-reach-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let status = Command::new(env!("CARGO_BIN_EXE_trainer"))
        .current_dir(root)
        .args([
            "train",
            "--config",
            "experiments/reach-g90-ln-clr1e-3.toml",
            "--seeds",
            "0",
            "--final-eval-episodes",
            "50",
            "--quiet",
            "--out",
        ])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("seed-0/final_eval.json")).unwrap())
            .unwrap();
    let rate = summary["success_rate"].as_f64().unwrap();
    assert_eq!(summary["episodes"].as_u64(), Some(50));
    let policy = std::fs::read(out.join("seed-0/policy.dxpl")).unwrap();
    let aligned = dex_runtime::testkit::aligned_copy(&policy);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes()).unwrap();
    assert_eq!(view.body().provenance.success_rate, Some(rate as f32));
    assert!(out.join("return.png").exists() && out.join("success.svg").exists());
    let _ = std::fs::remove_dir_all(&out);
    assert!(rate >= 0.7, "Reach success {rate} < 0.7");
}
