//! The committed EDSs (`can/jaco.eds`, classic layout; `can/jaco_fd.eds`, CAN FD layout) are
//! exactly what the dictionary's tables generate now, and the tables agree with what the codecs
//! put on the bus: identifiers, frame lengths and every byte of the mapped frames.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use dex_runtime::can::FrameLayout;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::canopen::{Object, Value, eds};
use dex_runtime::{Controller, ControllerConfig};

const LAYOUTS: [FrameLayout; 2] = [FrameLayout::Classic, FrameLayout::Fd];

fn fresh(layout: FrameLayout) -> String {
    let controller: Controller<'_, 64> = Controller::new(ControllerConfig::default());
    let fd: Controller<'_, 64, dex_runtime::can::AnyFrame> =
        Controller::new_fd(ControllerConfig::default());
    assert_eq!(controller.device_state(), fd.device_state());
    eds::generate(controller.device_state(), layout)
}

#[test]
fn committed_eds_files_match_the_dictionary() {
    for layout in LAYOUTS {
        let name = eds::file_name(layout);
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../can")
            .join(name);
        let fresh = fresh(layout);
        if std::env::var_os("DEX_BLESS").is_some() {
            std::fs::write(&path, &fresh).unwrap();
        }
        let committed = std::fs::read_to_string(&path)
            .unwrap_or_else(|_| panic!("no can/{name}: run with DEX_BLESS=1"));
        assert_eq!(
            committed, fresh,
            "can/{name} is stale: DEX_BLESS=1 cargo test -p dex-runtime --test eds"
        );
    }
}

#[test]
fn every_object_has_a_section_and_sub_index_zero_counts_the_rest() {
    for layout in LAYOUTS {
        let text = fresh(layout);
        for object in eds::objects(layout) {
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
                    Value::Const(object.subs.len() as u32 - 1),
                    "0x{:04X}:0 counts its sub-objects",
                    object.index
                );
            }
        }
    }
}

/// The mapping entries of `m`: (index, sub-index, bits).
fn entries(m: &Object) -> Vec<(u16, u8, u32)> {
    let Value::Const(n) = m.subs[0].value else {
        panic!()
    };
    assert_eq!(n as usize, m.subs.len() - 1);
    m.subs[1..]
        .iter()
        .map(|s| {
            let Value::Const(e) = s.value else { panic!() };
            ((e >> 16) as u16, (e >> 8) as u8, e & 0xFF)
        })
        .collect()
}

/// The PDO objects describe the frames the codec makes: the COB-IDs of `rpdo_cob_id` and
/// `tpdo_cob_id` for every node id, mappings as long as the frames, every mapped object present;
/// in the FD layout exactly RPDO 0-1, TPDO 0, 3, 4.
#[test]
fn pdo_objects_describe_the_codec_frames() {
    use dex_runtime::can::fd_messages::{FD_ACTION_LEN, FD_OBS_FRAMES, FD_OBS_LEN};
    use dex_runtime::can::messages::{
        OBS_FRAMES, POLICY_INFO_TPDO, STATUS_LEN, STATUS_TPDO, TPDOS, rpdo_cob_id, tpdo_cob_id,
    };
    use dex_runtime::canopen::pdo::{DUMMY_INTEGER16, objects};
    for layout in LAYOUTS {
        let table = objects(layout);
        let object = |index: u16| table.iter().find(|o| o.index == index);
        let all = eds::objects(layout);
        let (rpdos, tpdos): (Vec<usize>, Vec<usize>) = match layout {
            FrameLayout::Classic => ((0..OBS_FRAMES).collect(), (0..TPDOS).collect()),
            FrameLayout::Fd => (
                (0..FD_OBS_FRAMES).collect(),
                vec![0, POLICY_INFO_TPDO, STATUS_TPDO],
            ),
        };
        let len_of = |comm: u16, k: usize| match (layout, comm, k) {
            (_, 0x1800, k) if k == STATUS_TPDO => STATUS_LEN,
            (FrameLayout::Fd, 0x1400, _) => FD_OBS_LEN,
            (FrameLayout::Fd, 0x1800, 0) => FD_ACTION_LEN,
            _ => 8,
        };
        type CobId = fn(u8, usize) -> u16;
        let tables: [(u16, u16, &[usize], CobId); 2] = [
            (0x1400, 0x1600, &rpdos, rpdo_cob_id as fn(u8, usize) -> u16),
            (0x1800, 0x1A00, &tpdos, tpdo_cob_id),
        ];
        for (comm, map, present, cob) in tables {
            for k in 0..0x200u16 {
                assert_eq!(
                    object(comm + k).is_some(),
                    present.contains(&usize::from(k)),
                    "{layout:?} 0x{:04X}",
                    comm + k
                );
                assert_eq!(object(comm + k).is_some(), object(map + k).is_some());
            }
            for &k in present {
                let Value::NodeId(base) = object(comm + k as u16).unwrap().subs[1].value else {
                    panic!("0x{:04X}:1 is node-relative", comm + k as u16);
                };
                for node in 1..=31u8 {
                    assert_eq!(base + u32::from(node), u32::from(cob(node, k)));
                }
                let mut bits = 0;
                for (index, sub, b) in entries(object(map + k as u16).unwrap()) {
                    bits += b;
                    assert!(
                        index == DUMMY_INTEGER16
                            || all
                                .iter()
                                .any(|o| o.index == index && o.subs.iter().any(|x| x.sub == sub)),
                        "0x{index:04X}:{sub} mapped but not in the dictionary"
                    );
                }
                assert_eq!(
                    bits as usize,
                    8 * len_of(comm, k),
                    "{layout:?} PDO 0x{:04X}",
                    map + k as u16
                );
            }
        }
    }
}

/// `frame`'s bytes as the mapping `m` describes them: each entry's bytes at its offset, checked
/// against what the mapped object holds (`value(index, sub)`: an observation or action value's
/// raw i16, a frame's E2E header; the dummy's bytes are zero).
fn check_mapping(m: &Object, frame: &[u8], value: impl Fn(u16, u8) -> u16) {
    let mut at = 0;
    for (index, sub, bits) in entries(m) {
        assert_eq!(bits, 16, "every mapped object is 16 bits here");
        let got = u16::from_le_bytes([frame[at], frame[at + 1]]);
        let want = if index == dex_runtime::canopen::pdo::DUMMY_INTEGER16 {
            0
        } else {
            value(index, sub)
        };
        assert_eq!(
            got, want,
            "0x{:04X} entry 0x{index:04X}:{sub} at byte {at}",
            m.index
        );
        at += 2;
    }
    assert_eq!(at, frame.len(), "0x{:04X} maps the whole frame", m.index);
}

/// Every byte of the observation and action frames of each layout is where its PDO mapping says:
/// the E2E header (0x2101:k+1 / 0x2201:k+1), the values of 0x2100 / 0x2200, the zero padding.
#[test]
fn pdo_mappings_describe_every_byte_of_the_frames() {
    use dex_runtime::can::fd_messages::{FD_OBS_FRAMES, encode_action_fd, encode_observation_fd};
    use dex_runtime::can::messages::{
        ACTION_FRAMES, ACTION_QUANTITY, OBS_FRAMES, encode_action, encode_observation, to_raw,
    };
    use dex_runtime::canopen::pdo::{
        ACTION_VALUES, OBSERVATION_E2E, OBSERVATION_VALUES, TPDO_E2E, objects,
    };
    use dex_runtime::interface::{ACT_DIM, OBS_DIM, Quantity, quantity_of};
    let obs: [f32; OBS_DIM] = core::array::from_fn(|i| ((i as f32) * 0.37).sin() * 0.9);
    let action: [f32; ACT_DIM] = core::array::from_fn(|j| j as f32 * 0.07 - 0.3);
    let obs_raw = |i: usize| to_raw(obs[i], quantity_of(i).map_or(1.0, Quantity::lsb)) as u16;
    let act_raw = |j: usize| to_raw(action[j], ACTION_QUANTITY.lsb()) as u16;
    for layout in LAYOUTS {
        let table = objects(layout);
        let map = |index: u16| table.iter().find(|o| o.index == index).unwrap();
        let (obs_frames, action_frames): (Vec<Vec<u8>>, Vec<Vec<u8>>) = match layout {
            FrameLayout::Classic => (
                encode_observation(0x10, &obs, 3, &mut [E2eSender::default(); OBS_FRAMES])
                    .iter()
                    .map(|f| embedded_can::Frame::data(f).to_vec())
                    .collect(),
                encode_action(0x10, &action, 3, &mut [E2eSender::default(); ACTION_FRAMES])
                    .iter()
                    .map(|f| embedded_can::Frame::data(f).to_vec())
                    .collect(),
            ),
            FrameLayout::Fd => (
                encode_observation_fd(0x10, &obs, 3, &mut [E2eSender::default(); FD_OBS_FRAMES])
                    .iter()
                    .map(|f| embedded_can::Frame::data(f).to_vec())
                    .collect(),
                vec![
                    embedded_can::Frame::data(&encode_action_fd(
                        0x10,
                        &action,
                        3,
                        &mut E2eSender::default(),
                    ))
                    .to_vec(),
                ],
            ),
        };
        assert_eq!(obs_frames.len(), layout.observation_frames());
        assert_eq!(action_frames.len(), layout.action_frames());
        for (k, frame) in obs_frames.iter().enumerate() {
            let header = u16::from_le_bytes([frame[0], frame[1]]);
            check_mapping(map(0x1600 + k as u16), frame, |index, sub| match index {
                OBSERVATION_E2E if usize::from(sub) == k + 1 => header,
                OBSERVATION_VALUES => obs_raw(usize::from(sub) - 1),
                _ => panic!("0x{index:04X}:{sub} in observation frame {k}"),
            });
        }
        for (k, frame) in action_frames.iter().enumerate() {
            let header = u16::from_le_bytes([frame[0], frame[1]]);
            check_mapping(map(0x1A00 + k as u16), frame, |index, sub| match index {
                TPDO_E2E if usize::from(sub) == k + 1 => header,
                ACTION_VALUES => act_raw(usize::from(sub) - 1),
                _ => panic!("0x{index:04X}:{sub} in action frame {k}"),
            });
        }
    }
}
