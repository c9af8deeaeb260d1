//! Helpers shared by dex-env's integration tests (each test file uses some of them).

#![allow(dead_code)]

use std::sync::OnceLock;

use dex_env::Scene;
use dex_runtime::interface::OBS_DIM;

/// The Jaco scene, loaded once per test process (needs `scripts/setup-mujoco.sh` to have run).
pub fn scene() -> &'static Scene {
    static SCENE: OnceLock<Scene> = OnceLock::new();
    SCENE.get_or_init(|| match Scene::load() {
        Ok(s) => s,
        Err(e) => panic!("{e}"),
    })
}

/// An observation's bits, for bit-for-bit comparisons.
pub fn bits(o: &[f32; OBS_DIM]) -> Vec<u32> {
    o.iter().map(|x| x.to_bits()).collect()
}
