//! Links a crate's binaries, tests and extension module against the MuJoCo library fetched by
//! `scripts/setup-mujoco.sh` and records its folder as RUNPATH, so nothing needs `LD_LIBRARY_PATH`.
//! The build script of every crate that links MuJoCo: `dex-env` (here), and `dex-trainer` and
//! `dexstack` through `build = "../env/build.rs"` (a link argument does not pass to dependents).

use std::path::Path;

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") else {
        fail("MUJOCO_DYNAMIC_LINK_DIR is not set (it comes from .cargo/config.toml)");
    };
    let lib = Path::new(&dir).join("libmujoco.so");
    println!("cargo::rerun-if-changed={}", lib.display());
    if !lib.exists() {
        fail(&format!("{} does not exist", lib.display()));
    }
    println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
}

fn fail(why: &str) -> ! {
    eprintln!(
        "error: MuJoCo 3.17.0 not found: {why}.\n\
         Run `scripts/setup-mujoco.sh` from the repository root once; it fetches libmujoco and the \
         Jaco/Duplo assets into third_party/."
    );
    std::process::exit(1);
}
