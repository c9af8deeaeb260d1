//! Fuzzes the policy decoder: any bytes must give a policy or a typed error, never a panic, and a
//! decoded policy must be loadable by the evaluator or refused with a typed error.
#![no_main]

use dex_policy::PolicyView;
use dex_runtime::mlp::Mlp;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // Copy into a 4-aligned buffer so the evaluator can borrow the values.
    let mut words = vec![0u32; data.len().div_ceil(4)];
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
    bytes[..data.len()].copy_from_slice(data);
    let file = &bytes[..data.len()];
    if let Ok(view) = PolicyView::decode(file) {
        if let Ok(mut mlp) = Mlp::<64>::new(&view) {
            let obs = vec![0.5f32; mlp.obs_dim()];
            let mut action = vec![0.0f32; mlp.act_dim()];
            let _ = mlp.act(&obs, &mut action);
        }
    }
});
