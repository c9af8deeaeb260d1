//! Criterion benchmarks: the forward pass of the 48-256-256-9 MLP alone, and one whole control
//! step (15 observation frames decoded and checked, 44-256-256-9 forward pass, 3 action frames
//! encoded), and the int8 forward pass of the cell's 44-256-256-9 network.
//! `cargo bench -p dex-runtime --bench control_step`
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)] // benchmark harness

use criterion::{Criterion, black_box, criterion_group, criterion_main};
use dex_policy::PolicyView;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{NmtCommand, OBS_FRAMES, encode_observation, nmt_frame};
use dex_runtime::interface::ACT_DIM;
use dex_runtime::testkit::{
    aligned_copy, jaco_policy, jaco_policy_int8, mlp_48_256_256_9, observation_trace,
};
use dex_runtime::{Controller, ControllerConfig, Mlp, MockClock};

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
    let file = aligned_copy(&jaco_policy(&[256, 256], 1).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let clock = MockClock::new(0);
    let mut controller = Controller::<256>::new(ControllerConfig::default());
    controller.poll(&clock);
    controller.load_policy(&view).unwrap();
    controller.on_frame(&nmt_frame(NmtCommand::Start, 0), &clock);
    let trace = observation_trace(16, 3);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    // Frames are prepared outside the timed loop: the plant makes them, not the controller.
    let cycles: Vec<_> = (0..240u32)
        .map(|n| encode_observation(&trace[n as usize % 16], n as u8, &mut tx))
        .collect();
    let mut n = 0usize;
    c.bench_function("control_step_44_256_256_9", |b| {
        b.iter(|| {
            let frames = &cycles[n % cycles.len()];
            n += 1;
            let mut sent = 0;
            for f in frames {
                sent += controller.on_frame(black_box(f), &clock).len();
            }
            assert_eq!(sent, 3);
        })
    });
}

criterion_group!(benches, forward, forward_int8, control_step);
criterion_main!(benches);
