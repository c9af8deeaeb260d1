//! Fuzzes the policy decoder: any bytes must give a policy or a typed error, never a panic, and a
//! decoded policy must be loadable by the evaluator or refused with a typed error.
//!
//! Each input is decoded twice: as it is (exercises header, length and CRC checks) and with its CRC
//! field recomputed (so mutations reach the postcard body, layer-chain and value checks).
#![no_main]

use dex_policy::{PolicyView, file_crc};
use dex_runtime::mlp::Mlp;
use libfuzzer_sys::fuzz_target;

fn check(file: &[u8]) {
    if let Ok(view) = PolicyView::decode(file)
        && let Ok(mut mlp) = Mlp::<64>::new(&view)
    {
        let obs = vec![0.5f32; mlp.obs_dim()];
        let mut action = vec![0.0f32; mlp.act_dim()];
        let _ = mlp.act(&obs, &mut action);
    }
}

fuzz_target!(|data: &[u8]| {
    // Copy into a 4-aligned buffer so the evaluator can borrow the values.
    let mut words = vec![0u32; data.len().div_ceil(4)];
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut words);
    bytes[..data.len()].copy_from_slice(data);
    check(&bytes[..data.len()]);
    if data.len() >= 24 {
        let crc = file_crc(&bytes[..data.len()]);
        bytes[20..24].copy_from_slice(&crc.to_le_bytes());
        check(&bytes[..data.len()]);
    }
});
