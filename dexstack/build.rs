//! Records the folder of the MuJoCo library fetched by `scripts/setup-mujoco.sh` as the extension
//! module's RUNPATH (as `env/build.rs` and `trainer/build.rs` do for their tests and binaries), so `import dexstack`
//! finds `libmujoco.so` without `LD_LIBRARY_PATH`.

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
    println!("cargo::rustc-link-arg-cdylib=-Wl,-rpath,{dir}");
}

fn fail(why: &str) -> ! {
    eprintln!(
        "error: MuJoCo 3.17.0 not found: {why}.\n\
         Run `scripts/setup-mujoco.sh` from the repository root once; it fetches libmujoco and the \
         Jaco/Duplo assets into third_party/."
    );
    std::process::exit(1);
}
