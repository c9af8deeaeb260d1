//! Criterion benchmarks: the forward pass of the 48-256-256-9 MLP alone, and one whole control
//! step (15 observation frames decoded and checked, 44-256-256-9 forward pass, 3 action frames
//! encoded), and the int8 forward pass of the cell's 44-256-256-9 network.
//!
//! The control step is measured twice: `control_step_44_256_256_9` with the safety envelope off
//! (exactly the work above), and `control_step_envelope_44_256_256_9` with the Jaco envelope
//! (`EnvelopeConfig::jaco`, the default). The observations are random, so the envelope limits in
//! every cycle: its longest path (acceleration turn, position bisection). From the 21st limited
//! cycle on the envelope's run is "sustained": that cycle also sends emergency 0xFF10 after the
//! action frames, once.
//!
//! `cargo bench -p dex-runtime --bench control_step`; `-- --test` runs each benchmark once (no
//! timing), `-- --quick` times with fewer samples, `-- control_step` selects by name.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)] // benchmark harness

use criterion::{Criterion, black_box, criterion_group, criterion_main};
use dex_policy::PolicyView;
use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{
    ACTION_FRAMES, NmtCommand, OBS_FRAMES, action_frame_index, encode_observation, nmt_frame,
};
use dex_runtime::envelope::EnvelopeConfig;
use dex_runtime::interface::ACT_DIM;
use dex_runtime::testkit::{
    aligned_copy, jaco_policy, jaco_policy_int8, mlp_48_256_256_9, observation_trace,
};
use dex_runtime::{Controller, ControllerConfig, Mlp, MockClock, State};

fn forward(c: &mut Criterion) {
    let file = aligned_copy(&mlp_48_256_256_9().unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut mlp = Mlp::<256>::new(&view).unwrap();
    let obs: Vec<f32> = (0..48).map(|i| (i as f32 * 0.37).sin()).collect();
    let mut action = [0.0f32; ACT_DIM];
    c.bench_function("forward_48_256_256_9", |b| {
        b.iter(|| {
            mlp.act(black_box(&obs), &mut action).unwrap();
            black_box(&action);
        })
    });
}

fn forward_int8(c: &mut Criterion) {
    for (name, file) in [
        (
            "forward_f32_44_256_256_9",
            jaco_policy(&[256, 256], 1).unwrap(),
        ),
        (
            "forward_int8_44_256_256_9",
            jaco_policy_int8(&[256, 256], 1).unwrap(),
        ),
    ] {
        let file = aligned_copy(&file);
        let view = PolicyView::decode(file.as_bytes()).unwrap();
        let mut mlp = Mlp::<256>::new(&view).unwrap();
        let obs = observation_trace(1, 3)[0];
        let mut action = [0.0f32; ACT_DIM];
        c.bench_function(name, |b| {
            b.iter(|| {
                mlp.act(black_box(&obs), &mut action).unwrap();
                black_box(&action);
            })
        });
    }
}

fn control_step(c: &mut Criterion) {
    for (name, envelope) in [
        ("control_step_44_256_256_9", EnvelopeConfig::disabled()),
        ("control_step_envelope_44_256_256_9", EnvelopeConfig::jaco()),
    ] {
        control_step_with(c, name, envelope);
    }
}

/// Action frames among the frames a step sent.
fn action_frames(out: &[CanFrame]) -> usize {
    let node = ControllerConfig::default().node_id;
    out.iter()
        .filter(|f| {
            f.standard_id()
                .is_some_and(|id| action_frame_index(node, id).is_some())
        })
        .count()
}

fn control_step_with(c: &mut Criterion, name: &str, envelope: EnvelopeConfig) {
    let file = aligned_copy(&jaco_policy(&[256, 256], 1).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let clock = MockClock::new(0);
    let cfg = ControllerConfig {
        envelope,
        ..ControllerConfig::default()
    };
    let mut controller = Controller::<256>::new(cfg);
    controller.poll(&clock);
    controller.load_policy(&view).unwrap();
    controller.on_frame(&nmt_frame(NmtCommand::Start, 0), &clock);
    assert_eq!(controller.state(), State::Operational);
    let trace = observation_trace(16, 3);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    // Frames are prepared outside the timed loop: the plant makes them, not the controller.
    let cycles: Vec<_> = (0..240u32)
        .map(|n| {
            encode_observation(
                ControllerConfig::default().node_id,
                &trace[n as usize % 16],
                n as u8,
                &mut tx,
            )
        })
        .collect();
    let mut n = 0usize;
    let mut others = 0usize;
    c.bench_function(name, |b| {
        b.iter(|| {
            let frames = &cycles[n % cycles.len()];
            n += 1;
            let mut actions = 0;
            for f in frames {
                let out = controller.on_frame(black_box(f), &clock);
                let a = action_frames(&out);
                actions += a;
                others += out.len() - a;
            }
            assert_eq!(actions, ACTION_FRAMES, "cycle {n}");
        })
    });
    // One evaluation per cycle, and nothing else on the bus but the envelope's emergency.
    assert_eq!(controller.state(), State::Operational);
    assert_eq!(controller.diagnostics().evaluations, n as u64);
    let emergencies = controller.envelope_stats().sustained_events;
    assert_eq!(others as u64, emergencies, "frames other than actions");
}

criterion_group!(benches, forward, forward_int8, control_step);
criterion_main!(benches);
