//! Encode/decode round trips over generated policies, and decoder robustness on arbitrary bytes.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_policy::synth::{SynthSpec, synth_parts};
use dex_policy::{Activation, PolicyView, Task, encode_into, encode_to_vec};
use proptest::prelude::*;

const NAMES: [&str; 8] = ["a", "bb", "joint", "brick1_pos", "x_y", "q", "vel", "zz"];

fn activation() -> impl Strategy<Value = Activation> {
    prop_oneof![
        Just(Activation::Relu),
        Just(Activation::Tanh),
        Just(Activation::Linear)
    ]
}

fn task() -> impl Strategy<Value = Task> {
    prop_oneof![
        Just(Task::Reach),
        Just(Task::Grasp),
        Just(Task::StackInHand),
        Just(Task::Stack)
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn encode_then_decode_gives_back_the_policy(
        obs_sizes in prop::collection::vec(1u16..9, 1..6),
        act in prop::collection::vec((0.1f32..10.0, 0.0f32..5.0), 1..6),
        hidden in prop::collection::vec(1u16..17, 0..4),
        hidden_activation in activation(),
        output_activation in activation(),
        task in task(),
        seed in any::<u64>(),
    ) {
        let observation: Vec<(&str, u16)> =
            obs_sizes.iter().enumerate().map(|(i, &s)| (NAMES[i % 8], s)).collect();
        let action: Vec<(&str, f32, f32, f32)> =
            act.iter().enumerate().map(|(i, &(scale, lim))| (NAMES[i % 8], scale, -lim, lim)).collect();
        let spec = SynthSpec {
            task, observation: &observation, action: &action, hidden: &hidden,
            hidden_activation, output_activation, seed,
        };
        let (body, values) = synth_parts(&spec).unwrap();
        let file = encode_to_vec(&body, &values).unwrap();
        let view = PolicyView::decode(&file).unwrap();
        prop_assert_eq!(view.body(), &body);
        let decoded: Vec<u32> = view.values().iter().map(f32::to_bits).collect();
        let original: Vec<u32> = values.iter().map(|v| v.to_bits()).collect();
        prop_assert_eq!(decoded, original);
        // The allocator-free encoder writes the same bytes into an exact-size buffer.
        let mut buf = vec![0u8; file.len()];
        prop_assert_eq!(encode_into(&body, &values, &mut buf).unwrap(), file.len());
        prop_assert_eq!(&buf, &file);
        // Copying into a caller-owned buffer gives the same values.
        let mut copy = vec![0f32; values.len()];
        let copied = view.values().copy_into(&mut copy).unwrap();
        prop_assert_eq!(copied.len(), values.len());
        // Layers tile the stored values exactly.
        let last = view.layers().last().unwrap();
        prop_assert_eq!(last.biases + last.outputs, values.len());
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..600)) {
        let _ = PolicyView::decode(&bytes);
    }

    #[test]
    fn valid_header_with_garbage_after_never_panics(tail in prop::collection::vec(any::<u8>(), 0..400)) {
        let mut file = include_bytes!("golden/small.dxpl")[..24].to_vec();
        file.extend_from_slice(&tail);
        let _ = PolicyView::decode(&file);
    }
}
