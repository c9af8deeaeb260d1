//! The committed EDS (`can/jaco.eds`) is exactly what the dictionary's tables generate now, and
//! the tables agree with what the SDO server answers.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_runtime::canopen::eds;
use dex_runtime::{Controller, ControllerConfig};

fn fresh() -> String {
    let controller: Controller<'_, 64> = Controller::new(ControllerConfig::default());
    eds::generate(controller.device_state())
}

#[test]
fn committed_eds_matches_the_dictionary() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../can/jaco.eds");
    let fresh = fresh();
    if std::env::var_os("DEX_BLESS").is_some() {
        std::fs::write(&path, &fresh).unwrap();
    }
    let committed = std::fs::read_to_string(&path).expect("no can/jaco.eds: run with DEX_BLESS=1");
    assert_eq!(
        committed, fresh,
        "can/jaco.eds is stale: DEX_BLESS=1 cargo test -p dex-runtime --test eds"
    );
}

#[test]
fn every_object_has_a_section_and_sub_index_zero_counts_the_rest() {
    let text = fresh();
    for object in eds::objects() {
        assert!(text.contains(&format!("[{:04X}]\n", object.index)));
        let first = object.subs.first().unwrap();
        assert_eq!(first.sub, 0, "0x{:04X}", object.index);
        for (k, sub) in object.subs.iter().enumerate() {
            assert_eq!(
                usize::from(sub.sub),
                k,
                "0x{:04X} sub-indices in order",
                object.index
            );
        }
        // A record's or array's sub-index 0 is the highest sub-index (the error history's:
        // the number of errors recorded).
        if object.subs.len() > 1 && object.index != 0x1003 {
            assert_eq!(
                first.value,
                dex_runtime::canopen::Value::Const(object.subs.len() as u32 - 1),
                "0x{:04X}:0 counts its sub-objects",
                object.index
            );
        }
    }
}
