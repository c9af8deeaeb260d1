//! Latency percentiles (p50/p99/max) of the forward pass of the 48-256-256-9 MLP and of one whole
//! control step (15 observation frames in, 44-256-256-9 forward pass, 3 action frames out), the
//! step with the safety envelope off and then with the Jaco envelope (random observations: it
//! limits in every cycle, and from the 21st cycle on also sends emergency 0xFF10 once), as
//! `benches/control_step.rs` does.
//! `cargo run --release -p dex-runtime --example latency [-- ITERATIONS]`

use std::time::Instant;

use dex_policy::PolicyView;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{
    ACTION_FRAMES, NmtCommand, OBS_FRAMES, action_frame_index, encode_observation, nmt_frame,
};
use dex_runtime::envelope::EnvelopeConfig;
use dex_runtime::interface::ACT_DIM;
use dex_runtime::testkit::{aligned_copy, jaco_policy, mlp_48_256_256_9, observation_trace};
use dex_runtime::{Controller, ControllerConfig, Mlp, MockClock};

fn report(name: &str, mut ns: Vec<u64>) {
    ns.sort_unstable();
    let pick = |q: f64| ns[((ns.len() as f64 - 1.0) * q) as usize] as f64 / 1000.0;
    println!(
        "{name:<28} n={:<8} p50 {:>7.2} us  p99 {:>7.2} us  max {:>8.2} us",
        ns.len(),
        pick(0.5),
        pick(0.99),
        pick(1.0)
    );
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let n: usize = std::env::args().nth(1).map_or(Ok(100_000), |a| a.parse())?;
    let file = aligned_copy(&mlp_48_256_256_9()?);
    let view = PolicyView::decode(file.as_bytes())?;
    let mut mlp = Mlp::<256>::new(&view)?;
    let obs: Vec<f32> = (0..48).map(|i| (i as f32 * 0.37).sin()).collect();
    let mut out = [0.0f32; ACT_DIM];
    let mut samples = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        mlp.act(std::hint::black_box(&obs), &mut out)?;
        samples.push(t.elapsed().as_nanos() as u64);
    }
    std::hint::black_box(out);
    report("forward 48-256-256-9", samples);

    for (name, envelope) in [
        ("control step 44-256-256-9", EnvelopeConfig::disabled()),
        ("control step + envelope", EnvelopeConfig::jaco()),
    ] {
        report(name, control_steps(n, envelope)?);
    }
    Ok(())
}

/// Nanoseconds of each of `n` control steps with the given envelope.
fn control_steps(
    n: usize,
    envelope: EnvelopeConfig,
) -> Result<Vec<u64>, Box<dyn std::error::Error>> {
    let file = aligned_copy(&jaco_policy(&[256, 256], 1)?);
    let view = PolicyView::decode(file.as_bytes())?;
    let clock = MockClock::new(0);
    let cfg = ControllerConfig {
        envelope,
        ..ControllerConfig::default()
    };
    let mut controller = Controller::<256>::new(cfg);
    controller.poll(&clock);
    controller.load_policy(&view)?;
    controller.on_frame(&nmt_frame(NmtCommand::Start, 0), &clock);
    let trace = observation_trace(16, 3);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let mut samples = Vec::with_capacity(n);
    let node = ControllerConfig::default().node_id;
    for i in 0..n {
        let frames = encode_observation(
            ControllerConfig::default().node_id,
            &trace[i % 16],
            i as u8,
            &mut tx,
        );
        let t = Instant::now();
        let mut sent = 0;
        for f in &frames {
            let out = controller.on_frame(f, &clock);
            sent += out
                .iter()
                .filter(|f| {
                    f.standard_id()
                        .is_some_and(|id| action_frame_index(node, id).is_some())
                })
                .count();
        }
        samples.push(t.elapsed().as_nanos() as u64);
        if sent != ACTION_FRAMES {
            return Err(
                format!("step {i}: expected {ACTION_FRAMES} action frames, got {sent}").into(),
            );
        }
    }
    Ok(samples)
}
