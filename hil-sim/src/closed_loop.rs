//! Closed-loop episodes over a bus in this process (`hil-sim run`, the episodes of
//! `hil-sim latency`): the bus, the controller node on its own thread with the policy, and the
//! plant node (NMT master) running the episodes, in lockstep or in real time.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use dex_runtime::ControllerConfig;
use dex_runtime::can::FrameLayout;

use crate::bus::{Bus, BusClock, BusConfig, BusError, BusStats};
use crate::node::{NodeConfig, NodeError, NodeTiming, TimeMode, spawn_controller_node};
use crate::plant::{EpisodeReport, Plant, PlantError, PlantNode, PlantTiming};
use crate::wire::WireConfig;

/// Settings of a closed-loop run.
#[derive(Debug, Clone)]
pub struct ClosedLoopSettings {
    /// Episodes to run.
    pub episodes: u32,
    /// Run seed; episode `e` starts from `episode_seed(seed, e)`.
    pub seed: u64,
    /// The bus's candump-format log.
    pub log: Option<PathBuf>,
    /// Time on the wire; `None`: untimed.
    pub wire: Option<WireConfig>,
    /// CAN FD's data-phase bit rate; `None`: a classic bus.
    pub fd_data_bitrate: Option<u32>,
    /// The frame layout of the controller node and the plant.
    pub layout: FrameLayout,
    /// The controller node's timing. Its mode is the run's: [`TimeMode::RealTime`] puts the bus
    /// on the wall clock and the plant at 20 Hz; [`TimeMode::Lockstep`] puts the bus on virtual
    /// time and has each plant step wait for the answer to its observation.
    pub node: NodeTiming,
}

/// What a closed-loop run reports.
#[derive(Debug, Clone)]
pub struct ClosedLoopReport {
    /// Episodes that ended in success.
    pub successes: u32,
    /// Sum of the episodes' returns.
    pub total_return: f64,
    /// The emergency codes the plant received from the controller, in order.
    pub emergencies: Vec<u16>,
    /// The controller node's status line at the end.
    pub controller: String,
    /// The bus's counters at the end.
    pub bus: BusStats,
}

/// Errors of a closed-loop run.
#[derive(Debug, thiserror::Error)]
pub enum ClosedLoopError {
    /// The bus did not start.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The controller node did not start.
    #[error(transparent)]
    Node(#[from] NodeError),
    /// The plant node failed: its connection, the controller's start, or an episode.
    #[error(transparent)]
    Plant(#[from] PlantError),
}

/// Runs `settings.episodes` closed-loop episodes of the policy file `policy` on `plant`: starts a
/// bus, spawns the controller node with the policy, connects the plant node, starts the
/// controller and runs the episodes, calling `on_episode` after each; then stops the node and
/// shuts the bus down.
pub fn run(
    settings: &ClosedLoopSettings,
    policy: Vec<u8>,
    plant: &mut dyn Plant,
    on_episode: &mut dyn FnMut(u32, &EpisodeReport),
) -> Result<ClosedLoopReport, ClosedLoopError> {
    let realtime = settings.node.mode == TimeMode::RealTime;
    let bus = Bus::start(BusConfig {
        clock: if realtime {
            BusClock::Wall
        } else {
            BusClock::Virtual
        },
        log: settings.log.clone(),
        wire: settings.wire,
        fd_data_bitrate: settings.fd_data_bitrate,
        ..BusConfig::default()
    })?;
    let stop = Arc::new(AtomicBool::new(false));
    let status = bus.status_slot();
    let controller = ControllerConfig::default();
    let controller_id = controller.node_id;
    let node = spawn_controller_node(
        bus.addr(),
        Some(policy),
        NodeConfig {
            controller,
            layout: settings.layout,
        },
        settings.node,
        Arc::clone(&stop),
        Some(Arc::clone(&status)),
    )?;
    let timing = if realtime {
        PlantTiming::RealTime
    } else {
        PlantTiming::Lockstep
    };
    let result = (|| -> Result<_, PlantError> {
        let mut node =
            PlantNode::connect(&bus, timing, controller_id)?.with_layout(settings.layout);
        node.start_controller()?;
        let r = node.episodes(plant, settings.episodes, settings.seed, false, on_episode)?;
        Ok((r.successes, r.total_return, node.emergencies().to_vec()))
    })();
    stop.store(true, Ordering::SeqCst);
    let _ = node.join();
    let (successes, total_return, emergencies) = result?;
    let controller = status.lock().map(|s| s.clone()).unwrap_or_default();
    let stats = bus.stats();
    bus.shutdown();
    Ok(ClosedLoopReport {
        successes,
        total_return,
        emergencies,
        controller,
        bus: stats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::SyntheticPlant;

    fn settings() -> ClosedLoopSettings {
        ClosedLoopSettings {
            episodes: 2,
            seed: 7,
            log: None,
            wire: Some(WireConfig::default()),
            fd_data_bitrate: None,
            layout: FrameLayout::Classic,
            node: NodeTiming {
                mode: TimeMode::Lockstep,
                step_compute_us: 0,
            },
        }
    }

    /// The episodes' seeds, returns and answered steps, and the run's totals.
    fn episodes(policy: &[u8]) -> (Vec<(u64, f64, u32)>, ClosedLoopReport) {
        let mut plant = SyntheticPlant::new(20);
        let mut seen = Vec::new();
        let report = run(&settings(), policy.to_vec(), &mut plant, &mut |_, e| {
            seen.push((e.seed, e.episode_return, e.steps - e.steps_without_action))
        })
        .expect("a closed-loop run of a valid policy");
        (seen, report)
    }

    #[test]
    fn lockstep_runs_report_every_episode_and_repeat_exactly() {
        let policy = dex_runtime::synthetic::jaco_policy(&[16, 16], 3).expect("policy");
        let (first, report) = episodes(&policy);
        assert_eq!(first.len(), 2);
        assert_ne!(
            first[0].0, first[1].0,
            "each episode has its own start seed"
        );
        // Lockstep: every step is answered by the controller through the bus.
        assert!(
            first.iter().all(|&(_, _, answered)| answered == 20),
            "{first:?}"
        );
        let total: f64 = first.iter().map(|&(_, r, _)| r).sum();
        assert_eq!(report.total_return, total);
        assert!(report.bus.frames_on_bus > 0, "{:?}", report.bus);
        let (again, _) = episodes(&policy);
        assert_eq!(first, again, "same seed, same episodes");
    }

    #[test]
    fn a_corrupt_policy_file_is_an_error_not_a_run() {
        let mut policy = dex_runtime::synthetic::jaco_policy(&[16, 16], 3).expect("policy");
        let last = policy.len() - 1;
        policy[last] ^= 0xFF;
        let mut plant = SyntheticPlant::new(20);
        let mut episodes = 0;
        let err = run(&settings(), policy, &mut plant, &mut |_, _| episodes += 1)
            .expect_err("a file whose checksum fails");
        // The node refuses the file and stays out of operational; the plant says so.
        assert!(matches!(err, ClosedLoopError::Plant(_)), "{err}");
        assert!(err.to_string().contains("operational"), "{err}");
        assert_eq!(episodes, 0);
    }
}
