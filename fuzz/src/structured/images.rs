//! The policy files the fuzzer starts with, flashes or loads: seeded synthetic policies, four that the
//! controller takes and three that it must refuse.

use std::sync::OnceLock;

use dex_policy::synth::{SynthSpec, golden_small_spec, synth_parts, synth_policy};
use dex_policy::{Activation, Body, Task, encode_to_vec};
use dex_runtime::interface::OBS_DIM;
use dex_runtime::testkit::{
    AlignedBytes, aligned_copy, cell_layout, jaco_policy, jaco_policy_int8,
};

/// A prepared policy file and whether the controller must take it.
pub(crate) struct Image {
    pub(crate) bytes: AlignedBytes,
    pub(crate) loads: bool,
}

/// A policy on the cell's layout, edited before encoding.
fn jaco_file(
    hidden: &[u16],
    seed: u64,
    output: Activation,
    edit: impl FnOnce(&mut Body<'_>, &mut Vec<f32>),
) -> Vec<u8> {
    let (observation, action) = cell_layout();
    let spec = SynthSpec {
        task: Task::Stack,
        observation: &observation,
        action: &action,
        hidden,
        hidden_activation: Activation::Relu,
        output_activation: output,
        seed,
    };
    let (mut body, mut values) = synth_parts(&spec).expect("synthetic policy");
    edit(&mut body, &mut values);
    encode_to_vec(&body, &values).expect("synthetic policy encodes")
}

/// The files the fuzzer flashes or loads; the first four load, the rest are refused.
pub(crate) fn images() -> &'static [Image] {
    static IMAGES: OnceLock<Vec<Image>> = OnceLock::new();
    IMAGES.get_or_init(|| {
        let image = |bytes: Vec<u8>, loads: bool| Image {
            bytes: aligned_copy(&bytes),
            loads,
        };
        vec![
            image(jaco_policy(&[16], 1).expect("policy"), true),
            image(jaco_policy(&[8, 8], 2).expect("policy"), true),
            image(jaco_policy_int8(&[16], 3).expect("policy"), true),
            // First-layer weights of +-1e38: every product overflows, the sums are inf - inf.
            image(
                jaco_file(&[16], 4, Activation::Linear, |_, values| {
                    let start = 2 * OBS_DIM;
                    for (i, w) in values[start..start + OBS_DIM * 16].iter_mut().enumerate() {
                        *w = if i % 2 == 0 { 1e38 } else { -1e38 };
                    }
                }),
                true,
            ),
            image(
                jaco_file(&[16], 5, Activation::Tanh, |body, _| {
                    body.control_period_us = 40_000;
                }),
                false,
            ),
            image(synth_policy(&golden_small_spec()).expect("policy"), false),
            image(jaco_policy(&[128], 6).expect("policy"), false),
        ]
    })
}
