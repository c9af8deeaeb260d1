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

/// The PDO objects describe the frames the codec makes: the COB-IDs of `rpdo_cob_id` and
/// `tpdo_cob_id` for every node id, mappings as long as the frames, every mapped object present.
#[test]
fn pdo_objects_describe_the_codec_frames() {
    use dex_runtime::can::messages::{
        OBS_FRAMES, STATUS_LEN, STATUS_TPDO, TPDOS, rpdo_cob_id, tpdo_cob_id,
    };
    use dex_runtime::canopen::Value;
    use dex_runtime::canopen::pdo::{DUMMY_INTEGER16, OBJECTS};
    let object = |index: u16| OBJECTS.iter().find(|o| o.index == index).unwrap();
    let all = eds::objects();
    type CobId = fn(u8, usize) -> u16;
    let tables: [(u16, u16, usize, CobId); 2] = [
        (
            0x1400,
            0x1600,
            OBS_FRAMES,
            rpdo_cob_id as fn(u8, usize) -> u16,
        ),
        (0x1800, 0x1A00, TPDOS, tpdo_cob_id),
    ];
    for (comm, map, count, cob) in tables {
        for k in 0..count {
            let Value::NodeId(base) = object(comm + k as u16).subs[1].value else {
                panic!("0x{:04X}:1 is node-relative", comm + k as u16);
            };
            for node in 1..=31u8 {
                assert_eq!(base + u32::from(node), u32::from(cob(node, k)));
            }
            let m = object(map + k as u16);
            let Value::Const(n) = m.subs[0].value else {
                panic!()
            };
            assert_eq!(n as usize, m.subs.len() - 1);
            let mut bits = 0;
            for s in &m.subs[1..] {
                let Value::Const(e) = s.value else { panic!() };
                let (index, sub) = ((e >> 16) as u16, (e >> 8) as u8);
                bits += e & 0xFF;
                assert!(
                    index == DUMMY_INTEGER16
                        || all
                            .iter()
                            .any(|o| o.index == index && o.subs.iter().any(|x| x.sub == sub)),
                    "0x{index:04X}:{sub} mapped but not in the dictionary"
                );
            }
            let len = if comm == 0x1800 && k == STATUS_TPDO {
                STATUS_LEN
            } else {
                8
            };
            assert_eq!(bits as usize, 8 * len, "PDO 0x{:04X}", map + k as u16);
        }
    }
}
