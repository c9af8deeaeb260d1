//! The SDO server serves the PDO objects of its controller's frame layout: an FD controller
//! (`Controller::new_fd`) answers the FD mapping (RPDO 0-1 of 48 bytes, TPDO 0 of 20 bytes; no
//! RPDO 2-14, no TPDO 1-2), a classic controller the classic mapping, unchanged; and the mapped
//! live objects hold what went over the bus in each layout.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;
use common::{bytes, regions};

use dex_policy::PolicyView;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::fd_messages::{FD_OBS_FRAMES, encode_observation_fd};
use dex_runtime::can::messages::{
    ACTION_QUANTITY, NmtCommand, OBS_FRAMES, encode_observation, nmt_frame, rpdo_cob_id, to_raw,
    tpdo_cob_id,
};
use dex_runtime::can::{AnyFrame, CanFrame, TxFrame};
use dex_runtime::canopen::Value;
use dex_runtime::canopen::pdo::{FD_OBJECTS, OBJECTS};
use dex_runtime::controller::SDO_RESPONSE_BASE;
use dex_runtime::interface::{Quantity, quantity_of};
use dex_runtime::testkit::{aligned_copy, observation_trace, sdo_abort_code, sdo_read};
use dex_runtime::{Controller, ControllerConfig, MockClock, PolicySlots, State};
use embedded_can::{Frame, Id};

const NODE: u8 = 0x10;
const NO_OBJECT: u32 = 0x0602_0000;
const NO_SUB_INDEX: u32 = 0x0609_0011;

/// An SDO upload of `index`:`sub` through the controller: the value (expedited) or the abort code.
fn upload<F: TxFrame + Frame>(
    c: &mut Controller<'_, 64, F>,
    slots: &mut PolicySlots<'_>,
    index: u16,
    sub: u8,
) -> Result<u32, u32> {
    let out = c.on_frame_slots(
        &sdo_read(NODE, index, sub).unwrap(),
        &MockClock::new(0),
        slots,
    );
    let responses: Vec<&F> = out
        .iter()
        .filter(|f| {
            f.id()
                == Id::Standard(
                    embedded_can::StandardId::new(SDO_RESPONSE_BASE + u16::from(NODE)).unwrap(),
                )
        })
        .collect();
    assert_eq!(responses.len(), 1, "{index:#06x}:{sub}");
    let d = responses[0].data();
    if let Some(code) = sdo_abort_code(d) {
        return Err(code);
    }
    assert_eq!(
        d[0] & 0xF3,
        0x43,
        "{index:#06x}:{sub}: expedited upload {d:02x?}"
    );
    let n = 4 - usize::from((d[0] >> 2) & 3);
    let mut v = [0u8; 4];
    v[..n].copy_from_slice(&d[4..4 + n]);
    Ok(u32::from_le_bytes(v))
}

/// Mapping record `index` as the server answers it: the count, then each entry.
fn mapping<F: TxFrame + Frame>(
    c: &mut Controller<'_, 64, F>,
    slots: &mut PolicySlots<'_>,
    index: u16,
) -> Vec<u32> {
    let n = upload(c, slots, index, 0).unwrap();
    (1..=n as u8)
        .map(|s| upload(c, slots, index, s).unwrap())
        .collect()
}

/// Entry `index`:`sub`, 16 bits (CiA 301's mapping layout), written out independently of the
/// tables.
fn e16(index: u16, sub: u8) -> u32 {
    (u32::from(index) << 16) | (u32::from(sub) << 8) | 16
}

#[test]
fn an_fd_controller_serves_the_fd_mapping() {
    let (mut ra, mut rb) = regions();
    let mut slots = PolicySlots::mount(bytes(&mut ra), bytes(&mut rb)).unwrap();
    let mut c = Controller::<64, AnyFrame>::new_fd(ControllerConfig::default());
    c.poll(&MockClock::new(0));
    // RPDO 0 and 1: 24 entries each, the E2E header, 22 values, the dummy INTEGER16 (bytes 46-47).
    for k in 0..2u16 {
        let mut want = vec![e16(0x2101, k as u8 + 1)];
        want.extend((1..=22).map(|s| e16(0x2100, 22 * k as u8 + s)));
        want.push(e16(0x0003, 0));
        assert_eq!(mapping(&mut c, &mut slots, 0x1600 + k), want, "RPDO {k}");
        assert_eq!(
            upload(&mut c, &mut slots, 0x1400 + k, 1),
            Ok(u32::from(rpdo_cob_id(NODE, k as usize)))
        );
        assert_eq!(upload(&mut c, &mut slots, 0x1400 + k, 2), Ok(0xFE));
    }
    // TPDO 0: 10 entries, the E2E header and the 9 action values (20 bytes).
    let mut want = vec![e16(0x2201, 1)];
    want.extend((1..=9).map(|s| e16(0x2200, s)));
    assert_eq!(mapping(&mut c, &mut slots, 0x1A00), want);
    // Policy information and status: classic frames, as in the classic layout.
    for k in [0u16, 3, 4] {
        assert_eq!(
            upload(&mut c, &mut slots, 0x1800 + k, 1),
            Ok(u32::from(tpdo_cob_id(NODE, k as usize)))
        );
    }
    assert_eq!(
        mapping(&mut c, &mut slots, 0x1A04),
        [e16(0x2201, 5), 0x2002_0108, 0x2002_0208, 0x2001_0008]
    );
    // No other PDOs, and two observation headers.
    for index in [
        0x1402, 0x140E, 0x1602, 0x160E, 0x1801, 0x1802, 0x1A01, 0x1A02,
    ] {
        assert_eq!(
            upload(&mut c, &mut slots, index, 0),
            Err(NO_OBJECT),
            "{index:#06x}"
        );
    }
    assert_eq!(upload(&mut c, &mut slots, 0x2101, 0), Ok(2));
    assert_eq!(upload(&mut c, &mut slots, 0x2101, 3), Err(NO_SUB_INDEX));
    // Every described sub-object answers its table value; the classic-only objects are absent.
    check_served(&mut c, &mut slots, &FD_OBJECTS);
    for o in OBJECTS
        .iter()
        .filter(|o| FD_OBJECTS.iter().all(|f| f.index != o.index))
    {
        assert_eq!(upload(&mut c, &mut slots, o.index, 0), Err(NO_OBJECT));
    }
}

#[test]
fn a_classic_controller_serves_the_classic_mapping_unchanged() {
    let (mut ra, mut rb) = regions();
    let mut slots = PolicySlots::mount(bytes(&mut ra), bytes(&mut rb)).unwrap();
    let mut c = Controller::<64>::new(ControllerConfig::default());
    c.poll(&MockClock::new(0));
    for k in 0..15u16 {
        let mut want = vec![e16(0x2101, k as u8 + 1)];
        for s in 0..3u8 {
            let value = 3 * k as u8 + s + 1;
            want.push(if value <= 44 {
                e16(0x2100, value)
            } else {
                e16(0x0003, 0)
            });
        }
        assert_eq!(mapping(&mut c, &mut slots, 0x1600 + k), want, "RPDO {k}");
        assert_eq!(
            upload(&mut c, &mut slots, 0x1400 + k, 1),
            Ok(u32::from(rpdo_cob_id(NODE, k as usize)))
        );
    }
    for k in 0..3u16 {
        let want: Vec<u32> = [e16(0x2201, k as u8 + 1)]
            .into_iter()
            .chain((1..=3).map(|s| e16(0x2200, 3 * k as u8 + s)))
            .collect();
        assert_eq!(mapping(&mut c, &mut slots, 0x1A00 + k), want, "TPDO {k}");
    }
    for k in 0..5u16 {
        assert_eq!(
            upload(&mut c, &mut slots, 0x1800 + k, 1),
            Ok(u32::from(tpdo_cob_id(NODE, k as usize)))
        );
    }
    assert_eq!(upload(&mut c, &mut slots, 0x2101, 0), Ok(15));
    assert_eq!(upload(&mut c, &mut slots, 0x140F, 0), Err(NO_OBJECT));
    check_served(&mut c, &mut slots, &OBJECTS);
}

/// Every sub-object of `table` with a static value answers it (COB-IDs for this node).
fn check_served<F: TxFrame + Frame>(
    c: &mut Controller<'_, 64, F>,
    slots: &mut PolicySlots<'_>,
    table: &[dex_runtime::canopen::Object],
) {
    for o in table {
        for s in o.subs {
            let want = match s.value {
                Value::Const(v) => v,
                Value::NodeId(base) => base + u32::from(NODE),
                _ => continue,
            };
            assert_eq!(
                upload(c, slots, o.index, s.sub),
                Ok(want),
                "{:#06x}:{}",
                o.index,
                s.sub
            );
        }
    }
}

/// The live objects the FD mapping names hold what the FD frames carried: 0x2101:k+1 each FD
/// observation frame's header, 0x2100 its values, 0x2201:1 the FD action frame's header.
#[test]
fn the_mapped_objects_hold_the_fd_frames_values() {
    let file = aligned_copy(include_bytes!("golden/jaco_64.dxpl"));
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let (mut ra, mut rb) = regions();
    let mut slots = PolicySlots::mount(bytes(&mut ra), bytes(&mut rb)).unwrap();
    let clock = MockClock::new(0);
    let mut fd = Controller::<64, AnyFrame>::new_fd(ControllerConfig::default());
    let mut classic = Controller::<64>::new(ControllerConfig::default());
    fd.poll(&clock);
    classic.poll(&clock);
    fd.load_policy(&view).unwrap();
    classic.load_policy(&view).unwrap();
    fd.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    classic.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    assert_eq!(
        (fd.state(), classic.state()),
        (State::Operational, State::Operational)
    );
    let obs = observation_trace(1, 3)[0];
    let fd_frames =
        encode_observation_fd(NODE, &obs, 5, &mut [E2eSender::default(); FD_OBS_FRAMES]);
    let mut action = None;
    for f in &fd_frames {
        for out in fd.on_frame(f, &clock) {
            if let AnyFrame::Fd(a) = out {
                action = Some(a);
            }
        }
    }
    let action = action.expect("the FD action frame");
    let classic_frames: [CanFrame; OBS_FRAMES] =
        encode_observation(NODE, &obs, 5, &mut [E2eSender::default(); OBS_FRAMES]);
    for f in &classic_frames {
        classic.on_frame(f, &clock);
    }
    for (k, f) in fd_frames.iter().enumerate() {
        assert_eq!(
            upload(&mut fd, &mut slots, 0x2101, k as u8 + 1),
            Ok(u32::from(u16::from_le_bytes([f.data()[0], f.data()[1]])))
        );
    }
    assert_eq!(
        upload(&mut fd, &mut slots, 0x2201, 1),
        Ok(u32::from(u16::from_le_bytes([
            action.data()[0],
            action.data()[1]
        ])))
    );
    for (i, &v) in obs.iter().enumerate() {
        let raw = to_raw(v, quantity_of(i).map_or(1.0, Quantity::lsb)) as u16;
        let sub = i as u8 + 1;
        assert_eq!(upload(&mut fd, &mut slots, 0x2100, sub), Ok(u32::from(raw)));
        assert_eq!(
            upload(&mut classic, &mut slots, 0x2100, sub),
            Ok(u32::from(raw))
        );
    }
    for j in 0..9u8 {
        let at = 2 + 2 * usize::from(j);
        let raw = u16::from_le_bytes([action.data()[at], action.data()[at + 1]]);
        assert_eq!(
            upload(&mut fd, &mut slots, 0x2200, j + 1),
            Ok(u32::from(raw))
        );
        let classic_raw = to_raw(classic.last_action()[usize::from(j)], ACTION_QUANTITY.lsb());
        assert_eq!(raw, classic_raw as u16, "the same action in both layouts");
    }
}
