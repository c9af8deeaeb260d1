//! The committed golden file: exact bytes, decoded contents, and rejection of every single-bit flip.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::{Activation, FormatError, PolicyView, Task, synth};

const GOLDEN: &[u8] = include_bytes!("golden/small.dxpl");

#[test]
fn generator_still_produces_the_committed_bytes() {
    let fresh = synth::synth_policy(&synth::golden_small_spec()).unwrap();
    assert_eq!(
        fresh, GOLDEN,
        "encoding changed: if intended, bump FORMAT_VERSION, update docs/policy-format.md and re-bless with \
         `cargo run -p dex-policy --example make_format_golden`"
    );
}

#[test]
fn golden_decodes_to_the_expected_policy() {
    let view = PolicyView::decode(GOLDEN).unwrap();
    let body = view.body();
    assert_eq!(body.task, Task::Grasp);
    assert_eq!(body.obs_dim(), 5);
    assert_eq!(body.act_dim(), 3);
    assert_eq!(body.observation[1].name, "brick_pos");
    assert_eq!(body.action[2].scale, 5.0);
    assert_eq!(body.layers.len(), 2);
    assert_eq!(body.layers[0].activation, Activation::Relu);
    assert_eq!(body.layers[1].activation, Activation::Tanh);
    assert_eq!(body.control_period_us, 50_000);
    assert_eq!(body.provenance.seed, 7);
    assert_eq!(view.values().len(), 2 * 5 + 5 * 8 + 8 + 8 * 3 + 3);
    let l1 = view.layer(1).unwrap();
    assert_eq!(
        (l1.inputs, l1.outputs, l1.weights, l1.biases),
        (8, 3, 58, 82)
    );
    assert_eq!(view.header().crc, dex_policy::file_crc(GOLDEN));
}

#[test]
fn every_single_bit_flip_is_rejected() {
    let mut file = GOLDEN.to_vec();
    for byte in 0..file.len() {
        for bit in 0..8 {
            file[byte] ^= 1 << bit;
            let rejected = PolicyView::decode(&file).is_err();
            assert!(rejected, "flip of byte {byte} bit {bit} was accepted");
            file[byte] ^= 1 << bit;
        }
    }
    assert!(PolicyView::decode(&file).is_ok());
}

#[test]
fn flips_map_to_the_specific_errors() {
    let flip = |byte: usize, bit: u8| {
        let mut f = GOLDEN.to_vec();
        f[byte] ^= 1 << bit;
        PolicyView::decode(&f).unwrap_err()
    };
    assert!(matches!(flip(0, 0), FormatError::BadMagic { .. }));
    assert_eq!(
        flip(4, 1),
        FormatError::UnsupportedVersion {
            found: 3,
            supported: 2
        }
    );
    assert_eq!(flip(6, 0), FormatError::UnknownFlags { flags: 1 });
    assert!(matches!(flip(9, 3), FormatError::CrcMismatch { .. }));
    assert!(matches!(flip(16, 7), FormatError::Truncated { .. }));
    assert!(matches!(flip(16, 0), FormatError::TrailingBytes { .. }));
    assert!(matches!(flip(200, 5), FormatError::CrcMismatch { .. }));
}

#[test]
fn every_truncation_is_rejected() {
    for len in 0..GOLDEN.len() {
        assert!(PolicyView::decode(&GOLDEN[..len]).is_err(), "len {len}");
    }
    let mut longer = GOLDEN.to_vec();
    longer.push(0);
    assert!(matches!(
        PolicyView::decode(&longer),
        Err(FormatError::TrailingBytes { .. })
    ));
}
