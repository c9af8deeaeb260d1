//! Proves the control path never touches the heap: a counting global allocator watches 10,000
//! control cycles (poll, 15 observation frames, one 44-256-256-9 evaluation, action frames), for an
//! f32 policy and for the same policy quantised to int8.
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may panic on failure

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

use dex_policy::PolicyView;
use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{NmtCommand, OBS_FRAMES, encode_observation, nmt_frame};
use dex_runtime::testkit::{aligned_copy, jaco_policy, jaco_policy_int8, observation_trace};
use dex_runtime::{Controller, ControllerConfig, MockClock, State};

struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);
thread_local! {
    static WATCHING: Cell<bool> = const { Cell::new(false) };
}

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if WATCHING.with(Cell::get) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if WATCHING.with(Cell::get) {
            ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn ten_thousand_control_cycles_allocate_nothing() {
    control_cycles_allocate_nothing(&jaco_policy(&[256, 256], 21).unwrap());
}

#[test]
fn ten_thousand_int8_control_cycles_allocate_nothing() {
    control_cycles_allocate_nothing(&jaco_policy_int8(&[256, 256], 21).unwrap());
}

fn control_cycles_allocate_nothing(policy: &[u8]) {
    let file = aligned_copy(policy);
    let view = PolicyView::decode(file.as_bytes()).unwrap();
    let trace = observation_trace(64, 8);
    let clock = MockClock::new(0);
    let mut controller = Controller::<256>::new(ControllerConfig::default());
    controller.poll(&clock);
    controller.load_policy(&view).unwrap();
    controller.on_frame(&nmt_frame(NmtCommand::Start, 0), &clock);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let mut sent = 0usize;

    WATCHING.with(|w| w.set(true));
    for cycle in 0..10_000u64 {
        clock.set(cycle * 50_000 + 1_000);
        sent += controller.poll(&clock).len();
        let frames = encode_observation(0x10, &trace[(cycle % 64) as usize], cycle as u8, &mut tx);
        for f in &frames {
            sent += controller.on_frame(f, &clock).len();
        }
    }
    WATCHING.with(|w| w.set(false));

    assert_eq!(
        ALLOCATIONS.load(Ordering::Relaxed),
        0,
        "heap allocations in the control path"
    );
    assert_eq!(controller.state(), State::Operational);
    assert_eq!(controller.diagnostics().evaluations, 10_000);
    assert!(sent >= 30_000, "three action frames per cycle");
}

#[test]
fn flashing_activating_and_running_a_slot_allocate_nothing() {
    use dex_runtime::PolicySlots;
    use dex_runtime::canopen::program::{PROGRAM_CONTROL, PROGRAM_ID, control};
    use dex_runtime::testkit::{program_download, sdo_read, sdo_write};
    let old = jaco_policy(&[32], 1).unwrap();
    let new = jaco_policy_int8(&[64, 64], 2).unwrap();
    // Frames built before watching; the regions are caller-provided.
    let frames = program_download(0x10, &old);
    let mut second = program_download(0x10, &new);
    let roll_back = sdo_write(0x10, PROGRAM_CONTROL, 1, &[control::ROLL_BACK]).unwrap();
    second.push(roll_back);
    second.push(roll_back);
    second.push(sdo_read(0x10, PROGRAM_ID, 1).unwrap());
    let mut a = vec![0u64; 8 * 1024];
    let mut b = vec![0u64; 8 * 1024];
    let trace = observation_trace(64, 8);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let clock = MockClock::new(0);
    let mut controller = Controller::<256>::new(ControllerConfig::default());

    WATCHING.with(|w| w.set(true));
    let mut slots = PolicySlots::mount(
        bytemuck::cast_slice_mut(&mut a),
        bytemuck::cast_slice_mut(&mut b),
    )
    .unwrap();
    controller.poll(&clock);
    for f in &frames {
        controller.on_frame_slots(f, &clock, &mut slots);
    }
    for f in &second {
        controller.on_frame_slots(f, &clock, &mut slots);
    }
    controller.on_frame_slots(&nmt_frame(NmtCommand::Start, 0), &clock, &mut slots);
    for cycle in 1..1_000u64 {
        clock.set(cycle * 50_000);
        controller.poll_slots(&clock, &mut slots);
        let frames = encode_observation(0x10, &trace[(cycle % 64) as usize], cycle as u8, &mut tx);
        for f in &frames {
            controller.on_frame_slots(f, &clock, &mut slots);
        }
    }
    WATCHING.with(|w| w.set(false));

    assert_eq!(
        ALLOCATIONS.load(Ordering::Relaxed),
        0,
        "heap allocations in the slot path"
    );
    assert_eq!(controller.state(), State::Operational);
    assert_eq!(
        controller.policy_info().unwrap().format_version,
        2,
        "the int8 file runs"
    );
    assert!(controller.diagnostics().evaluations >= 990);
}
