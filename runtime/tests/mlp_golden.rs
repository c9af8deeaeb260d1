//! The evaluator against its committed goldens (the host half of the bit-exactness proof; the
//! firmware check compares the thumbv7em build with the same files) and against an f64 reference.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::{Activation, PolicyView};
use dex_runtime::EvalError;
use dex_runtime::interface::{ACT_DIM, ACTION_JOINTS, OBS_DIM};
use dex_runtime::mlp::Mlp;
use dex_runtime::testkit::{aligned_copy, f32s_le, jaco_policy, observation_trace};

const POLICY: &[u8] = include_bytes!("golden/jaco_64.dxpl");
const TRACE: &[u8] = include_bytes!("golden/obs_trace.f32");
const ACTIONS: &[u8] = include_bytes!("golden/actions_64.f32");

/// Straightforward f64 evaluation of a policy view (the reference the f32 evaluator must track).
fn reference(view: &PolicyView<'_>, obs: &[f32]) -> Vec<f64> {
    let v: Vec<f64> = view.values().iter().map(f64::from).collect();
    let body = view.body();
    let n = body.obs_dim();
    let clip = f64::from(body.obs_clip);
    let mut x: Vec<f64> = (0..n)
        .map(|i| ((f64::from(obs[i]) - v[i]) / v[n + i]).clamp(-clip, clip))
        .collect();
    for (layer, spec) in view.layers().zip(body.layers.iter()) {
        let mut y = vec![0.0; layer.outputs];
        for (j, yj) in y.iter_mut().enumerate() {
            *yj = v[layer.biases + j];
            for (i, xi) in x.iter().enumerate() {
                *yj += v[layer.weights + i * layer.outputs + j] * xi;
            }
            *yj = match spec.activation {
                Activation::Relu => yj.max(0.0),
                Activation::Tanh => yj.tanh(),
                Activation::Linear => *yj,
            };
        }
        x = y;
    }
    x.iter()
        .zip(&body.action)
        .map(|(y, j)| (y * f64::from(j.scale)).clamp(f64::from(j.min), f64::from(j.max)))
        .collect()
}

#[test]
fn golden_policy_is_reproducible() {
    assert_eq!(
        jaco_policy(&[64, 64], 11).unwrap(),
        POLICY,
        "re-bless with `cargo run -p dex-runtime --example make_golden` only on purpose"
    );
}

#[test]
fn evaluator_reproduces_the_golden_actions_bit_for_bit() {
    let file = aligned_copy(POLICY);
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut mlp = Mlp::<64>::new(&view).unwrap();
    let trace = f32s_le(TRACE);
    let expected = f32s_le(ACTIONS);
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
        let reference = reference(&view, obs);
        for (a, r) in action.iter().zip(&reference) {
            assert!((f64::from(*a) - r).abs() < 1e-5, "{a} vs {r}");
        }
    }
}

#[test]
fn wide_policy_agrees_with_reference_and_is_deterministic() {
    let file = aligned_copy(&jaco_policy(&[256, 256], 3).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let mut a = Mlp::<256>::new(&view).unwrap();
    let mut b = Mlp::<256>::new(&view).unwrap();
    for obs in observation_trace(20, 9) {
        let (mut x, mut y) = ([0.0f32; ACT_DIM], [0.0f32; ACT_DIM]);
        a.act(&obs, &mut x).unwrap();
        b.act(&obs, &mut y).unwrap();
        assert_eq!(x.map(f32::to_bits), y.map(f32::to_bits));
        for (v, r) in x.iter().zip(reference(&view, &obs)) {
            assert!((f64::from(*v) - r).abs() < 1e-4, "{v} vs {r}");
        }
        for (v, j) in x.iter().zip(ACTION_JOINTS) {
            assert!(*v >= j.min && *v <= j.max);
        }
    }
}

#[test]
fn capacity_and_input_errors() {
    let file = aligned_copy(&jaco_policy(&[256, 256], 3).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    assert!(matches!(
        Mlp::<128>::new(&view),
        Err(dex_policy::FormatError::ExceedsCapacity { .. })
    ));
    let small = aligned_copy(POLICY);
    let view = PolicyView::decode(small.as_bytes()).unwrap();
    let mut mlp = Mlp::<64>::new(&view).unwrap();
    let mut action = [0.0f32; ACT_DIM];
    assert_eq!(
        mlp.act(&[0.0; 10], &mut action),
        Err(EvalError::ObservationLength {
            expected: OBS_DIM,
            got: 10
        })
    );
    let mut obs = [0.0f32; OBS_DIM];
    obs[7] = f32::NAN;
    assert_eq!(
        mlp.act(&obs, &mut action),
        Err(EvalError::NonFiniteObservation { index: 7 })
    );
    assert_eq!(
        mlp.act(&[0.0; OBS_DIM], &mut [0.0; 3]),
        Err(EvalError::ActionLength {
            expected: ACT_DIM,
            got: 3
        })
    );
}

#[test]
fn huge_observations_are_clipped_not_propagated() {
    let small = aligned_copy(POLICY);
    let view = PolicyView::decode(small.as_bytes()).unwrap();
    let mut mlp = Mlp::<64>::new(&view).unwrap();
    let mut clipped = [0.0f32; ACT_DIM];
    let mut at_clip = [0.0f32; ACT_DIM];
    mlp.act(&[1.0e30; OBS_DIM], &mut clipped).unwrap();
    // Every normalised value saturates at +clip, the same as an observation exactly there.
    let clip = view.body().obs_clip;
    let v: Vec<f32> = view.values().iter().collect();
    let obs: Vec<f32> = (0..OBS_DIM)
        .map(|i| v[i] + v[OBS_DIM + i] * clip * 2.0)
        .collect();
    mlp.act(&obs, &mut at_clip).unwrap();
    assert_eq!(clipped.map(f32::to_bits), at_clip.map(f32::to_bits));
}
