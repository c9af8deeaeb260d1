//! Policies that take the task features (`dex_runtime::features`): the controller computes them
//! from each observation and feeds them after it, bit for bit as the evaluator does; any other
//! arrangement of the feature fields is refused at load.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::synth::{SynthSpec, synth_policy};
use dex_policy::{Activation, FormatError, PolicyView, Task};
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{
    NmtCommand, OBS_FRAMES, encode_observation, nmt_frame, quantise_observation,
};
use dex_runtime::envelope::{Envelope, EnvelopeConfig};
use dex_runtime::features::{FEATURE_FIELDS, INPUT_MAX, check_layout, policy_input};
use dex_runtime::interface::{ACT_DIM, OBS_DIM};
use dex_runtime::testkit::{
    aligned_copy, cell_layout, jaco_policy, jaco_policy_with_features, observation_trace,
};
use dex_runtime::{Controller, ControllerConfig, LoadError, Mlp, MockClock, State};

const PERIOD: u64 = 50_000;

#[test]
fn the_controller_feeds_a_featured_policy_its_features_exactly_as_the_evaluator() {
    let file = aligned_copy(&jaco_policy_with_features(&[64, 64], 3).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    assert_eq!(view.body().obs_dim(), INPUT_MAX);
    check_layout(&view).unwrap();
    let mut reference = Mlp::<64>::new(&view).unwrap();
    let mut envelope = Envelope::new(EnvelopeConfig::jaco(), PERIOD as u32);
    let clock = MockClock::new(0);
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.poll(&clock);
    c.load_policy(&view).unwrap();
    let node = ControllerConfig::default().node_id;
    c.on_frame(&nmt_frame(NmtCommand::Start, node), &clock);
    assert_eq!(c.state(), State::Operational);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let mut plain_differs = 0;
    for (sample, obs) in observation_trace(20, 7).into_iter().enumerate() {
        clock.advance(PERIOD);
        c.poll(&clock);
        for f in encode_observation(0x10, &obs, sample as u8 + 1, &mut tx) {
            c.on_frame(&f, &clock);
        }
        let quantised: [f32; OBS_DIM] = core::array::from_fn(|i| quantise_observation(i, obs[i]));
        let mut buf = [0.0f32; INPUT_MAX];
        let mut want = [0.0f32; ACT_DIM];
        reference
            .act(policy_input(&quantised, INPUT_MAX, &mut buf), &mut want)
            .unwrap();
        envelope.apply(&quantised, &mut want);
        assert_eq!(c.last_action().map(f32::to_bits), want.map(f32::to_bits));
        // The features matter: zeros in their place give another action.
        buf[OBS_DIM..].fill(0.0);
        let mut without = [0.0f32; ACT_DIM];
        reference.act(&buf, &mut without).unwrap();
        envelope.apply(&quantised, &mut without);
        plain_differs += usize::from(without != want);
    }
    assert_eq!(c.diagnostics().evaluations, 20);
    assert!(
        plain_differs > 10,
        "features changed {plain_differs} of 20 actions"
    );
}

#[test]
fn a_plain_policy_gets_the_observation_alone() {
    let file = aligned_copy(&jaco_policy(&[32], 1).unwrap());
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    check_layout(&view).unwrap();
    let obs = observation_trace(1, 2)[0];
    let mut buf = [0.0f32; INPUT_MAX];
    assert_eq!(policy_input(&obs, OBS_DIM, &mut buf), &obs[..]);
}

/// A synthetic policy whose observation fields are `fields`.
fn policy_with(fields: &[(&'static str, u16)]) -> Vec<u8> {
    let (_, action) = cell_layout();
    synth_policy(&SynthSpec {
        task: Task::Grasp,
        observation: fields,
        action: &action,
        hidden: &[16],
        hidden_activation: Activation::Relu,
        output_activation: Activation::Tanh,
        seed: 0,
    })
    .unwrap()
}

#[test]
fn feature_fields_out_of_place_are_refused_at_load() {
    let (obs, _) = cell_layout();
    let features: Vec<(&'static str, u16)> =
        FEATURE_FIELDS.iter().map(|f| (f.name, f.size)).collect();
    let all: Vec<_> = obs.iter().chain(&features).copied().collect();
    // Features first; one feature field missing (a shorter input); two fields swapped (same size).
    let first: Vec<_> = features.iter().chain(&obs).copied().collect();
    let partial: Vec<_> = all[..all.len() - 1].to_vec();
    let mut swapped = all.clone();
    swapped.swap(obs.len(), obs.len() + 1);
    for (what, fields) in [("first", first), ("partial", partial), ("swapped", swapped)] {
        let file = aligned_copy(&policy_with(&fields));
        let view = PolicyView::decode(file.as_bytes()).unwrap();
        let mut c = Controller::<64>::new(ControllerConfig::default());
        assert!(
            matches!(
                c.load_policy(&view),
                Err(LoadError::Format(
                    FormatError::ObservationLayoutMismatch { .. }
                ))
            ),
            "{what}"
        );
    }
    let file = aligned_copy(&policy_with(&all));
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    assert_eq!(
        Controller::<64>::new(ControllerConfig::default()).load_policy(&view),
        Ok(())
    );
}
