//! The harness of the program-download target (`fuzz_targets/program_download.rs`, issue #29): the
//! controller's own flashing path, its CiA 301 SDO server on `0x600 + node` with CiA 302-3 program
//! download into two policy slots (`Controller::on_frame_slots`, `Controller::poll_slots`).
//!
//! An input ([`ProgramInput`]) is a sequence of what a flashing tool, an NMT master, a plant, a
//! clock and the power supply do: well-formed block or segmented downloads of prepared policy files
//! into 0x1F50:1 (bits flipped before sending, cut anywhere, ended with a right or wrong CRC),
//! program control writes to 0x1F51:1 (any value), reads, arbitrary 0-8 byte SDO requests, NMT
//! commands, observations (so a newly started policy is evaluated: one of the files faults at its
//! first evaluation and is rolled back), clock steps through `poll_slots` (SDO timeouts) and power
//! cuts (the regions mounted again, a new controller attached).
//!
//! The reference model: after every step the active policy is the previous one or a file that was
//! downloaded whole, verified and started, never a partial or unverified one. It checks:
//!
//! 1. the active file, when there is one, decodes, passes a fresh controller's checks and is one of
//!    the prepared files the controller takes, byte for byte;
//! 2. the active file changes only on an accepted start (to the staged file), an accepted roll-back
//!    or an emergency 0xFF07 (to the previous one); never on a power cut, a download or an abort;
//! 3. a download accepted at its end was of bytes that verify (a corrupt or refused file is aborted
//!    with 0x0800_0020, a wrong block CRC with 0x0504_0004), and a whole, uncorrupted download of a
//!    loadable file outside operational is accepted;
//! 4. refusals carry their codes: a download or program control while operational 0x0800_0022, a
//!    start with nothing staged or a roll-back with no previous policy 0x0800_0024;
//! 5. what is staged and what is kept for a roll-back are what the model predicts (after an
//!    arbitrary request, which the model does not interpret, it takes them from the slots again).

use arbitrary::Arbitrary;
use dex_policy::PolicyView;
use dex_runtime::can::CanFrame;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{NmtCommand, OBS_FRAMES, encode_observation, nmt_frame};
use dex_runtime::canopen::program::{PROGRAM_CONTROL, PROGRAM_DATA, control};
use dex_runtime::canopen::sdo::BLOCK_CRC;
use dex_runtime::controller::{SDO_REQUEST_BASE, SDO_RESPONSE_BASE};
use dex_runtime::slots::{CRC32, SLOT_HEADER_BYTES};
use dex_runtime::testkit::{aligned_copy, observation_trace};
use dex_runtime::{
    Controller, ControllerConfig, FaultCode, MockClock, Network, Outbox, PolicySlots, State,
};
use embedded_can::Frame;

use crate::structured::images::images;

/// Evaluator capacity of the controller (widest layer).
const WIDTH: usize = 64;
/// Bytes of policy file a slot takes.
const CAPACITY: usize = 64 * 1024;
/// The controller's node id.
const NODE: u8 = 0x10;

/// The fuzzer's input: the policy the controller starts with and the operations.
#[derive(Arbitrary, Debug)]
pub struct ProgramInput {
    /// Index of the prepared, loadable file provisioned at the start (none when `None`).
    pub initial: Option<u8>,
    /// The operations, at most 256 of them played.
    pub ops: Vec<ProgramOp>,
}

/// One operation.
#[derive(Arbitrary, Debug)]
pub enum ProgramOp {
    /// The tool initiates a download of a prepared file into 0x1F50:1 (block or segmented).
    Begin {
        /// Which file.
        image: u8,
        /// Block download (else segmented).
        block: bool,
    },
    /// The tool flips bits in its copy of the file before sending them.
    Corrupt {
        /// Byte offset (modulo the file length).
        offset: u16,
        /// The bits.
        xor: u8,
    },
    /// The tool sends up to this many more segments.
    Send {
        /// Segments.
        segments: u16,
    },
    /// The tool ends a block download.
    End {
        /// Send a CRC-16 that does not match.
        wrong_crc: bool,
    },
    /// Program control 0x1F51:1 written with this value.
    Control(u8),
    /// An arbitrary request of 0-8 bytes on `0x600 + node`.
    Raw {
        /// The bytes.
        data: [u8; 8],
        /// How many of them (modulo 9).
        len: u8,
    },
    /// An NMT command to the node (start, stop, pre-operational, reset node, reset communication).
    Nmt(u8),
    /// One observation (all its frames).
    Observe,
    /// The clock moves on by this many milliseconds, then `poll_slots`.
    Clock(u16),
    /// A power cut: the regions mounted again, a new controller attached to them.
    PowerCut,
}

/// What the model predicts about the slots (CRC-32s of files).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Model {
    active: Option<u32>,
    previous: Option<u32>,
    /// A verified file is staged (its CRC when the model knows it).
    staged: Option<Option<u32>>,
}

/// The tool's side of a download.
struct Client {
    data: Vec<u8>,
    block: bool,
    /// Bytes the server has taken (acknowledged).
    done: usize,
    /// Segments sent in the running sub-block (block mode).
    in_sub: usize,
    /// Block size the server offered.
    blksize: usize,
    /// The segmented transfer's next toggle.
    toggle: bool,
    /// All segments sent and acknowledged (block: waiting for the end).
    complete: bool,
    /// The controller was operational at the initiate.
    started_operational: bool,
}

/// The controller, its slots over two regions and the model, in lockstep.
struct Rig<'r> {
    controller: Controller<'static, WIDTH>,
    slots: Option<PolicySlots<'r>>,
    clock: MockClock,
    model: Model,
    client: Option<Client>,
    senders: [E2eSender; OBS_FRAMES],
    sample: u8,
    /// Arbitrary requests were sent since the last well-formed operation.
    dirty: bool,
}

fn sdo(data: &[u8]) -> CanFrame {
    CanFrame::standard(SDO_REQUEST_BASE + u16::from(NODE), data).expect("SDO frame")
}

fn request(command: u8, index: u16, sub: u8, value: [u8; 4]) -> [u8; 8] {
    let i = index.to_le_bytes();
    [
        command, i[0], i[1], sub, value[0], value[1], value[2], value[3],
    ]
}

fn abort_code(r: &[u8; 8]) -> Option<u32> {
    dex_runtime::canopen::sdo::abort_code(r)
}

/// Whether a controller takes `bytes` (what verification at the end of a download checks).
fn verifies(bytes: &[u8]) -> bool {
    let copy = aligned_copy(bytes);
    let Ok(view) = PolicyView::decode(copy.as_bytes()) else {
        return false;
    };
    let c = Controller::<WIDTH>::new(ControllerConfig::default());
    c.check_policy(&view).is_ok() && Network::<WIDTH>::new(&view, copy.as_bytes()).is_ok()
}

impl<'r> Rig<'r> {
    fn slots(&mut self) -> &mut PolicySlots<'r> {
        self.slots.as_mut().expect("slots mounted")
    }

    /// The controller's SDO responses in `out`.
    fn responses(out: &Outbox) -> Vec<[u8; 8]> {
        out.iter()
            .filter(|f| f.standard_id() == Some(SDO_RESPONSE_BASE + u16::from(NODE)))
            .map(|f| {
                let mut d = [0u8; 8];
                d[..f.data().len()].copy_from_slice(f.data());
                d
            })
            .collect()
    }

    fn deliver(&mut self, frame: &CanFrame) -> Outbox {
        let slots = self.slots.as_mut().expect("slots mounted");
        let out = self.controller.on_frame_slots(frame, &self.clock, slots);
        if rolled_back(&out) {
            self.model.active = self.model.previous.take();
        }
        out
    }

    /// Sends one SDO request; the response, if any.
    fn send(&mut self, data: &[u8]) -> Option<[u8; 8]> {
        let out = self.deliver(&sdo(data));
        let r = Self::responses(&out);
        assert!(r.len() <= 1, "more than one SDO response: {r:02x?}");
        r.first().copied()
    }

    fn active_crc(&mut self) -> Option<u32> {
        self.slots().active().map(|f| f.crc)
    }

    /// The model taken from the slots (after what it does not interpret).
    fn resync(&mut self) {
        let s = self.slots();
        self.model = Model {
            active: s.active().map(|f| f.crc),
            previous: s.previous().map(|f| f.crc),
            staged: (s.transfer_state() == 2).then_some(None),
        };
    }

    /// Invariants 1 and 5 after a step.
    fn check(&mut self) {
        let loadable: Vec<&[u8]> = images()
            .iter()
            .filter(|i| i.loads)
            .map(|i| i.bytes.as_bytes())
            .collect();
        let s = self.slots.as_ref().expect("slots mounted");
        let file = s.active_file();
        if !file.is_empty() {
            assert!(
                loadable.contains(&file),
                "the active file is none of the loadable files"
            );
            assert!(verifies(file), "the active file does not verify");
        }
        assert_eq!(
            s.active().map(|f| f.crc),
            self.model.active,
            "active policy"
        );
        assert_eq!(
            s.previous().map(|f| f.crc),
            self.model.previous,
            "previous policy"
        );
        assert_eq!(
            s.transfer_state() == 2,
            self.model.staged.is_some(),
            "staged file"
        );
        if let Some(Some(crc)) = self.model.staged {
            // Only a verified file is staged: it is one the model saw verify.
            assert_ne!(crc, 0);
        }
    }

    fn begin(&mut self, image: usize, block: bool) {
        let operational = self.controller.state() == State::Operational;
        let data = images()[image].bytes.as_bytes().to_vec();
        let size = (data.len() as u32).to_le_bytes();
        let cs = if block { 0xC6 } else { 0x21 };
        let r = self.send(&request(cs, PROGRAM_DATA, 1, size));
        let r = r.expect("an initiate is answered");
        // A new initiate ends a running transfer (dropped) before it starts.
        if operational {
            assert_eq!(
                abort_code(&r),
                Some(0x0800_0022),
                "download while operational"
            );
            self.client = None;
            return;
        }
        assert!(data.len() <= CAPACITY);
        let accepted = if block { r[0] == 0xA4 } else { r[0] == 0x60 };
        assert!(
            accepted,
            "initiate of a {} B file refused: {r:02x?}",
            data.len()
        );
        // The inactive slot is invalidated: no previous policy, nothing staged.
        self.model.previous = None;
        self.model.staged = None;
        self.client = Some(Client {
            data,
            block,
            done: 0,
            in_sub: 0,
            blksize: usize::from(r[4]),
            toggle: false,
            complete: false,
            started_operational: operational,
        });
    }

    /// The tool's transfer ended (aborted, or completed with `staged`).
    fn transfer_over(&mut self, staged: Option<u32>) {
        self.client = None;
        if let Some(crc) = staged {
            self.model.staged = Some(Some(crc));
        }
    }

    fn send_segments(&mut self, n: usize) {
        for _ in 0..n {
            let Some(c) = self.client.as_mut() else {
                return;
            };
            if c.complete {
                return;
            }
            let offset = c.done + 7 * c.in_sub;
            let chunk_end = (offset + 7).min(c.data.len());
            let chunk = c.data[offset..chunk_end].to_vec();
            let last = chunk_end == c.data.len();
            let mut f = [0u8; 8];
            f[1..1 + chunk.len()].copy_from_slice(&chunk);
            if c.block {
                c.in_sub += 1;
                let seq = c.in_sub;
                f[0] = (u8::from(last) << 7) | seq as u8;
                let ends_sub = last || seq == c.blksize;
                let r = self.send(&f);
                let Some(c) = self.client.as_mut() else {
                    return;
                };
                if !ends_sub {
                    assert_eq!(r, None, "a response inside a sub-block");
                    continue;
                }
                let r = r.expect("a sub-block is acknowledged");
                if abort_code(&r).is_some() {
                    self.transfer_over(None);
                    return;
                }
                assert_eq!(r[0], 0xA2, "block acknowledgement");
                assert_eq!(usize::from(r[1]), seq, "every segment arrived in order");
                c.done += 7 * seq;
                c.in_sub = 0;
                c.blksize = usize::from(r[2]);
                c.complete = last;
                if last {
                    c.done = c.data.len();
                }
            } else {
                let t = u8::from(c.toggle);
                f[0] = (t << 4) | (((7 - chunk.len()) as u8) << 1) | u8::from(last);
                c.toggle = !c.toggle;
                let r = self.send(&f).expect("a segment is answered");
                let c = self.client.as_ref().expect("client");
                if let Some(code) = abort_code(&r) {
                    if last {
                        self.end_refused(code);
                    }
                    self.transfer_over(None);
                    return;
                }
                assert_eq!(r[0], 0x20 | (t << 4), "segment response");
                if last {
                    let data = c.data.clone();
                    self.end_accepted(&data);
                    return;
                }
                self.client.as_mut().expect("client").done = chunk_end;
            }
        }
    }

    /// Invariant 3 for an end the server refused with `code`.
    fn end_refused(&mut self, code: u32) {
        let c = self.client.as_ref().expect("client");
        if code == 0x0800_0020 {
            assert!(!verifies(&c.data), "a file that verifies was refused");
        } else if code != 0x0504_0004 {
            panic!("end aborted with {code:#010x}");
        }
        self.model.staged = None;
    }

    /// Invariant 3 for an end the server accepted.
    fn end_accepted(&mut self, data: &[u8]) {
        assert!(verifies(data), "a file that does not verify was staged");
        let c = self.client.as_ref().expect("client");
        assert!(!c.started_operational);
        self.transfer_over(Some(CRC32.checksum(data)));
    }

    fn end(&mut self, wrong_crc: bool) {
        let Some(c) = self.client.as_ref() else {
            return;
        };
        if !c.block || !c.complete {
            return;
        }
        let data = c.data.clone();
        let unused = (7 - (data.len() - 1) % 7 - 1) as u8;
        let mut crc = BLOCK_CRC.checksum(&data);
        if wrong_crc {
            crc ^= 0x5A5A;
        }
        let crc = crc.to_le_bytes();
        let r = self
            .send(&[0xC1 | (unused << 2), crc[0], crc[1], 0, 0, 0, 0, 0])
            .expect("the end is answered");
        match abort_code(&r) {
            Some(code) => {
                if wrong_crc {
                    assert_eq!(code, 0x0504_0004, "wrong CRC");
                } else {
                    assert_ne!(code, 0x0504_0004, "a right block CRC refused");
                }
                self.end_refused(code);
                self.transfer_over(None);
            }
            None => {
                assert!(!wrong_crc, "a wrong block CRC accepted");
                assert_eq!(r[0], 0xA1);
                self.end_accepted(&data);
            }
        }
    }

    fn control(&mut self, value: u8) {
        let operational = self.controller.state() == State::Operational;
        let before = self.active_crc();
        let r = self
            .send(&request(0x2F, PROGRAM_CONTROL, 1, [value, 0, 0, 0]))
            .expect("program control is answered");
        let code = abort_code(&r);
        match value {
            control::START | control::CLEAR | control::ROLL_BACK if operational => {
                assert_eq!(code, Some(0x0800_0022), "control {value} while operational");
            }
            control::START => match self.model.staged {
                None => assert_eq!(code, Some(0x0800_0024), "start with nothing staged"),
                Some(staged) => {
                    assert_eq!(code, None, "start of a staged file refused");
                    let now = self.active_crc();
                    if let Some(crc) = staged {
                        assert_eq!(now, Some(crc), "start activated another file");
                    }
                    self.model.previous = before;
                    self.model.active = now;
                    self.model.staged = None;
                }
            },
            control::CLEAR => {
                assert_eq!(code, None);
                self.model.staged = None;
            }
            control::ROLL_BACK => match self.model.previous {
                None => assert_eq!(code, Some(0x0800_0024), "roll-back with no previous"),
                Some(prev) => {
                    assert_eq!(code, None, "roll-back refused");
                    assert_eq!(self.active_crc(), Some(prev), "roll-back target");
                    self.model.previous = before;
                    self.model.active = Some(prev);
                }
            },
            control::STOP => assert_eq!(code, None),
            _ => assert_eq!(code, Some(0x0609_0030), "control value {value}"),
        }
        // Invariant 2: only a start or a roll-back changes the active file here.
        if code.is_some() || !matches!(value, control::START | control::ROLL_BACK) {
            assert_eq!(
                self.active_crc(),
                before,
                "a refused control changed the policy"
            );
        }
    }

    fn observe(&mut self) {
        let obs = observation_trace(1, u64::from(self.sample))[0];
        self.sample = self.sample.wrapping_add(1);
        let frames = encode_observation(NODE, &obs, self.sample & 0x0F, &mut self.senders);
        for f in &frames {
            self.deliver(f);
        }
    }

    /// A power cut: RAM state gone, the regions mounted again, a new controller attached to the
    /// active slot. The active file is what was committed; a staged file (no header yet) is gone.
    fn power_cut(&mut self) {
        let before = self.active_crc();
        let slots = self.slots.take().expect("slots mounted");
        let (a, b) = slots.into_regions();
        let mut slots = PolicySlots::mount(a, b).expect("regions mount");
        self.controller = Controller::new(ControllerConfig::default());
        self.controller.poll_slots(&self.clock, &mut slots);
        if slots.active().is_some() {
            self.controller
                .attach_slots(&slots)
                .expect("the committed file attaches");
        }
        self.slots = Some(slots);
        self.client = None;
        self.senders = [E2eSender::default(); OBS_FRAMES];
        assert_eq!(
            self.active_crc(),
            before,
            "a power cut changed the active policy"
        );
        self.model.staged = None;
    }

    /// An operation the model does not interpret (an arbitrary request, or a request into the
    /// middle of the tool's block transfer): invariant 2 only, then the model from the slots.
    fn uninterpreted(&mut self, data: &[u8]) {
        let before = self.active_crc();
        let r = self.send(data);
        let started = r.is_some_and(|r| r[0] == 0x60 && r[1..4] == [0x51, 0x1F, 1]);
        if !started && self.model.active == before {
            assert_eq!(
                self.active_crc(),
                before,
                "an uninterpreted request changed the policy"
            );
        }
        self.client = None;
        self.dirty = true;
    }
}

/// Whether `out` holds an emergency 0xFF07 (a newly started policy rolled back).
fn rolled_back(out: &Outbox) -> bool {
    let code = FaultCode::PolicyRolledBack.emcy_code().to_le_bytes();
    out.iter().any(|f| {
        f.standard_id() == Some(0x080 + u16::from(NODE)) && f.data().get(2..4) == Some(&code[..])
    })
}

/// Plays `input` (at most 256 operations); panics when an invariant fails.
pub fn run_program(input: &ProgramInput) {
    let images = images();
    let loadable: Vec<usize> = (0..images.len()).filter(|&i| images[i].loads).collect();
    let words = (SLOT_HEADER_BYTES + CAPACITY) / 8;
    let (mut ra, mut rb) = (vec![0u64; words], vec![0u64; words]);
    let mut slots = PolicySlots::mount(
        bytemuck::cast_slice_mut(&mut ra),
        bytemuck::cast_slice_mut(&mut rb),
    )
    .expect("regions mount");
    let clock = MockClock::new(0);
    let mut controller = Controller::<'static, WIDTH>::new(ControllerConfig::default());
    controller.poll_slots(&clock, &mut slots);
    if let Some(i) = input.initial {
        // Provisioning through the slots' own API, as the firmware does.
        let file = images[loadable[usize::from(i) % loadable.len()]]
            .bytes
            .as_bytes();
        slots.begin(file.len()).expect("fits");
        slots.write_at(0, file).expect("writes");
        slots
            .finish(|view, _| controller.check_policy(view))
            .expect("verifies");
        controller.activate_slot(&mut slots).expect("activates");
    }
    let mut rig = Rig {
        controller,
        model: Model {
            active: slots.active().map(|f| f.crc),
            previous: None,
            staged: None,
        },
        slots: Some(slots),
        clock,
        client: None,
        senders: [E2eSender::default(); OBS_FRAMES],
        sample: 0,
        dirty: false,
    };
    for op in input.ops.iter().take(256) {
        let mid_block = rig.client.as_ref().is_some_and(|c| c.block && !c.complete);
        let sdo_op = matches!(op, ProgramOp::Begin { .. } | ProgramOp::Control(_));
        if sdo_op && rig.dirty {
            // The tool aborts whatever the arbitrary requests left running.
            let _ = rig.send(&request(0x80, 0, 0, 0x0800_0000u32.to_le_bytes()));
            rig.resync();
            rig.dirty = false;
        }
        match *op {
            ProgramOp::Begin { image, block } => {
                let image = usize::from(image) % images.len();
                if mid_block {
                    let size = (images[image].bytes.as_bytes().len() as u32).to_le_bytes();
                    rig.uninterpreted(&request(0xC6, PROGRAM_DATA, 1, size));
                } else {
                    rig.begin(image, block);
                }
            }
            ProgramOp::Corrupt { offset, xor } => {
                if let Some(c) = rig.client.as_mut() {
                    let sent = c.done + 7 * c.in_sub;
                    if sent < c.data.len() && xor != 0 {
                        let at = sent + usize::from(offset) % (c.data.len() - sent);
                        c.data[at] ^= xor;
                    }
                }
            }
            ProgramOp::Send { segments } => rig.send_segments(usize::from(segments % 512)),
            ProgramOp::End { wrong_crc } => rig.end(wrong_crc),
            ProgramOp::Control(value) => {
                if mid_block {
                    rig.uninterpreted(&request(0x2F, PROGRAM_CONTROL, 1, [value, 0, 0, 0]));
                } else {
                    rig.client = None;
                    rig.control(value);
                }
            }
            ProgramOp::Raw { data, len } => rig.uninterpreted(&data[..usize::from(len % 9)]),
            ProgramOp::Nmt(c) => {
                let command = match c % 5 {
                    0 => NmtCommand::Start,
                    1 => NmtCommand::Stop,
                    2 => NmtCommand::EnterPreOperational,
                    3 => NmtCommand::ResetNode,
                    _ => NmtCommand::ResetCommunication,
                };
                let before = rig.active_crc();
                rig.deliver(&nmt_frame(command, NODE));
                if matches!(
                    command,
                    NmtCommand::ResetNode | NmtCommand::ResetCommunication
                ) {
                    // A reset drops a running SDO transfer, and restarts the alive counters.
                    rig.client = None;
                    rig.senders = [E2eSender::default(); OBS_FRAMES];
                }
                assert_eq!(rig.active_crc(), before, "NMT changed the policy");
            }
            ProgramOp::Observe => rig.observe(),
            ProgramOp::Clock(ms) => {
                rig.clock.advance(u64::from(ms) * 1000);
                let slots = rig.slots.as_mut().expect("slots mounted");
                let out = rig.controller.poll_slots(&rig.clock, slots);
                let r = Rig::responses(&out);
                if let Some(r) = r.first() {
                    assert_eq!(
                        abort_code(r),
                        Some(0x0504_0000),
                        "poll answers only timeouts"
                    );
                    rig.client = None;
                }
            }
            ProgramOp::PowerCut => rig.power_cut(),
        }
        if rig.dirty {
            let s = rig.slots.as_ref().expect("slots mounted");
            let file = s.active_file();
            assert!(
                file.is_empty() || verifies(file),
                "the active file does not verify"
            );
            rig.resync();
        }
        rig.check();
    }
}
