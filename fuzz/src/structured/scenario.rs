//! The scenario: an [`Input`] played against a controller and the reference model, each operation
//! turned into what a plant, an NMT master, a clock, a CAN driver or a flashing tool would do.

use crc::{CRC_32_ISO_HDLC, Crc};
use dex_policy::{CRC_OFFSET, PolicyView, file_crc};
use dex_runtime::can::CanFrame;
use dex_runtime::can::messages::{ACTION_FRAMES, NMT_ID, NODE_ID_MAX, NmtCommand, OBS_FRAMES};
use dex_runtime::envelope::EnvelopeConfig;
use dex_runtime::interface::CONTROL_PERIOD_US;
use dex_runtime::testkit::aligned_copy;
use dex_runtime::{Controller, ControllerConfig, MockClock, State};

use super::checks::Event;
use super::flash::{Staging, verifies};
use super::images::images;
use super::input::{CrcSel, Input, NmtSel, NodeSel, Op, Step};
use super::model::Model;
use super::plant::Plant;
use super::run::Run;
use super::{PERIOD, WIDTH, stats};

const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);
/// Bytes per staged data segment (how far one `FlashData` segment moves the staged file).
const SEGMENT_BYTES: usize = 6;
/// Staging buffers per input for verified files that differ from every prepared one.
const POOL_SLOTS: usize = 4;

/// Plays `input` (at most 512 of its operations), checking the invariants and the reference model
/// after every step; panics on a violation or a difference.
pub fn run_scenario(input: &Input) {
    let images = images();
    let loadable = images.iter().filter(|i| i.loads).count();
    let cfg = ControllerConfig {
        node_id: 1 + input.node_id % NODE_ID_MAX,
        period_us: CONTROL_PERIOD_US,
        watchdog_cycles: u32::from(input.watchdog_cycles % 7),
        heartbeat_cycles: u32::from(input.heartbeat_cycles % 21),
        e2e_max_delta: input.e2e_max_delta % 15,
        // The model predicts the policy's actions bit for bit: the safety envelope, which rescales
        // them from the kinematics, is off here (its own tests: runtime/tests/envelope.rs).
        envelope: EnvelopeConfig {
            enabled: false,
            ..EnvelopeConfig::default()
        },
    };
    // Storage for verified files that match no prepared one; it outlives the controller.
    let mut pool: [Vec<u64>; POOL_SLOTS] = Default::default();
    let mut free = pool.iter_mut();
    let mut run = Run {
        controller: Controller::<WIDTH>::new(cfg),
        model: Model::new(cfg),
        clock: MockClock::new(1_000_000),
        tx_action: [0; ACTION_FRAMES],
        tx_emcy: 0,
        tx_info: 0,
        tx_status: 0,
    };
    if let Some(i) = input.initial_policy {
        let image = &images[usize::from(i) % loadable];
        let view = PolicyView::decode(image.bytes.as_bytes()).expect("prepared file decodes");
        run.load(&view, true);
    }
    let mut plant = Plant::default();
    plant.node = cfg.node_id;
    let mut staging = Staging::Empty;
    for op in input.ops.iter().take(512) {
        match *op {
            Op::Sample { sample, values } => {
                let sample = plant.select(sample);
                for k in 0..OBS_FRAMES {
                    for f in plant.frames(k, sample, values, None) {
                        run.deliver(f);
                    }
                }
            }
            Op::Frames {
                sample,
                first,
                count,
                values,
                flaw,
                reverse,
            } => {
                let sample = plant.select(sample);
                let first = usize::from(first) % OBS_FRAMES;
                let last = (first + usize::from(count) % OBS_FRAMES).min(OBS_FRAMES - 1);
                let mut ks: Vec<usize> = (first..=last).collect();
                if reverse {
                    ks.reverse();
                }
                let flawed = flaw.map(|(at, f)| (usize::from(at) % ks.len(), f));
                for (n, &k) in ks.iter().enumerate() {
                    let f = flawed.and_then(|(at, f)| (at == n).then_some(f));
                    for frame in plant.frames(k, sample, values, f) {
                        run.deliver(frame);
                    }
                }
            }
            Op::Nmt { command, node } => {
                let code = match command {
                    NmtSel::Start => NmtCommand::Start.code(),
                    NmtSel::Stop => NmtCommand::Stop.code(),
                    NmtSel::PreOperational => NmtCommand::EnterPreOperational.code(),
                    NmtSel::ResetNode => NmtCommand::ResetNode.code(),
                    NmtSel::ResetCommunication => NmtCommand::ResetCommunication.code(),
                    NmtSel::Unknown(c) => c,
                };
                let node = match node {
                    NodeSel::All => 0,
                    NodeSel::Own => cfg.node_id,
                    NodeSel::Other(n) => n,
                };
                run.deliver(CanFrame::standard(NMT_ID, &[code, node]).expect("NMT frame"));
            }
            Op::Clock { step, poll } => {
                run.clock.advance(match step {
                    Step::Period => PERIOD,
                    Step::Periods(n) => PERIOD * u64::from(n % 8),
                    Step::Micros(us) => u64::from(us),
                    Step::Long(us) => u64::from(us),
                });
                if poll {
                    run.poll();
                }
            }
            Op::Poll => run.poll(),
            Op::BusOff => {
                let before = run.controller.state();
                run.model.bus_off();
                let out = run.controller.on_bus_off();
                run.step(Event::BusOff, before, None, out);
            }
            Op::BusRecovered => {
                let before = run.controller.state();
                run.model.bus_recovered();
                let out = run.controller.on_bus_recovered();
                run.step(Event::BusRecovered, before, None, out);
            }
            Op::FlashInit { image } => {
                staging = Staging::Receiving {
                    image: usize::from(image) % images.len(),
                    data: Vec::new(),
                };
            }
            Op::FlashData { segments } => {
                if let Staging::Receiving { image, data } = &mut staging {
                    let file = images[*image].bytes.as_bytes();
                    let end =
                        (data.len() + usize::from(segments % 1024) * SEGMENT_BYTES).min(file.len());
                    data.extend_from_slice(&file[data.len()..end]);
                }
            }
            Op::FlashCorrupt { offset, xor } => {
                if let Staging::Receiving { data, .. } = &mut staging
                    && !data.is_empty()
                {
                    let at = usize::from(offset) % data.len();
                    data[at] ^= xor;
                }
            }
            Op::FlashEnd { crc, reseal } => {
                let Staging::Receiving { image, mut data } =
                    std::mem::replace(&mut staging, Staging::Empty)
                else {
                    continue;
                };
                let file = images[image].bytes.as_bytes();
                if data.len() != file.len() {
                    continue;
                }
                if reseal {
                    let c = file_crc(&data);
                    data[CRC_OFFSET..CRC_OFFSET + 4].copy_from_slice(&c.to_le_bytes());
                }
                let claimed = match crc {
                    CrcSel::Sent => CRC32.checksum(&data),
                    CrcSel::Original => CRC32.checksum(file),
                    CrcSel::Wrong => CRC32.checksum(&data) ^ 1,
                };
                if claimed != CRC32.checksum(&data) {
                    continue;
                }
                let aligned = aligned_copy(&data);
                let ok =
                    PolicyView::decode(aligned.as_bytes()).is_ok_and(|view| verifies(&view, cfg));
                // 7. Corruption that kept the file CRC never verifies.
                if data[..] != file[..] && !reseal {
                    assert!(!ok, "a corrupted transfer verified");
                }
                if data[..] == file[..] {
                    assert_eq!(
                        ok, images[image].loads,
                        "prepared file {image} verification"
                    );
                }
                if ok {
                    staging = Staging::Verified { image, data };
                }
            }
            Op::FlashActivate => {
                let Staging::Verified { image, data } =
                    std::mem::replace(&mut staging, Staging::Empty)
                else {
                    continue;
                };
                if run.model.state == State::Operational {
                    // Refused before the file is looked at (the prepared file it came from stands
                    // in for it); the verified file stays for a later activation.
                    let view = PolicyView::decode(images[image].bytes.as_bytes()).expect("decodes");
                    run.load(&view, false);
                    staging = Staging::Verified { image, data };
                    continue;
                }
                let file = images[image].bytes.as_bytes();
                let bytes: &[u8] = if data[..] == file[..] {
                    file
                } else {
                    let Some(slot) = free.next() else { continue };
                    *slot = vec![0u64; data.len().div_ceil(8)];
                    let buf: &mut [u8] = bytemuck::cast_slice_mut(slot.as_mut_slice());
                    buf[..data.len()].copy_from_slice(&data);
                    let buf: &[u8] = buf;
                    &buf[..data.len()]
                };
                if bytes != file {
                    stats::count(8);
                }
                let view = PolicyView::decode(bytes).expect("verified file decodes");
                run.load(&view, true);
            }
            Op::FlashAbort => staging = Staging::Empty,
            Op::Load { image } => {
                let image = &images[usize::from(image) % images.len()];
                let view = PolicyView::decode(image.bytes.as_bytes()).expect("prepared file");
                run.load(&view, image.loads);
            }
            Op::Raw { id, data, len } => {
                let frame =
                    CanFrame::standard(id & 0x7FF, &data[..usize::from(len % 9)]).expect("frame");
                run.deliver(frame);
            }
        }
    }
    stats::print();
}
