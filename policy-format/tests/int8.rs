//! Format version 2: int8 layers. The committed int8 golden, the packed layout, the quantiser's
//! error bound, the version 1 fixture still decoding, and one test per new failure mode.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::synth::{SynthSpec, golden_small_int8, golden_small_spec, synth_parts};
use dex_policy::{
    Activation, FormatError, LayerDtype, PolicyView, Task, encode_data_to_vec, encode_to_vec,
    file_crc, int8,
};
use proptest::prelude::*;

const GOLDEN_V1: &[u8] = include_bytes!("golden/small.dxpl");
const GOLDEN_INT8: &[u8] = include_bytes!("golden/small_int8.dxpl");

fn reseal(mut file: Vec<u8>) -> Vec<u8> {
    let crc = file_crc(&file);
    file[20..24].copy_from_slice(&crc.to_le_bytes());
    file
}

/// Byte offset of stored word `word` in `file`.
fn word_offset(file: &[u8], word: usize) -> usize {
    let body_len = u32::from_le_bytes(file[12..16].try_into().unwrap()) as usize;
    dex_policy::values_offset(body_len) + 4 * word
}

#[test]
fn generator_still_produces_the_committed_int8_bytes() {
    assert_eq!(
        golden_small_int8().unwrap(),
        GOLDEN_INT8,
        "int8 encoding changed: if intended, update docs/policy-format.md and re-bless with \
         `cargo run -p dex-policy --features std --example make_format_golden`"
    );
}

#[test]
fn int8_golden_decodes_as_version_2() {
    let view = PolicyView::decode(GOLDEN_INT8).unwrap();
    assert_eq!(view.header().version, 2);
    let body = view.body();
    assert_eq!(body.task, Task::Grasp);
    assert!(body.has_int8());
    assert_eq!(body.layers[0].dtype, LayerDtype::Int8);
    assert_eq!(body.layers[1].dtype, LayerDtype::Int8);
    // 5 -> 8: inputs padded to 8, 8 outputs: 64 bytes = 16 words; 8 -> 3: 8 x 4 = 32 bytes.
    let l0 = view.layer(0).unwrap();
    assert_eq!(
        (l0.weights, l0.scales, l0.biases),
        (10, Some(10 + 16), 10 + 16 + 8)
    );
    let l1 = view.layer(1).unwrap();
    assert_eq!(
        (l1.weights, l1.scales, l1.biases),
        (42, Some(42 + 8), 42 + 8 + 3)
    );
    assert_eq!(view.values().len(), 42 + 8 + 3 + 3);
    assert_eq!(view.weight_bytes(), 64 + 32);
    assert_eq!(view.int8_weights(0).unwrap().len(), 64);
    assert_eq!(view.int8_weights(2), None);
    // The f32 policy it came from: same layouts and normalisation.
    let f32_view = PolicyView::decode(GOLDEN_V1).unwrap();
    assert_eq!(f32_view.header().version, 1);
    assert_eq!(view.header().layout_hash, f32_view.header().layout_hash);
    assert_eq!(f32_view.int8_weights(0), None);
    assert_eq!(f32_view.weight_bytes(), (5 * 8 + 8 * 3) * 4);
    for k in 0..10 {
        assert_eq!(view.values().get(k), f32_view.values().get(k));
    }
}

#[test]
fn int8_golden_dequantises_close_to_the_f32_weights() {
    let view = PolicyView::decode(GOLDEN_INT8).unwrap();
    let f32_view = PolicyView::decode(GOLDEN_V1).unwrap();
    for (index, (q, f)) in view.layers().zip(f32_view.layers()).enumerate() {
        let packed = view.int8_weights(index).unwrap();
        let scales = q.scales.unwrap();
        for j in 0..q.outputs {
            let s = view.values().get(scales + j).unwrap();
            for i in 0..q.inputs {
                let w = f32_view
                    .values()
                    .get(f.weights + i * f.outputs + j)
                    .unwrap();
                let wq = f32::from(packed[int8::byte_index(q.inputs, i, j)]) * s;
                assert!((w - wq).abs() <= 0.5 * s * 1.0001, "layer {index} {i}->{j}");
            }
            assert_eq!(
                view.values().get(q.biases + j),
                f32_view.values().get(f.biases + j)
            );
        }
    }
}

#[test]
fn every_single_bit_flip_of_the_int8_golden_is_rejected() {
    let mut file = GOLDEN_INT8.to_vec();
    for byte in 0..file.len() {
        for bit in 0..8 {
            file[byte] ^= 1 << bit;
            assert!(
                PolicyView::decode(&file).is_err(),
                "flip of byte {byte} bit {bit} was accepted"
            );
            file[byte] ^= 1 << bit;
        }
    }
    assert!(PolicyView::decode(&file).is_ok());
}

#[test]
fn all_f32_policies_are_still_written_as_version_1() {
    let (body, values) = synth_parts(&golden_small_spec()).unwrap();
    let file = encode_to_vec(&body, &values).unwrap();
    assert_eq!(file, GOLDEN_V1);
    assert_eq!(u16::from_le_bytes([file[4], file[5]]), 1);
}

#[test]
fn newer_versions_are_refused_naming_both() {
    let mut f = GOLDEN_INT8.to_vec();
    f[4] = 3;
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::UnsupportedVersion {
            found: 3,
            supported: 2
        })
    );
    let mut f = GOLDEN_V1.to_vec();
    f[4] = 0;
    assert!(matches!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::UnsupportedVersion { found: 0, .. })
    ));
}

#[test]
fn a_version_2_body_in_a_version_1_header_is_malformed() {
    let mut f = GOLDEN_INT8.to_vec();
    f[4] = 1;
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::MalformedBody)
    );
}

#[test]
fn zero_or_negative_scale_is_reported() {
    let view = PolicyView::decode(GOLDEN_INT8).unwrap();
    let scales = view.layer(1).unwrap().scales.unwrap();
    for bad in [0.0f32, -0.5] {
        let mut f = GOLDEN_INT8.to_vec();
        let at = word_offset(&f, scales + 2);
        f[at..at + 4].copy_from_slice(&bad.to_le_bytes());
        assert_eq!(
            PolicyView::decode(&reseal(f)),
            Err(FormatError::InvalidScale {
                layer: 1,
                output: 2
            })
        );
    }
    let mut f = GOLDEN_INT8.to_vec();
    let at = word_offset(&f, scales);
    f[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::NonFiniteWeight { index: scales })
    );
}

#[test]
fn any_int8_weight_byte_is_accepted_but_padding_must_be_zero() {
    let view = PolicyView::decode(GOLDEN_INT8).unwrap();
    let l0 = view.layer(0).unwrap();
    // A real weight may be any byte, including NaN-looking patterns: int8 words are not f32.
    let mut f = GOLDEN_INT8.to_vec();
    let at = word_offset(&f, l0.weights);
    f[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(PolicyView::decode(&reseal(f)).is_ok());
    // Input 5 of layer 0 is padding (5 inputs padded to 8).
    let mut f = GOLDEN_INT8.to_vec();
    let at = word_offset(&f, l0.weights) + int8::byte_index(5, 5, 3);
    f[at] = 1;
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::NonZeroWeightPadding { layer: 0 })
    );
    // Output 3 of layer 1 is padding (3 outputs padded to 4).
    let l1 = view.layer(1).unwrap();
    let mut f = GOLDEN_INT8.to_vec();
    let at = word_offset(&f, l1.weights) + int8::byte_index(8, 6, 3);
    f[at] = 0x80;
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::NonZeroWeightPadding { layer: 1 })
    );
}

#[test]
fn int8_layers_wider_than_exact_accumulation_are_refused() {
    let spec = SynthSpec {
        task: Task::Reach,
        observation: &[("wide", 513)],
        action: &[("j", 1.0, -1.0, 1.0)],
        hidden: &[],
        hidden_activation: Activation::Relu,
        output_activation: Activation::Tanh,
        seed: 1,
    };
    let f32_file = dex_policy::synth::synth_policy(&spec).unwrap();
    let view = PolicyView::decode(&f32_file).unwrap();
    assert_eq!(
        int8::quantise_policy(&view, |_| true, None),
        Err(FormatError::QuantisedLayerTooWide {
            layer: 0,
            inputs: 516,
            max: 512
        })
    );
    let narrow = SynthSpec {
        observation: &[("wide", 512)],
        ..spec
    };
    let f32_file = dex_policy::synth::synth_policy(&narrow).unwrap();
    let view = PolicyView::decode(&f32_file).unwrap();
    assert!(int8::quantise_policy(&view, |_| true, None).is_ok());
}

#[test]
fn int8_data_of_the_wrong_size_is_refused() {
    let view = PolicyView::decode(GOLDEN_INT8).unwrap();
    let body = view.body().clone();
    let data = view.values().bytes();
    assert_eq!(encode_data_to_vec(&body, data).unwrap(), GOLDEN_INT8);
    assert_eq!(
        encode_data_to_vec(&body, &data[..data.len() - 4]),
        Err(FormatError::WeightCountMismatch {
            expected: 56,
            stored: 55
        })
    );
    assert!(matches!(
        encode_data_to_vec(&body, &data[..data.len() - 1]),
        Err(FormatError::WeightCountMismatch { .. })
    ));
}

#[test]
fn new_errors_have_messages() {
    for (e, needle) in [
        (
            FormatError::InvalidScale {
                layer: 1,
                output: 2,
            },
            "scale",
        ),
        (FormatError::NonZeroWeightPadding { layer: 0 }, "padding"),
        (
            FormatError::QuantisedLayerTooWide {
                layer: 0,
                inputs: 516,
                max: 512,
            },
            "516",
        ),
    ] {
        assert!(e.to_string().contains(needle), "{e}");
    }
}

#[test]
fn partial_quantisation_keeps_the_other_layers_f32() {
    let f32_view = PolicyView::decode(GOLDEN_V1).unwrap();
    let file = int8::quantise_policy(&f32_view, |l| l == 0, None).unwrap();
    let view = PolicyView::decode(&file).unwrap();
    assert_eq!(view.header().version, 2);
    assert_eq!(view.body().layers[0].dtype, LayerDtype::Int8);
    assert_eq!(view.body().layers[1].dtype, LayerDtype::F32);
    let (l, f) = (view.layer(1).unwrap(), f32_view.layer(1).unwrap());
    for k in 0..l.inputs * l.outputs + l.outputs {
        assert_eq!(
            view.values().get(l.weights + k),
            f32_view.values().get(f.weights + k)
        );
    }
    // Quantising an already-int8 file copies its int8 layers unchanged.
    let twice = int8::quantise_policy(&view, |_| true, None).unwrap();
    assert_eq!(twice, GOLDEN_INT8);
}

#[test]
fn byte_index_is_a_bijection_onto_the_non_padding_bytes() {
    for (inputs, outputs) in [(5, 8), (8, 3), (44, 9), (4, 4), (1, 1), (13, 6)] {
        let len = int8::packed_bytes(inputs, outputs).unwrap();
        let mut seen = vec![false; len];
        for j in 0..outputs {
            for i in 0..inputs {
                let k = int8::byte_index(inputs, i, j);
                assert!(!seen[k] && !int8::is_padding(inputs, outputs, k));
                seen[k] = true;
            }
        }
        let padding = (0..len)
            .filter(|&k| int8::is_padding(inputs, outputs, k))
            .count();
        assert_eq!(padding + inputs * outputs, len, "{inputs}x{outputs}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    #[test]
    fn quantised_policies_round_trip_within_half_a_step(
        obs in 1u16..20,
        hidden in prop::collection::vec(1u16..20, 0..3),
        act in 1usize..6,
        seed in any::<u64>(),
    ) {
        let action: Vec<(&str, f32, f32, f32)> = (0..act).map(|_| ("j", 1.0, -1.0, 1.0)).collect();
        let spec = SynthSpec {
            task: Task::Stack,
            observation: &[("o", obs)],
            action: &action,
            hidden: &hidden,
            hidden_activation: Activation::Relu,
            output_activation: Activation::Linear,
            seed,
        };
        let f32_file = dex_policy::synth::synth_policy(&spec).unwrap();
        let f32_view = PolicyView::decode(&f32_file).unwrap();
        let file = int8::quantise_policy(&f32_view, |_| true, None).unwrap();
        let view = PolicyView::decode(&file).unwrap();
        prop_assert_eq!(&view.body().observation, &f32_view.body().observation);
        let last = view.layers().last().unwrap();
        prop_assert_eq!(last.biases + last.outputs, view.values().len());
        for (index, (q, f)) in view.layers().zip(f32_view.layers()).enumerate() {
            let packed = view.int8_weights(index).unwrap();
            for j in 0..q.outputs {
                let s = view.values().get(q.scales.unwrap() + j).unwrap();
                for i in 0..q.inputs {
                    let w = f32_view.values().get(f.weights + i * f.outputs + j).unwrap();
                    let wq = f32::from(packed[int8::byte_index(q.inputs, i, j)]) * s;
                    prop_assert!((w - wq).abs() <= 0.5 * s * 1.0001);
                }
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Dequantised weights are on the grid (and stay there), random weights are not, nor is a
    /// grid layer with one weight nudged by a hundredth of a step.
    #[test]
    fn dequantised_layers_are_on_the_grid_and_others_are_not(
        inputs in 2usize..40,
        outputs in 1usize..12,
        seed in any::<u64>(),
    ) {
        let mut rng = dex_policy::synth::SplitMix64::new(seed);
        let mut next = || rng.uniform(-1.0, 1.0);
        let w: Vec<f32> = (0..inputs * outputs).map(|_| next() * 0.7).collect();
        prop_assume!(!int8::on_grid(inputs, outputs, &w));
        let q = int8::quantise_layer(inputs, outputs, &w);
        let mut grid = vec![0.0f32; w.len()];
        for i in 0..inputs {
            for j in 0..outputs {
                grid[i * outputs + j] = f32::from(q.weights[j * inputs + i]) * q.scales[j];
            }
        }
        prop_assert!(int8::on_grid(inputs, outputs, &grid));
        // A weight that is not the column's largest, moved by 1% of a step, leaves the grid.
        let j = 0;
        let big = (0..inputs).map(|i| grid[i * outputs + j].abs()).fold(0.0f32, f32::max);
        if let Some(i) = (0..inputs).find(|&i| grid[i * outputs + j].abs() < 0.5 * big) {
            let mut nudged = grid.clone();
            nudged[i * outputs + j] += 0.01 * q.scales[j];
            prop_assert!(!int8::on_grid(inputs, outputs, &nudged));
        }
        prop_assert!(!int8::on_grid(inputs, outputs, &grid[1..]));
    }
}
