//! Shared set-up of the lockstep tests: a virtual-time bus, the controller node with a policy, and
//! a plant node that records every action it applies.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)] // test helper

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use dex_hil_sim::bus::{Bus, BusClock, BusConfig};
use dex_hil_sim::node::{NodeConfig, NodeTiming, TimeMode, spawn_controller_node};
use dex_hil_sim::plant::{EpisodeReport, Plant, PlantNode, PlantTiming};
use dex_hil_sim::wire::WireConfig;
use dex_runtime::can::FrameLayout;
use dex_runtime::interface::ACT_DIM;

/// Runs `episodes` (seed, step limit) of `plant` in lockstep over the bus with `policy` in the
/// controller node; returns every applied action and each episode's report.
pub fn lockstep_over_the_bus(
    policy: &[u8],
    plant: &mut dyn Plant,
    episodes: &[(u64, u32)],
) -> (Vec<[f32; ACT_DIM]>, Vec<EpisodeReport>) {
    lockstep_over_a_wire(policy, plant, episodes, None, 0, None)
}

/// [`lockstep_over_the_bus`] on a bus with `wire` (`None`: untimed), the node's answers taking
/// `compute_us` of bus time after an evaluation, the bus log written to `log`.
pub fn lockstep_over_a_wire(
    policy: &[u8],
    plant: &mut dyn Plant,
    episodes: &[(u64, u32)],
    wire: Option<WireConfig>,
    compute_us: u64,
    log: Option<std::path::PathBuf>,
) -> (Vec<[f32; ACT_DIM]>, Vec<EpisodeReport>) {
    lockstep_over_an_fd_wire(policy, plant, episodes, wire, None, compute_us, log)
}

/// [`lockstep_over_a_wire`] on a CAN FD bus when `fd_data_bitrate` is given: the controller node
/// and the plant in the FD layout.
pub fn lockstep_over_an_fd_wire(
    policy: &[u8],
    plant: &mut dyn Plant,
    episodes: &[(u64, u32)],
    wire: Option<WireConfig>,
    fd_data_bitrate: Option<u32>,
    compute_us: u64,
    log: Option<std::path::PathBuf>,
) -> (Vec<[f32; ACT_DIM]>, Vec<EpisodeReport>) {
    let layout = if fd_data_bitrate.is_some() {
        FrameLayout::Fd
    } else {
        FrameLayout::Classic
    };
    let bus = Bus::start(BusConfig {
        clock: BusClock::Virtual,
        wire,
        fd_data_bitrate,
        log,
        ..BusConfig::default()
    })
    .unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let node = spawn_controller_node(
        bus.addr(),
        Some(policy.to_vec()),
        NodeConfig {
            controller: dex_runtime::ControllerConfig::default(),
            layout,
        },
        NodeTiming {
            mode: TimeMode::Lockstep,
            step_compute_us: compute_us,
        },
        Arc::clone(&stop),
        None,
    )
    .unwrap();
    let mut plant_node = PlantNode::connect(&bus, PlantTiming::Lockstep, 0x10)
        .unwrap()
        .with_layout(layout);
    plant_node.record = Some(Vec::new());
    plant_node.start_controller().unwrap();
    let reports = episodes
        .iter()
        .map(|&(seed, steps)| plant_node.episode(plant, seed, steps).unwrap())
        .collect();
    let actions = plant_node.record.take().unwrap();
    stop.store(true, Ordering::SeqCst);
    node.join().unwrap().unwrap();
    bus.shutdown();
    (actions, reports)
}
