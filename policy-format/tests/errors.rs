//! One test per way a policy file can be wrong, each expecting its own typed error.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::synth::{golden_small_spec, synth_parts};
use dex_policy::{
    Body, Capacity, CapacityItem, FormatError, PolicyView, encode_into, encode_to_vec, file_crc,
};

const GOLDEN: &[u8] = include_bytes!("golden/small.dxpl");

fn reseal(mut file: Vec<u8>) -> Vec<u8> {
    let crc = file_crc(&file);
    file[20..24].copy_from_slice(&crc.to_le_bytes());
    file
}

fn parts() -> (Body<'static>, Vec<f32>) {
    synth_parts(&golden_small_spec()).unwrap()
}

#[test]
fn messages_name_what_is_wrong() {
    let e = FormatError::UnsupportedVersion {
        found: 9,
        supported: 1,
    };
    let text = e.to_string();
    assert!(text.contains('9') && text.contains('1'), "{text}");
    let e = FormatError::CrcMismatch {
        stored: 1,
        computed: 2,
    };
    assert!(e.to_string().contains("CRC"));
}

#[test]
fn empty_file_is_truncated() {
    assert_eq!(
        PolicyView::decode(&[]),
        Err(FormatError::Truncated { needed: 24, got: 0 })
    );
}

#[test]
fn malformed_body_is_reported() {
    let mut f = GOLDEN.to_vec();
    f[24] = 0x7f; // task discriminant far out of range
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::MalformedBody)
    );
}

#[test]
fn nonzero_padding_is_reported() {
    let body_len = u32::from_le_bytes(GOLDEN[12..16].try_into().unwrap()) as usize;
    let pad_at = 24 + body_len;
    assert_ne!(pad_at % 4, 0, "golden must have padding for this test");
    let mut f = GOLDEN.to_vec();
    f[pad_at] = 1;
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::NonZeroPadding)
    );
}

#[test]
fn layout_hash_mismatch_is_reported() {
    let mut f = GOLDEN.to_vec();
    f[8] ^= 0x55;
    assert!(matches!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::LayoutHashMismatch { .. })
    ));
}

#[test]
fn non_finite_weight_is_reported_by_encoder_and_decoder() {
    let (body, mut values) = parts();
    values[20] = f32::NAN;
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::NonFiniteWeight { index: 20 })
    );
    let mut f = GOLDEN.to_vec();
    let start = f.len() - 4;
    f[start..].copy_from_slice(&f32::INFINITY.to_le_bytes());
    let last = (f.len() - dex_policy::values_offset(110)) / 4 - 1;
    assert_eq!(
        PolicyView::decode(&reseal(f)),
        Err(FormatError::NonFiniteWeight { index: last })
    );
}

#[test]
fn layer_chain_errors() {
    let (mut body, values) = parts();
    body.layers[0].outputs = 0;
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::EmptyLayer { layer: 0 })
    );
    let (mut body, values) = parts();
    body.layers[1].outputs = 4;
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::OutputMismatch {
            outputs: 4,
            actions: 3
        })
    );
    let (body, mut values) = parts();
    values.pop();
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::WeightCountMismatch {
            expected: 85,
            stored: 84
        })
    );
    let (mut body, values) = parts();
    body.layers.clear();
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::EmptyLayer { layer: 0 })
    );
}

#[test]
fn layout_and_limit_errors() {
    let (mut body, values) = parts();
    body.observation[0].name = "";
    assert!(matches!(
        encode_to_vec(&body, &values),
        Err(FormatError::BadName { .. })
    ));
    let (mut body, values) = parts();
    body.action[1].name = "a_name_that_is_much_longer_than_32_bytes";
    assert!(matches!(
        encode_to_vec(&body, &values),
        Err(FormatError::BadName { .. })
    ));
    let (mut body, values) = parts();
    body.observation[1].size = 0;
    assert!(matches!(
        encode_to_vec(&body, &values),
        Err(FormatError::EmptyObservationField { field: 1 })
            | Err(FormatError::WeightCountMismatch { .. })
    ));
    let (mut body, values) = parts();
    body.action[2].min = 6.0;
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::InvalidActionJoint { joint: 2 })
    );
    let (mut body, values) = parts();
    body.action[0].scale = f32::NAN;
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::InvalidActionJoint { joint: 0 })
    );
    let (mut body, values) = parts();
    body.control_period_us = 0;
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::InvalidControlPeriod)
    );
    let (mut body, values) = parts();
    body.obs_clip = -1.0;
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::InvalidNormalisation { index: usize::MAX })
    );
    let (body, mut values) = parts();
    values[5 + 2] = 0.0; // scale of observation value 2
    assert_eq!(
        encode_to_vec(&body, &values),
        Err(FormatError::InvalidNormalisation { index: 2 })
    );
}

#[test]
fn capacity_is_checked() {
    let view = PolicyView::decode(GOLDEN).unwrap();
    let roomy = Capacity {
        max_obs: 5,
        max_act: 3,
        max_width: 8,
        max_layers: 2,
    };
    assert_eq!(view.check_capacity(&roomy), Ok(()));
    let narrow = Capacity {
        max_width: 7,
        ..roomy
    };
    assert_eq!(
        view.check_capacity(&narrow),
        Err(FormatError::ExceedsCapacity {
            what: CapacityItem::Width,
            value: 8,
            max: 7
        })
    );
    let shallow = Capacity {
        max_layers: 1,
        ..roomy
    };
    assert!(matches!(
        view.check_capacity(&shallow),
        Err(FormatError::ExceedsCapacity {
            what: CapacityItem::Layers,
            ..
        })
    ));
}

#[test]
fn layouts_are_compared_with_the_controller() {
    let view = PolicyView::decode(GOLDEN).unwrap();
    let obs = [("joint_pos", 3), ("brick_pos", 2)];
    let act = ["joint_a", "joint_b", "finger"];
    assert_eq!(view.check_layout(obs, act), Ok(()));
    assert_eq!(
        view.check_layout([("joint_pos", 3), ("brick_pos", 3)], act),
        Err(FormatError::ObservationLayoutMismatch { field: 1 })
    );
    assert_eq!(
        view.check_layout([("joint_pos", 3)], act),
        Err(FormatError::ObservationLayoutMismatch { field: 1 })
    );
    assert_eq!(
        view.check_layout(obs, ["joint_a", "joint_b"]),
        Err(FormatError::ActionLayoutMismatch { joint: 2 })
    );
    assert_eq!(
        view.check_layout(obs, ["joint_a", "joint_b", "finger", "extra"]),
        Err(FormatError::ActionLayoutMismatch { joint: 3 })
    );
}

#[test]
fn misaligned_values_cannot_be_borrowed_but_can_be_copied() {
    let mut storage = vec![0u8; GOLDEN.len() + 8];
    let base = storage.as_ptr() as usize;
    let aligned = (4 - base % 4) % 4;
    let misaligned = aligned + 1;
    storage[misaligned..misaligned + GOLDEN.len()].copy_from_slice(GOLDEN);
    let view = PolicyView::decode(&storage[misaligned..misaligned + GOLDEN.len()]).unwrap();
    assert_eq!(
        view.values().as_slice(),
        Err(FormatError::MisalignedWeights)
    );
    let mut buf = [0f32; 85];
    assert_eq!(view.values().copy_into(&mut buf).unwrap().len(), 85);
    let mut small = [0f32; 10];
    assert_eq!(
        view.values().copy_into(&mut small),
        Err(FormatError::BufferTooSmall { needed: 85 })
    );
    drop(view);
    storage[aligned..aligned + GOLDEN.len()].copy_from_slice(GOLDEN);
    let view = PolicyView::decode(&storage[aligned..aligned + GOLDEN.len()]).unwrap();
    assert_eq!(view.values().as_slice().unwrap().len(), 85);
}

#[test]
fn encoder_reports_a_small_buffer() {
    let (body, values) = parts();
    let mut buf = [0u8; 100];
    assert!(matches!(
        encode_into(&body, &values, &mut buf),
        Err(FormatError::BufferTooSmall { .. })
    ));
}
