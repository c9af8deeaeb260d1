//! The int8 evaluator (format version 2 files): committed goldens bit for bit (the host half of the
//! firmware's bit-exactness check), an independent integer reference, the error against f32, the
//! controller running int8 files, and capacity.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::{Activation, CapacityItem, FormatError, LayerDtype, PolicyView, int8};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::mlp::Mlp;
use dex_runtime::testkit::{
    aligned_copy, f32s_le, jaco_policy, jaco_policy_int8, observation_trace,
};
use dex_runtime::{Controller, ControllerConfig, MockClock, State};

const POLICY_INT8: &[u8] = include_bytes!("golden/jaco_64_int8.dxpl");
const TRACE: &[u8] = include_bytes!("golden/obs_trace.f32");
const ACTIONS_INT8: &[u8] = include_bytes!("golden/actions_64_int8.f32");

/// W8A16 written out plainly from the format's definition (i64 sums over `byte_index`), with
/// the same f32 operations as the runtime in the same order: must give the same bits.
fn reference(view: &PolicyView<'_>, obs: &[f32]) -> Vec<f32> {
    let v = view.values();
    let body = view.body();
    let n = body.obs_dim();
    let mut x: Vec<f32> = (0..n)
        .map(|i| {
            ((obs[i] - v.get(i).unwrap()) / v.get(n + i).unwrap())
                .clamp(-body.obs_clip, body.obs_clip)
        })
        .collect();
    for (index, (l, spec)) in view.layers().zip(body.layers.iter()).enumerate() {
        assert_eq!(l.dtype, LayerDtype::Int8);
        let packed = view.int8_weights(index).unwrap();
        let max = x.iter().fold(0.0f32, |m, a| m.max(a.abs()));
        let sx = if max > 0.0 { max / 32767.0 } else { 1.0 };
        let inv = 1.0 / sx;
        let xq: Vec<i64> = x
            .iter()
            .map(|a| {
                let t = a * inv;
                let r = (t + if t < 0.0 { -0.5 } else { 0.5 }) as i32;
                i64::from(r.clamp(-32767, 32767))
            })
            .collect();
        let y: Vec<f32> = (0..l.outputs)
            .map(|j| {
                let acc: i64 = (0..l.inputs)
                    .map(|i| i64::from(packed[int8::byte_index(l.inputs, i, j)]) * xq[i])
                    .sum();
                let s = v.get(l.scales.unwrap() + j).unwrap();
                let y = acc as i32 as f32 * (s * sx) + v.get(l.biases + j).unwrap();
                match spec.activation {
                    Activation::Relu => y.max(0.0),
                    Activation::Tanh => libm::tanhf(y),
                    Activation::Linear => y,
                }
            })
            .collect();
        x = y;
    }
    x.iter()
        .zip(&body.action)
        .map(|(y, j)| (y * j.scale).clamp(j.min, j.max))
        .collect()
}

#[test]
fn int8_golden_policy_is_reproducible() {
    assert_eq!(
        jaco_policy_int8(&[64, 64], 11).unwrap(),
        POLICY_INT8,
        "re-bless with `cargo run -p dex-runtime --example make_golden` only on purpose"
    );
}

#[test]
fn int8_evaluator_reproduces_the_golden_actions_and_the_reference_bit_for_bit() {
    let file = aligned_copy(POLICY_INT8);
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    assert_eq!(view.header().version, 2);
    let mut mlp = Mlp::<64>::new(&view).unwrap();
    assert_eq!(mlp.int8_layers(), 3);
    let trace = f32s_le(TRACE);
    let expected = f32s_le(ACTIONS_INT8);
    assert_eq!(trace.len() / OBS_DIM, expected.len() / ACT_DIM);
    for (n, (obs, want)) in trace
        .chunks_exact(OBS_DIM)
        .zip(expected.chunks_exact(ACT_DIM))
        .enumerate()
    {
        let mut action = [0.0f32; ACT_DIM];
        mlp.act(obs, &mut action).unwrap();
        let got: Vec<u32> = action.iter().map(|v| v.to_bits()).collect();
        let want: Vec<u32> = want.iter().map(|v| v.to_bits()).collect();
        assert_eq!(got, want, "observation {n}");
        let reference: Vec<u32> = reference(&view, obs).iter().map(|v| v.to_bits()).collect();
        assert_eq!(
            got, reference,
            "observation {n}: kernel differs from the plain reference"
        );
    }
}

#[test]
fn int8_error_against_f32_is_within_one_percent_of_each_joint_range() {
    let f32_file = aligned_copy(&jaco_policy(&[256, 256], 3).unwrap());
    let int8_file = aligned_copy(&jaco_policy_int8(&[256, 256], 3).unwrap());
    let f32_view = PolicyView::decode(f32_file.as_bytes()).unwrap();
    let int8_view = PolicyView::decode(int8_file.as_bytes()).unwrap();
    // About 4x smaller weights.
    let ratio = f32_view.weight_bytes() as f64 / int8_view.weight_bytes() as f64;
    assert!((3.8..=4.0).contains(&ratio), "{ratio}");
    let mut a = Mlp::<256>::new(&f32_view).unwrap();
    let mut b = Mlp::<256>::new(&int8_view).unwrap();
    let mut worst = [0.0f32; ACT_DIM];
    for obs in observation_trace(512, 99) {
        let (mut ya, mut yb) = ([0.0f32; ACT_DIM], [0.0f32; ACT_DIM]);
        a.act(&obs, &mut ya).unwrap();
        b.act(&obs, &mut yb).unwrap();
        for (k, joint) in f32_view.body().action.iter().enumerate() {
            worst[k] = worst[k].max((ya[k] - yb[k]).abs() / (joint.max - joint.min));
        }
    }
    for (k, w) in worst.iter().enumerate() {
        assert!(
            *w <= 0.01,
            "joint {k}: error {:.3}% of its range",
            w * 100.0
        );
    }
}

#[test]
fn controller_runs_int8_files_like_the_evaluator() {
    let file = aligned_copy(POLICY_INT8);
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut reference = Mlp::<64>::new(&view).unwrap();
    let clock = MockClock::new(0);
    // The envelope off: the actions must be the evaluator's, bit for bit (the trace's joint
    // angles are random, so the envelope would rescale the arm's commands).
    let mut ctrl = Controller::<64>::new(ControllerConfig {
        envelope: dex_runtime::envelope::EnvelopeConfig::disabled(),
        ..ControllerConfig::default()
    });
    ctrl.poll(&clock);
    ctrl.load_policy(&view).unwrap();
    assert_eq!(ctrl.policy_info().unwrap().format_version, 2);
    ctrl.on_frame(
        &dex_runtime::can::messages::nmt_frame(dex_runtime::can::messages::NmtCommand::Start, 0),
        &clock,
    );
    let mut tx =
        [dex_runtime::can::e2e::E2eSender::default(); dex_runtime::can::messages::OBS_FRAMES];
    for (cycle, obs) in observation_trace(16, 4).iter().enumerate() {
        clock.set(cycle as u64 * 50_000 + 1_000);
        ctrl.poll(&clock);
        let frames =
            dex_runtime::can::messages::encode_observation(0x10, obs, cycle as u8, &mut tx);
        for f in &frames {
            ctrl.on_frame(f, &clock);
        }
        assert_eq!(ctrl.state(), State::Operational);
        let mut want = [0.0f32; ACT_DIM];
        reference.act(ctrl.last_observation(), &mut want).unwrap();
        assert_eq!(ctrl.last_action(), &want);
    }
}

#[test]
fn int8_capacity_counts_padded_inputs() {
    // 44 inputs need a 44-wide evaluator in f32 and in int8 (44 is a multiple of 4) ...
    let file = aligned_copy(&jaco_policy_int8(&[40], 1).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    assert!(Mlp::<44>::new(&view).is_ok());
    // ... but a 42-wide hidden layer feeds the next int8 layer 44 padded inputs.
    let file = aligned_copy(&jaco_policy_int8(&[42], 1).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let f32_file = aligned_copy(&jaco_policy(&[42], 1).unwrap());
    let f32_view = PolicyView::decode(f32_file.as_bytes()).unwrap();
    assert!(Mlp::<44>::new(&f32_view).is_ok());
    assert!(Mlp::<44>::new(&view).is_ok());
    let file = aligned_copy(&jaco_policy_int8(&[46], 1).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    assert_eq!(
        Mlp::<46>::new(&view).unwrap_err(),
        FormatError::ExceedsCapacity {
            what: CapacityItem::Width,
            value: 48,
            max: 46
        }
    );
}

#[test]
fn a_misaligned_int8_file_is_refused_not_misread() {
    let mut storage = vec![0u8; POLICY_INT8.len() + 8];
    let base = storage.as_ptr() as usize;
    let misaligned = (4 - base % 4) % 4 + 1;
    storage[misaligned..misaligned + POLICY_INT8.len()].copy_from_slice(POLICY_INT8);
    let view = PolicyView::decode(&storage[misaligned..misaligned + POLICY_INT8.len()]).unwrap();
    assert_eq!(
        Mlp::<64>::new(&view).unwrap_err(),
        FormatError::MisalignedWeights
    );
}
