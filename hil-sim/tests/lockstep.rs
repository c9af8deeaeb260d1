//! Lockstep over the bus gives exactly the actions of the same controller fed directly (no bus),
//! so the bus, the adapter and the plant node add nothing but transport.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

mod common;

use dex_hil_sim::bus::{ControlCommand, FaultKind, parse_control};
use dex_hil_sim::plant::{ActionAssembler, Plant, SyntheticPlant};
use dex_policy::PolicyView;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{NmtCommand, OBS_FRAMES, encode_observation, nmt_frame};
use dex_runtime::interface::{ACT_DIM, CONTROL_PERIOD_US};
use dex_runtime::testkit::{aligned_copy, jaco_policy};
use dex_runtime::{Controller, ControllerConfig, MockClock};

const STEPS: u32 = 40;
const SEEDS: [u64; 2] = [11, 12];

fn over_the_bus(policy: &[u8]) -> Vec<[f32; ACT_DIM]> {
    let mut plant = SyntheticPlant::new(STEPS);
    let episodes: Vec<(u64, u32)> = SEEDS.iter().map(|&s| (s, STEPS)).collect();
    let (actions, reports) = common::lockstep_over_the_bus(policy, &mut plant, &episodes);
    for r in reports {
        assert_eq!(r.steps, STEPS);
        assert_eq!(r.steps_without_action, 0);
    }
    actions
}

fn direct(policy: &[u8]) -> Vec<[f32; ACT_DIM]> {
    let bytes = aligned_copy(policy);
    let view = PolicyView::decode(bytes.as_bytes()).unwrap();
    let mut c = Controller::<256>::new(ControllerConfig::default());
    c.load_policy(&view).unwrap();
    let clock = MockClock::new(0);
    c.poll(&clock);
    c.on_frame(&nmt_frame(NmtCommand::Start, 0x10), &clock);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let mut plant = SyntheticPlant::new(STEPS);
    let mut t = 0;
    let mut sample = 0u8;
    let mut out = Vec::new();
    let mut asm = ActionAssembler::new(0x10);
    for seed in SEEDS {
        let mut obs = plant.reset(seed).unwrap();
        for _ in 0..STEPS {
            t += u64::from(CONTROL_PERIOD_US);
            sample = (sample + 1) & 0x0F;
            clock.set(t);
            c.poll(&clock);
            let mut action = None;
            for f in encode_observation(0x10, &obs, sample, &mut tx) {
                for a in c.on_frame(&f, &clock) {
                    if asm.push(&a) == Some(sample) {
                        action = asm.newest.map(|(v, _)| v);
                    }
                }
            }
            let action = action.unwrap();
            out.push(action);
            obs = plant.step(&action).unwrap().observation;
        }
    }
    out
}

#[test]
fn lockstep_bus_run_equals_direct_controller_bit_for_bit() {
    let policy = jaco_policy(&[64, 64], 5).unwrap();
    let bus = over_the_bus(&policy);
    let reference = direct(&policy);
    assert_eq!(bus.len(), reference.len());
    for (i, (a, b)) in bus.iter().zip(&reference).enumerate() {
        let a: Vec<u32> = a.iter().map(|v| v.to_bits()).collect();
        let b: Vec<u32> = b.iter().map(|v| v.to_bits()).collect();
        assert_eq!(a, b, "step {i}");
    }
    assert!(reference.iter().any(|a| a.iter().any(|v| *v != 0.0)));
    // And the run repeats exactly.
    assert_eq!(over_the_bus(&policy), bus);
}

#[test]
fn control_commands_parse() {
    let w = |s: &str| s.split(' ').map(String::from).collect::<Vec<_>>();
    match parse_control(&w("fault delay 280 20000 1")) {
        Ok(ControlCommand::Fault(r)) => {
            assert_eq!(r.kind, FaultKind::Delay(20_000));
            assert_eq!(r.id, Some(0x280));
            assert_eq!(r.remaining, Some(1));
        }
        other => panic!("{other:?}"),
    }
    match parse_control(&w("fault drop * 0")) {
        Ok(ControlCommand::Fault(r)) => assert!(r.id.is_none() && r.remaining.is_none()),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        parse_control(&w("fault busoff 300")),
        Ok(ControlCommand::BusOff(300_000))
    );
    assert_eq!(
        parse_control(&w("fault busoff 0")),
        Ok(ControlCommand::BusOff(0)),
        "off until cleared"
    );
    assert_eq!(parse_control(&w("fault clear")), Ok(ControlCommand::Clear));
    assert!(parse_control(&w("fault explode 1")).is_err());
    assert!(parse_control(&w("fault drop 2x0 1")).is_err());
}
