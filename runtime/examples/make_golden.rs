//! Writes the runtime's golden files (host reference for every target, reused by the firmware
//! check): a random-weight 44-64-64-9 policy on the cell's layout, an observation trace and the
//! actions the evaluator produces, all little-endian f32; and the same policy quantised to int8
//! (format version 2) with its actions.
//!
//! `cargo run -p dex-runtime --example make_golden` — re-bless only on purpose and review the diff.

use std::path::Path;

use dex_policy::PolicyView;
use dex_runtime::interface::ACT_DIM;
use dex_runtime::mlp::Mlp;
use dex_runtime::testkit::{aligned_copy, jaco_policy, jaco_policy_int8, observation_trace};

/// Observations in the golden trace.
const TRACE_LEN: usize = 64;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden");
    std::fs::create_dir_all(&dir)?;
    let policy = jaco_policy(&[64, 64], 11)?;
    let aligned = aligned_copy(&policy);
    let view = PolicyView::decode(aligned.as_bytes())?;
    let mut mlp = Mlp::<64>::new(&view)?;
    let trace = observation_trace(TRACE_LEN, 5);
    let mut obs_bytes = Vec::new();
    let mut act_bytes = Vec::new();
    for obs in &trace {
        let mut action = [0.0f32; ACT_DIM];
        mlp.act(obs, &mut action)?;
        obs.iter().for_each(|v| obs_bytes.extend(v.to_le_bytes()));
        action
            .iter()
            .for_each(|v| act_bytes.extend(v.to_le_bytes()));
    }
    let policy_int8 = jaco_policy_int8(&[64, 64], 11)?;
    let aligned_int8 = aligned_copy(&policy_int8);
    let view_int8 = PolicyView::decode(aligned_int8.as_bytes())?;
    let mut mlp_int8 = Mlp::<64>::new(&view_int8)?;
    let mut act_int8_bytes = Vec::new();
    for obs in &trace {
        let mut action = [0.0f32; ACT_DIM];
        mlp_int8.act(obs, &mut action)?;
        action
            .iter()
            .for_each(|v| act_int8_bytes.extend(v.to_le_bytes()));
    }
    std::fs::write(dir.join("jaco_64_int8.dxpl"), &policy_int8)?;
    std::fs::write(dir.join("actions_64_int8.f32"), &act_int8_bytes)?;
    std::fs::write(dir.join("jaco_64.dxpl"), &policy)?;
    std::fs::write(dir.join("obs_trace.f32"), &obs_bytes)?;
    std::fs::write(dir.join("actions_64.f32"), &act_bytes)?;
    println!(
        "wrote golden policy ({} bytes), trace and actions to {}",
        policy.len(),
        dir.display()
    );
    Ok(())
}
