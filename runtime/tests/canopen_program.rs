//! CiA 302-3 program download onto the policy slots: a block download into 0x1F50, verification,
//! an explicit start on 0x1F51, the identification in 0x1F56, the flash status in 0x1F57, and the
//! refusals (a bad file, a start with nothing staged, a download while operational) that leave the
//! running policy as it was.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;
use common::{REGION, bytes, regions};

use dex_runtime::can::messages::{NmtCommand, nmt_frame};
use dex_runtime::canopen::device::{DeviceObjects, DeviceState, Identity};
use dex_runtime::canopen::program::{
    FLASH_STATUS, FlashResult, PROGRAM_CONTROL, PROGRAM_DATA, PROGRAM_ID, ProgramObjects,
    ProgramState, control,
};
use dex_runtime::canopen::sdo::BLOCK_CRC;
use dex_runtime::canopen::{SdoFrame, SdoServer};
use dex_runtime::slots::CRC32;
use dex_runtime::testkit::jaco_policy;
use dex_runtime::{Controller, ControllerConfig, MockClock, PolicySlots, State};

const NODE: u8 = 0x10;

type Ctl = Controller<'static, 64>;

struct Node<'r> {
    ctl: Ctl,
    slots: PolicySlots<'r>,
    sdo: SdoServer,
    program: ProgramState,
}

impl Node<'_> {
    fn request(&mut self, f: SdoFrame) -> Option<SdoFrame> {
        let mut od = ProgramObjects {
            slots: &mut self.slots,
            host: &mut self.ctl,
            state: &mut self.program,
        };
        self.sdo.on_request(&f, 0, &mut od)
    }

    fn read_u32(&mut self, index: u16) -> u32 {
        let r = self
            .request(req(&[0x40, index as u8, (index >> 8) as u8, 1]))
            .unwrap();
        assert_eq!(
            r[0] & 0xF3,
            0x43,
            "expedited upload of {index:#06x}: {r:02x?}"
        );
        let n = 4 - usize::from((r[0] >> 2) & 3);
        let mut v = [0u8; 4];
        v[..n].copy_from_slice(&r[4..4 + n]);
        u32::from_le_bytes(v)
    }

    fn write_u8(&mut self, index: u16, value: u8) -> SdoFrame {
        self.request(req(&[0x2F, index as u8, (index >> 8) as u8, 1, value]))
            .unwrap()
    }

    /// A block download of `file` into 0x1F50:1; the last response.
    fn download(&mut self, file: &[u8]) -> SdoFrame {
        let size = (file.len() as u32).to_le_bytes();
        let i = PROGRAM_DATA.to_le_bytes();
        let r = self
            .request(req(&[
                0xC6, i[0], i[1], 1, size[0], size[1], size[2], size[3],
            ]))
            .unwrap();
        if r[0] == 0x80 {
            return r;
        }
        let chunks: Vec<&[u8]> = file.chunks(7).collect();
        let mut next = 0;
        while next < chunks.len() {
            let blksize = usize::from(r[4]);
            let mut ack = None;
            for seq in 1..=blksize {
                let k = next + seq - 1;
                if k >= chunks.len() {
                    break;
                }
                let mut f = [0u8; 8];
                f[0] = (u8::from(k + 1 == chunks.len()) << 7) | seq as u8;
                f[1..1 + chunks[k].len()].copy_from_slice(chunks[k]);
                ack = self.request(f);
            }
            let ack = ack.unwrap();
            if ack[0] == 0x80 {
                return ack;
            }
            next += usize::from(ack[1]);
        }
        let unused = (7 - chunks.last().unwrap().len()) as u8;
        let c = BLOCK_CRC.checksum(file).to_le_bytes();
        self.request(req(&[0xC1 | (unused << 2), c[0], c[1]]))
            .unwrap()
    }
}

fn req(bytes: &[u8]) -> SdoFrame {
    let mut f = [0u8; 8];
    f[..bytes.len()].copy_from_slice(bytes);
    f
}

fn abort_code(f: &SdoFrame) -> Option<u32> {
    (f[0] == 0x80).then(|| u32::from_le_bytes([f[4], f[5], f[6], f[7]]))
}

fn node<'r>(a: &'r mut [u8], b: &'r mut [u8]) -> Node<'r> {
    let mut ctl = Ctl::new(ControllerConfig::default());
    ctl.poll(&MockClock::new(0));
    Node {
        ctl,
        slots: PolicySlots::mount(a, b).unwrap(),
        sdo: SdoServer::default(),
        program: ProgramState::default(),
    }
}

#[test]
fn download_verify_start_and_identify() {
    let (mut ra, mut rb) = regions();
    let mut n = node(bytes(&mut ra), bytes(&mut rb));
    let file = jaco_policy(&[64], 7).unwrap();
    assert_eq!(n.read_u32(PROGRAM_ID), 0, "nothing active yet");
    assert_eq!(n.download(&file)[0], 0xA1);
    // Verified and staged, not active: a staged file waits for an explicit start.
    assert_eq!(n.read_u32(FLASH_STATUS), 1 << 8);
    assert_eq!(n.read_u32(PROGRAM_ID), 0);
    assert!(n.ctl.policy_info().is_none());
    assert_eq!(n.write_u8(PROGRAM_CONTROL, control::START)[0], 0x60);
    assert_eq!(n.read_u32(PROGRAM_ID), CRC32.checksum(&file));
    assert_eq!(n.read_u32(FLASH_STATUS), 0);
    assert!(n.ctl.policy_info().is_some());
    assert_eq!(
        n.read_u32(PROGRAM_CONTROL),
        0,
        "pre-operational: not running"
    );

    // A second file, then a roll-back to the first.
    let second = jaco_policy(&[64], 8).unwrap();
    assert_eq!(n.download(&second)[0], 0xA1);
    assert_eq!(n.write_u8(PROGRAM_CONTROL, control::START)[0], 0x60);
    assert_eq!(n.read_u32(PROGRAM_ID), CRC32.checksum(&second));
    assert_eq!(n.write_u8(PROGRAM_CONTROL, control::ROLL_BACK)[0], 0x60);
    assert_eq!(n.read_u32(PROGRAM_ID), CRC32.checksum(&file));
}

#[test]
fn refusals_leave_the_running_policy() {
    let (mut ra, mut rb) = regions();
    let mut n = node(bytes(&mut ra), bytes(&mut rb));
    let file = jaco_policy(&[64], 7).unwrap();
    n.download(&file);
    n.write_u8(PROGRAM_CONTROL, control::START);
    let active = CRC32.checksum(&file);

    // Start with nothing staged: 0x0800_0024, flash status "no program".
    let r = n.write_u8(PROGRAM_CONTROL, control::START);
    assert_eq!(abort_code(&r), Some(0x0800_0024));
    assert_eq!(
        n.read_u32(FLASH_STATUS) >> 1 & 0x7F,
        FlashResult::NoProgram as u32
    );

    // A corrupt file: 0x0800_0020, nothing staged, the active policy unchanged.
    let mut bad = jaco_policy(&[64], 9).unwrap();
    bad[100] ^= 0x40;
    assert_eq!(abort_code(&n.download(&bad)), Some(0x0800_0020));
    assert_eq!(n.read_u32(FLASH_STATUS), (FlashResult::Format as u32) << 1);
    assert_eq!(n.read_u32(PROGRAM_ID), active);
    // A file larger than a slot is refused at the initiate.
    assert_eq!(
        abort_code(&n.download(&vec![0u8; REGION])),
        Some(0x0607_0012)
    );

    // Clear discards a staged file; reset and unknown values are invalid.
    n.download(&jaco_policy(&[64], 10).unwrap());
    assert_eq!(n.read_u32(FLASH_STATUS), 1 << 8);
    assert_eq!(n.write_u8(PROGRAM_CONTROL, control::CLEAR)[0], 0x60);
    assert_eq!(n.read_u32(FLASH_STATUS), 0);
    for v in [control::RESET, 7] {
        assert_eq!(
            abort_code(&n.write_u8(PROGRAM_CONTROL, v)),
            Some(0x0609_0030)
        );
    }

    // Operational: downloads and starts are refused (0x0800_0022); stop leaves operational at
    // the next cycle.
    let clock = MockClock::new(0);
    n.ctl.on_frame(&nmt_frame(NmtCommand::Start, NODE), &clock);
    assert_eq!(n.ctl.state(), State::Operational);
    assert_eq!(n.read_u32(PROGRAM_CONTROL), 1);
    assert_eq!(abort_code(&n.download(&file)), Some(0x0800_0022));
    assert_eq!(
        abort_code(&n.write_u8(PROGRAM_CONTROL, control::START)),
        Some(0x0800_0022)
    );
    assert_eq!(n.write_u8(PROGRAM_CONTROL, control::STOP)[0], 0x60);
    n.ctl.poll(&MockClock::new(60_000));
    assert_eq!(n.ctl.state(), State::PreOperational);
    assert_eq!(n.read_u32(PROGRAM_ID), active);

    // Read-only and unknown objects.
    let r = n.request(req(&[0x23, 0x56, 0x1F, 1, 1, 2, 3, 4])).unwrap();
    assert_eq!(abort_code(&r), Some(0x0601_0002));
    let r = n.request(req(&[0x40, 0x50, 0x1F, 1])).unwrap();
    assert_eq!(abort_code(&r), Some(0x0601_0001));
    let r = n.request(req(&[0x40, 0x51, 0x1F, 2])).unwrap();
    assert_eq!(abort_code(&r), Some(0x0609_0011));
}

#[test]
fn a_download_cut_in_the_middle_keeps_the_old_policy_and_reports_it() {
    let (mut ra, mut rb) = regions();
    let mut n = node(bytes(&mut ra), bytes(&mut rb));
    let file = jaco_policy(&[64], 7).unwrap();
    n.download(&file);
    n.write_u8(PROGRAM_CONTROL, control::START);
    let next = jaco_policy(&[64], 11).unwrap();
    let size = (next.len() as u32).to_le_bytes();
    n.request(req(&[
        0xC6, 0x50, 0x1F, 1, size[0], size[1], size[2], size[3],
    ]))
    .unwrap();
    for seq in 1..=20u8 {
        let mut f = [seq; 8];
        f[0] = seq;
        n.request(f);
    }
    // The client goes silent in the middle of a sub-block: the server's timeout aborts the
    // transfer (0x0504_0000), the slot drops it, and the flash status says so.
    let mut od = ProgramObjects {
        slots: &mut n.slots,
        host: &mut n.ctl,
        state: &mut n.program,
    };
    assert_eq!(n.sdo.poll(500, &mut od), None);
    let r = n.sdo.poll(10_000, &mut od).unwrap();
    assert_eq!(abort_code(&r), Some(0x0504_0000));
    assert_eq!(n.read_u32(FLASH_STATUS), (FlashResult::Aborted as u32) << 1);
    assert_eq!(n.read_u32(PROGRAM_ID), CRC32.checksum(&file));
    let r = n.write_u8(PROGRAM_CONTROL, control::START);
    assert_eq!(abort_code(&r), Some(0x0800_0024));
}

#[test]
fn the_communication_objects_read_and_write_through_the_same_server() {
    let (mut ra, mut rb) = regions();
    let mut n = node(bytes(&mut ra), bytes(&mut rb));
    let mut device = DeviceState::new(
        Identity {
            serial: 0x1234,
            ..Identity::default()
        },
        500,
    );
    let file = jaco_policy(&[64], 7).unwrap();
    let serve = |n: &mut Node<'_>, device: &mut DeviceState, f: SdoFrame| {
        let program = ProgramObjects {
            slots: &mut n.slots,
            host: &mut n.ctl,
            state: &mut n.program,
        };
        let mut od = DeviceObjects::new(device, program);
        n.sdo.on_request(&f, 0, &mut od).unwrap()
    };
    let read = |n: &mut Node<'_>, device: &mut DeviceState, index: u16, sub: u8| {
        let r = serve(
            n,
            device,
            req(&[0x40, index as u8, (index >> 8) as u8, sub]),
        );
        assert_eq!(r[0] & 0xF3, 0x43, "{index:#06x}:{sub}: {r:02x?}");
        u32::from_le_bytes([r[4], r[5], r[6], r[7]])
    };
    assert_eq!(read(&mut n, &mut device, 0x1000, 0), 0);
    assert_eq!(read(&mut n, &mut device, 0x1018, 0), 4);
    assert_eq!(
        read(&mut n, &mut device, 0x1018, 2),
        Identity::default().product
    );
    assert_eq!(read(&mut n, &mut device, 0x1018, 4), 0x1234);
    assert_eq!(read(&mut n, &mut device, 0x1017, 0), 500);
    assert_eq!(read(&mut n, &mut device, 0x1001, 0), 0);
    // Program download goes through the same dictionary.
    n.download(&file);
    n.write_u8(PROGRAM_CONTROL, control::START);
    assert_eq!(read(&mut n, &mut device, 0x2000, 3), CRC32.checksum(&file));
    assert_eq!(
        read(&mut n, &mut device, 0x2000, 5),
        1,
        "first slot generation"
    );
    // Heartbeat time and error behaviour are writable; identity is not.
    let r = serve(&mut n, &mut device, req(&[0x2B, 0x17, 0x10, 0, 0xE8, 0x03]));
    assert_eq!(r[0], 0x60);
    assert_eq!(device.heartbeat_ms, 1000);
    let r = serve(&mut n, &mut device, req(&[0x2F, 0x29, 0x10, 1, 3]));
    assert_eq!(abort_code(&r), Some(0x0609_0031));
    let r = serve(&mut n, &mut device, req(&[0x23, 0x18, 0x10, 4, 1, 0, 0, 0]));
    assert_eq!(abort_code(&r), Some(0x0601_0002));
    // The error history: newest first, cleared by writing 0 to sub-index 0.
    device.record_emergency(0x8250, 1);
    device.record_emergency(0xFF02, 2);
    assert_eq!(read(&mut n, &mut device, 0x1003, 0), 2);
    assert_eq!(read(&mut n, &mut device, 0x1003, 1), 0x0002_FF02);
    assert_eq!(read(&mut n, &mut device, 0x1003, 2), 0x0001_8250);
    let r = serve(&mut n, &mut device, req(&[0x40, 0x03, 0x10, 3]));
    assert_eq!(abort_code(&r), Some(0x0800_0024));
    let r = serve(&mut n, &mut device, req(&[0x2F, 0x03, 0x10, 0, 0]));
    assert_eq!(r[0], 0x60);
    assert_eq!(read(&mut n, &mut device, 0x1003, 0), 0);
    let r = serve(&mut n, &mut device, req(&[0x40, 0x00, 0x30, 0]));
    assert_eq!(abort_code(&r), Some(0x0602_0000));
    let r = serve(&mut n, &mut device, req(&[0x40, 0x18, 0x10, 9]));
    assert_eq!(abort_code(&r), Some(0x0609_0011));
}
