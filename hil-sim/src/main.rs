//! `hil-sim`: the virtual CAN bus, closed-loop runs over it, and the latency benchmark.

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand, ValueEnum};
use dex_hil_sim::bench::{BenchConfig, frame_bits, run_bench};
use dex_hil_sim::bus::{Bus, BusClock, BusConfig};
use dex_hil_sim::closed_loop::{ClosedLoopReport, ClosedLoopSettings};
use dex_hil_sim::compute::{DEFAULT_CPU_HZ, StepCompute};
use dex_hil_sim::flash::{Transfer, flash};
use dex_hil_sim::node::{NodeConfig, NodeTiming, TimeMode, spawn_controller_node};
use dex_hil_sim::plant::{Plant, PlantNode, PlantTiming, SyntheticPlant};
use dex_hil_sim::wire::{Stuffing, WireConfig};
use dex_hil_sim::wire_fd::BusWire;
use dex_runtime::can::FrameLayout;

#[derive(Parser)]
#[command(
    name = "hil-sim",
    about = "Software-in-the-loop over a virtual CAN bus"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
enum PlantKind {
    /// Kinematic stand-in (no MuJoCo).
    Synthetic,
    /// The MuJoCo Jaco environment (feature `mujoco`).
    Mujoco,
}

#[cfg(feature = "mujoco")]
const DEFAULT_PLANT: PlantKind = PlantKind::Mujoco;
#[cfg(not(feature = "mujoco"))]
const DEFAULT_PLANT: PlantKind = PlantKind::Synthetic;

#[derive(Subcommand)]
enum Command {
    /// Run only the bus (and optionally the controller node) until `< quit >` or --seconds.
    Bus(BusArgs),
    /// The plant alone, on a bus started by another process (`hil-sim bus --lockstep`, whose
    /// controller may have been flashed over the bus first): NMT master, lockstep episodes.
    Plant {
        /// The bus, e.g. 127.0.0.1:29536.
        #[arg(long)]
        connect: SocketAddr,
        #[command(flatten)]
        episodes: EpisodeArgs,
        /// Write every applied command, one line per step: `episode step a0 ... a8` (shortest
        /// round-trip decimal, as `trainer eval --actions` writes them).
        #[arg(long)]
        actions: Option<PathBuf>,
        /// The CAN FD frame layout (the bus started with `--fd`, its controller in the FD
        /// layout): the observation in two FD frames, the action in one.
        #[arg(long)]
        fd: bool,
    },
    /// Flash a policy file into a controller node on a bus (`hil-sim bus --controller`): CANopen
    /// program download (SDO into 0x1F50:1, start on 0x1F51:1, 0x1F56:1 checked against the file's
    /// CRC-32). The node must be pre-operational or stopped.
    Flash {
        /// The bus, e.g. 127.0.0.1:29536.
        #[arg(long)]
        connect: SocketAddr,
        /// The controller's node id.
        #[arg(long, default_value_t = 0x10)]
        node: u8,
        /// Segmented SDO download instead of block download.
        #[arg(long)]
        segmented: bool,
        /// Seconds to wait for each SDO response.
        #[arg(long, default_value_t = 1.0)]
        timeout: f64,
        /// Policy file (.dxpl).
        policy: PathBuf,
    },
    /// Closed-loop episodes: plant node and controller node over the bus.
    Run(RunArgs),
    /// Observation to action in bus time over a timed wire (p50/p99/max: wire time, the
    /// controller's compute, queuing): lockstep closed-loop episodes, or a recorded trace.
    Latency(LatencyArgs),
    /// Observation-to-action latency through the bus, period jitter, bus load.
    Bench {
        /// Cycles.
        #[arg(long, default_value_t = 10_000)]
        cycles: usize,
        /// Pace at 20 Hz wall clock (period jitter, missed cycles) instead of back to back.
        #[arg(long)]
        realtime: bool,
        /// Policy file (default: random 44-256-256-9 policy on the cell's layout).
        #[arg(long)]
        policy: Option<PathBuf>,
    },
    /// Run the controller node alone on a SocketCAN interface (feature `socketcan`), real time.
    Node {
        /// Interface name, e.g. can0.
        #[arg(long)]
        socketcan: String,
        /// Policy file.
        #[arg(long)]
        policy: Option<PathBuf>,
    },
    /// Join an SLCAN serial line (the firmware node in QEMU, `-serial tcp:HOST:PORT,server=on`)
    /// to a bus started by another process; runs until either side closes. Prints
    /// `hil-sim slcan-bridge ready: ...` once the device has answered the start-up version
    /// request; no bus frame goes to the device before (a UART not yet enabled loses them).
    SlcanBridge {
        /// The bus, e.g. 127.0.0.1:29536.
        #[arg(long)]
        connect: SocketAddr,
        /// The serial line's TCP socket, e.g. 127.0.0.1:29600.
        #[arg(long)]
        serial: SocketAddr,
        /// Stamp frames to the device with their bus time (Lawicel time stamps): for a
        /// `hil-sim bus --lockstep` bus, so that the firmware runs on bus time.
        #[arg(long)]
        stamp: bool,
        /// Seconds to wait for the device's answer to the start-up version request.
        #[arg(long, default_value_t = 10.0)]
        ready_timeout: f64,
    },
    /// Write a random-weight policy file on the cell's layout (or a mismatched one) for tests.
    MakePolicy {
        /// Output file.
        #[arg(long)]
        out: PathBuf,
        /// Hidden widths, comma-separated.
        #[arg(long, default_value = "64,64", value_delimiter = ',')]
        hidden: Vec<u16>,
        /// Weight seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Write a policy whose observation layout does not match the controller's.
        #[arg(long)]
        mismatched_layout: bool,
        /// Quantise every layer to int8 (format version 2), as `policy quantise` does.
        #[arg(long)]
        int8: bool,
        /// Write a valid policy whose every output is infinite (one hidden layer, the first
        /// `--hidden` width): it loads, and faults at its first evaluation.
        #[arg(long)]
        faulting: bool,
    },
}

/// `hil-sim bus`: the bus alone, optionally with the controller node.
#[derive(Args)]
struct BusArgs {
    /// Port on 127.0.0.1 (0: a free one; the chosen one is printed).
    #[arg(long, default_value_t = 0)]
    port: u16,
    /// candump-format log.
    #[arg(long)]
    log: Option<PathBuf>,
    /// Run the controller node with this policy file (a refused file leaves it pre-operational).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Run the controller node without a policy.
    #[arg(long)]
    controller: bool,
    /// Run a controller node with this node id (1..=31), each with its own policy slots; repeat
    /// it for several on one bus (`--node 1 --node 2`). Implies `--controller`; without it, one
    /// node with the default id 0x10. `--policy` is installed in every node; `diag` reports the
    /// first.
    #[arg(long = "node", value_parser = parse_node_id)]
    nodes: Vec<u8>,
    /// Exit after this many seconds.
    #[arg(long)]
    seconds: Option<f64>,
    /// Frames queued per client before frames to it are dropped.
    #[arg(long, default_value_t = 4096)]
    queue: usize,
    /// Fixed kernel send buffer per client socket in bytes (default: autotuned).
    #[arg(long)]
    sndbuf: Option<usize>,
    #[command(flatten)]
    wire: WireArgs,
    /// Simulated time: the bus clock moves only on `< time US >` and the controller node polls
    /// on SYNC, for a lockstep plant in another process (`hil-sim plant --connect`).
    #[arg(long)]
    lockstep: bool,
    /// The controller node's watchdog: safe-stop when the newest complete observation is
    /// older than this many control periods (the controller's default is 3).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=1000))]
    watchdog_cycles: u32,
}

/// Stuff bits of each frame on the wire.
#[derive(Clone, Copy, ValueEnum, PartialEq, Eq)]
enum StuffingArg {
    /// The frame's own stuff bits (its identifier and data): what the wire carries.
    Exact,
    /// The most a frame of its length can carry: the bound of a schedulability analysis.
    Worst,
}

/// The wire of the virtual bus, and the controller's compute in bus time.
#[derive(Args, Clone)]
struct WireArgs {
    /// Classic CAN bit rate in bit/s: each frame takes its bits over it, the lowest identifier
    /// wins when frames wait, timestamps at the end of frame. 0: untimed (a frame's timestamp is
    /// when it arrived).
    #[arg(long, default_value_t = 500_000, value_parser = clap::value_parser!(u32).range(0..=1_000_000))]
    bitrate: u32,
    /// Stuff bits of each frame.
    #[arg(long, value_enum, default_value_t = StuffingArg::Exact)]
    stuffing: StuffingArg,
    /// Lockstep on a timed wire: the controller's instructions per control step, its answer
    /// leaving that long after the observation (default: `controller_step` of
    /// firmware/budget.txt, as built).
    #[arg(long)]
    step_instructions: Option<u64>,
    /// The controller's clock in Hz, one instruction per cycle (the STM32F4's 168 MHz).
    #[arg(long, default_value_t = DEFAULT_CPU_HZ)]
    cpu_hz: u64,
    /// CAN FD: the bus carries FD frames (socketcand's `< fdsend >` / `< fdframe >`), each over
    /// the nominal `--bitrate` and the data bit rate; the controller node and the plant speak the
    /// FD layout (observation in two FD frames, action in one).
    #[arg(long)]
    fd: bool,
    /// CAN FD's data-phase bit rate in bit/s (with `--fd`; default 2,000,000), at least the
    /// nominal `--bitrate`.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=8_000_000))]
    data_bitrate: Option<u32>,
}

/// CAN FD's data bit rate when `--fd` comes without `--data-bitrate`.
const DEFAULT_DATA_BITRATE: u32 = 2_000_000;

impl WireArgs {
    /// CAN FD's data bit rate, `None` on a classic bus; refuses `--data-bitrate` without `--fd`
    /// and a data bit rate below the nominal one.
    fn fd_data_bitrate(&self) -> Result<Option<u32>> {
        match (self.fd, self.data_bitrate) {
            (false, None) => Ok(None),
            (false, Some(d)) => bail!(
                "--data-bitrate {d} needs --fd: a classic CAN bus has one bit rate (--bitrate)"
            ),
            (true, d) => {
                let d = d.unwrap_or(DEFAULT_DATA_BITRATE);
                if d < self.bitrate {
                    bail!(
                        "--data-bitrate {d} is below the nominal --bitrate {}: CAN FD's data \
                         phase runs at least as fast as its arbitration phase",
                        self.bitrate
                    );
                }
                Ok(Some(d))
            }
        }
    }

    /// The frame layout of the controller node and the plant.
    fn layout(&self) -> FrameLayout {
        if self.fd {
            FrameLayout::Fd
        } else {
            FrameLayout::Classic
        }
    }

    /// The wire, or `None` when untimed.
    fn wire(&self) -> Option<WireConfig> {
        (self.bitrate > 0).then_some(WireConfig {
            bitrate: self.bitrate,
            stuffing: match self.stuffing {
                StuffingArg::Exact => Stuffing::Exact,
                StuffingArg::Worst => Stuffing::WorstCase,
            },
        })
    }

    /// The controller's compute per step.
    fn compute(&self) -> Result<StepCompute> {
        Ok(StepCompute::new(self.step_instructions, self.cpu_hz)?)
    }

    /// A node's timing: in lockstep on a timed wire its answers take the compute.
    fn node_timing(&self, mode: TimeMode) -> Result<NodeTiming> {
        let timed = mode == TimeMode::Lockstep && self.bitrate > 0;
        Ok(NodeTiming {
            mode,
            step_compute_us: if timed { self.compute()?.us() } else { 0 },
        })
    }
}

/// `hil-sim latency`: observation to action in bus time.
#[derive(Args)]
struct LatencyArgs {
    /// Analyse this candump log of a timed lockstep run (`hil-sim run --log`, with the same wire
    /// and compute flags) instead of running episodes.
    #[arg(long)]
    trace: Option<PathBuf>,
    /// Policy file of the run (default: random weights, 44-256-256-9 on the cell's layout, the
    /// size firmware/budget.txt measures).
    #[arg(long)]
    policy: Option<PathBuf>,
    #[command(flatten)]
    episodes: EpisodeArgs,
    #[command(flatten)]
    wire: WireArgs,
    /// The run's candump log (default: a file in the temporary folder, removed afterwards).
    #[arg(long)]
    log: Option<PathBuf>,
    /// The controller's node id.
    #[arg(long, default_value_t = 0x10, value_parser = parse_node_id)]
    node: u8,
}

/// The episodes of `hil-sim plant` and `hil-sim run`: how many, from which starts, on which plant.
#[derive(Args)]
struct EpisodeArgs {
    /// Episodes.
    #[arg(long, default_value_t = 1)]
    episodes: u32,
    /// Run seed; episode i starts from `episode_seed(seed, i)` as in `trainer eval`.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Task (MuJoCo plant): grasp, stack-in-hand, stack, reach.
    #[arg(long, default_value = "stack")]
    task: String,
    /// Which plant (default: mujoco when built with the `mujoco` feature, else synthetic).
    #[arg(long, value_enum, default_value_t = DEFAULT_PLANT)]
    plant: PlantKind,
    /// Steps per episode for the synthetic plant (the MuJoCo plant uses the task's length).
    #[arg(long, default_value_t = 150)]
    steps: u32,
}

/// `hil-sim run`: closed-loop episodes over the bus.
#[derive(Args)]
struct RunArgs {
    /// Policy file.
    #[arg(long)]
    policy: PathBuf,
    #[command(flatten)]
    episodes: EpisodeArgs,
    /// Wall clock at 20 Hz instead of lockstep.
    #[arg(long)]
    realtime: bool,
    /// candump-format log.
    #[arg(long)]
    log: Option<PathBuf>,
    #[command(flatten)]
    wire: WireArgs,
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Bus(args) => bus_command(args),
        Command::Plant {
            connect,
            episodes,
            actions,
            fd,
        } => plant_command(connect, &episodes, actions, fd),
        Command::Run(args) => run_command(&args),
        Command::Latency(args) => latency_command(&args),
        Command::Flash {
            connect,
            node,
            segmented,
            timeout,
            policy,
        } => flash_command(connect, node, segmented, timeout, &policy),
        Command::Bench {
            cycles,
            realtime,
            policy,
        } => bench_command(cycles, realtime, policy),
        Command::Node { socketcan, policy } => node_command(&socketcan, policy),
        Command::SlcanBridge {
            connect,
            serial,
            stamp,
            ready_timeout,
        } => slcan_bridge_command(connect, serial, stamp, ready_timeout),
        Command::MakePolicy {
            out,
            hidden,
            seed,
            mismatched_layout,
            int8,
            faulting,
        } => make_policy(&out, &hidden, seed, mismatched_layout, int8, faulting),
    }
}

fn bus_command(args: BusArgs) -> Result<()> {
    let bus = Bus::start(BusConfig {
        addr: SocketAddr::from(([127, 0, 0, 1], args.port)),
        log: args.log,
        queue_depth: args.queue,
        send_buffer: args.sndbuf,
        wire: args.wire.wire(),
        fd_data_bitrate: args.wire.fd_data_bitrate()?,
        clock: if args.lockstep {
            BusClock::Virtual
        } else {
            BusConfig::default().clock
        },
        ..BusConfig::default()
    })?;
    let stop = Arc::new(AtomicBool::new(false));
    let mut nodes = Vec::new();
    let timing = args.wire.node_timing(if args.lockstep {
        TimeMode::Lockstep
    } else {
        TimeMode::RealTime
    })?;
    if args.controller || args.policy.is_some() || !args.nodes.is_empty() {
        let bytes = match &args.policy {
            Some(p) => Some(std::fs::read(p).with_context(|| format!("reading {}", p.display()))?),
            None => None,
        };
        let ids = if args.nodes.is_empty() {
            vec![dex_runtime::ControllerConfig::default().node_id]
        } else {
            args.nodes.clone()
        };
        for (k, node_id) in ids.into_iter().enumerate() {
            if nodes.iter().any(|(id, _)| *id == node_id) {
                bail!("node id {node_id} given twice");
            }
            let handle = spawn_controller_node(
                bus.addr(),
                bytes.clone(),
                NodeConfig {
                    controller: dex_runtime::ControllerConfig {
                        node_id,
                        watchdog_cycles: args.watchdog_cycles,
                        ..dex_runtime::ControllerConfig::default()
                    },
                    layout: args.wire.layout(),
                },
                timing,
                Arc::clone(&stop),
                (k == 0).then(|| bus.status_slot()),
            )?;
            nodes.push((node_id, handle));
        }
    }
    println!("hil-sim bus listening on {}", bus.addr());
    std::io::stdout().flush()?;
    let start = Instant::now();
    while !bus.quit_requested()
        && args
            .seconds
            .is_none_or(|s| start.elapsed().as_secs_f64() < s)
    {
        if nodes.iter().any(|(_, n)| n.is_finished()) {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    stop.store(true, Ordering::SeqCst);
    for (id, n) in nodes {
        match n.join() {
            Ok(Ok(report)) => eprintln!("controller node {id}: {:?}", report.diagnostics),
            Ok(Err(e)) => eprintln!("controller node {id} failed: {e}"),
            Err(_) => eprintln!("controller node {id} panicked"),
        }
    }
    eprintln!("bus: {:?}", bus.stats());
    bus.shutdown();
    Ok(())
}

fn slcan_bridge_command(
    bus: SocketAddr,
    serial: SocketAddr,
    stamp: bool,
    ready_timeout: f64,
) -> Result<()> {
    let ready_timeout = Duration::try_from_secs_f64(ready_timeout).context("--ready-timeout")?;
    let cfg = dex_hil_sim::slcan_bridge::BridgeConfig {
        bus,
        serial,
        stamp,
        ready_timeout,
    };
    let bridge = dex_hil_sim::slcan_bridge::Bridge::connect(cfg)?;
    // Scripts wait for this line before they put frames for the device on the bus.
    println!(
        "hil-sim slcan-bridge ready: device {} after {} version request(s)",
        bridge.device_version(),
        bridge.stats().probes
    );
    std::io::stdout().flush()?;
    let stop = AtomicBool::new(false);
    let stats = bridge.run(&stop)?;
    eprintln!("slcan-bridge: {stats:?}");
    Ok(())
}

/// A controller node id from the command line (decimal or 0x-hex), 1..=31.
fn parse_node_id(s: &str) -> Result<u8, String> {
    let value = match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(hex) => u8::from_str_radix(hex, 16),
        None => s.parse(),
    }
    .map_err(|e| format!("node id '{s}': {e}"))?;
    dex_runtime::can::messages::check_node_id(value).map_err(|e| e.to_string())
}

fn flash_command(
    connect: SocketAddr,
    node: u8,
    segmented: bool,
    timeout: f64,
    policy: &std::path::Path,
) -> Result<()> {
    let image = std::fs::read(policy).with_context(|| format!("reading {}", policy.display()))?;
    let mut port = dex_hil_sim::client::BusClient::connect(connect, "vcan0")?;
    let how = if segmented {
        Transfer::Segmented
    } else {
        Transfer::Block
    };
    let timeout = Duration::try_from_secs_f64(timeout).context("--timeout")?;
    let done = flash(&mut port, node, &image, how, timeout)
        .with_context(|| format!("flashing {} into node {node}", policy.display()))?;
    println!(
        "flashed {} B ({:?} transfer, {} requests): node {node} runs program {:#010x}",
        done.bytes, done.transfer, done.requests, done.crc
    );
    Ok(())
}

fn run_command(args: &RunArgs) -> Result<()> {
    let bytes = std::fs::read(&args.policy)
        .with_context(|| format!("reading {}", args.policy.display()))?;
    let run = closed_loop(
        bytes,
        &args.episodes,
        &args.wire,
        args.realtime,
        args.log.clone(),
        &mut print_episode,
    )?;
    println!(
        "success {}/{} ({:.1}%) mean return {:.4} mode {}",
        run.successes,
        args.episodes.episodes,
        100.0 * f64::from(run.successes) / f64::from(args.episodes.episodes.max(1)),
        run.total_return / f64::from(args.episodes.episodes.max(1)),
        if args.realtime {
            "realtime"
        } else {
            "lockstep"
        }
    );
    println!("controller: {}", run.controller);
    println!("bus: {:?}", run.bus);
    Ok(())
}

/// The settings of a closed-loop run (lockstep unless `realtime`), validated from the flags.
fn closed_loop_settings(
    episodes: &EpisodeArgs,
    wire: &WireArgs,
    realtime: bool,
    log: Option<PathBuf>,
) -> Result<ClosedLoopSettings> {
    let fd_data_bitrate = wire.fd_data_bitrate()?;
    let mode = if realtime {
        TimeMode::RealTime
    } else {
        TimeMode::Lockstep
    };
    Ok(ClosedLoopSettings {
        episodes: episodes.episodes,
        seed: episodes.seed,
        log,
        wire: wire.wire(),
        fd_data_bitrate,
        layout: wire.layout(),
        node: wire.node_timing(mode)?,
    })
}

/// Closed-loop episodes of the policy file `bytes` on the plant `episodes` names (lockstep unless
/// `realtime`); prints the emergencies the plant received, if any.
fn closed_loop(
    bytes: Vec<u8>,
    episodes: &EpisodeArgs,
    wire: &WireArgs,
    realtime: bool,
    log: Option<PathBuf>,
    on_episode: &mut dyn FnMut(u32, &dex_hil_sim::plant::EpisodeReport),
) -> Result<ClosedLoopReport> {
    let mut plant = make_plant(episodes.plant, &episodes.task, episodes.steps)?;
    let settings = closed_loop_settings(episodes, wire, realtime, log)?;
    let run = dex_hil_sim::closed_loop::run(&settings, bytes, plant.as_mut(), on_episode)?;
    if !run.emergencies.is_empty() {
        println!("emergencies: {:04X?}", run.emergencies);
    }
    Ok(run)
}

fn latency_command(args: &LatencyArgs) -> Result<()> {
    let Some(nominal) = args.wire.wire() else {
        bail!("latency in bus time needs a timed wire: --bitrate above 0");
    };
    let wire = BusWire {
        nominal,
        data_bitrate: args.wire.fd_data_bitrate()?,
    };
    let layout = args.wire.layout();
    let compute = args.wire.compute()?;
    let text = match &args.trace {
        Some(path) => {
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?
        }
        None => {
            let bytes = match &args.policy {
                Some(p) => std::fs::read(p).with_context(|| format!("reading {}", p.display()))?,
                None => dex_runtime::synthetic::jaco_policy(&[256, 256], 1)?,
            };
            let path = args.log.clone().unwrap_or_else(|| {
                std::env::temp_dir().join(format!("hil-sim-latency-{}.log", std::process::id()))
            });
            let run = closed_loop(
                bytes,
                &args.episodes,
                &args.wire,
                false,
                Some(path.clone()),
                &mut |_, _| {},
            )?;
            println!(
                "run: {} episodes, success {}/{}, controller: {}",
                args.episodes.episodes, run.successes, args.episodes.episodes, run.controller
            );
            let text = std::fs::read_to_string(&path)
                .with_context(|| format!("reading {}", path.display()))?;
            if args.log.is_none() {
                let _ = std::fs::remove_file(&path);
            }
            text
        }
    };
    let trace = dex_hil_sim::latency::parse_trace_any(&text)?;
    let report = dex_hil_sim::latency::analyse_any(
        &trace,
        args.node,
        layout,
        wire,
        compute.ns().div_ceil(1000) * 1000,
    )?;
    let rates = match wire.data_bitrate {
        Some(d) => format!("CAN FD {} / {} kbit/s", nominal.bitrate / 1000, d / 1000),
        None => format!("classic {} kbit/s", nominal.bitrate / 1000),
    };
    println!(
        "wire: {rates}, {} stuffing; controller compute: {} instructions per step at {} MHz \
         = {:.3} ms",
        match nominal.stuffing {
            Stuffing::Exact => "exact",
            Stuffing::WorstCase => "worst-case",
        },
        compute.instructions,
        compute.cpu_hz as f64 / 1e6,
        compute.ns() as f64 / 1e6
    );
    println!(
        "{} observations answered, {} unanswered",
        report.cycles.len(),
        report.unanswered
    );
    println!("| part | p50 | p99 | max |");
    println!("|---|---:|---:|---:|");
    let ms = |p: dex_hil_sim::bench::Percentiles| {
        format!(
            "{:.3} ms | {:.3} ms | {:.3} ms |",
            p.p50 / 1e3,
            p.p99 / 1e3,
            p.max / 1e3
        )
    };
    println!("| observation to action | {}", ms(report.total_us()));
    println!("| wire time (both groups) | {}", ms(report.wire_us()));
    println!(
        "| - observation ({} frames) | {}",
        layout.observation_frames(),
        ms(report.observation_wire_us())
    );
    println!(
        "| - actions ({} frame{}) | {}",
        layout.action_frames(),
        if layout.action_frames() == 1 { "" } else { "s" },
        ms(report.action_wire_us())
    );
    println!("| controller compute | {}", ms(report.compute_us()));
    println!("| queuing | {}", ms(report.queuing_us()));
    Ok(())
}

#[cfg(feature = "socketcan")]
fn node_command(iface: &str, policy: Option<PathBuf>) -> Result<()> {
    let bytes = match &policy {
        Some(p) => Some(std::fs::read(p).with_context(|| format!("reading {}", p.display()))?),
        None => None,
    };
    let mut port = dex_hil_sim::port::SocketCanPort::open(iface)?;
    let stop = AtomicBool::new(false);
    let report = dex_hil_sim::node::run_controller_node(
        &mut port,
        bytes.as_deref(),
        dex_runtime::ControllerConfig::default(),
        TimeMode::RealTime,
        &stop,
        None,
    )?;
    eprintln!("controller node: {:?}", report.diagnostics);
    Ok(())
}

#[cfg(not(feature = "socketcan"))]
fn node_command(_iface: &str, _policy: Option<PathBuf>) -> Result<()> {
    bail!(
        "built without the `socketcan` feature: `cargo build -p dex-hil-sim --features socketcan`"
    )
}

/// One line per episode, as `trainer eval --actions` prints them.
fn print_episode(e: u32, r: &dex_hil_sim::plant::EpisodeReport) {
    println!(
        "episode {e} seed {} return {:.4} success {} steps {} steps_without_action {}",
        r.seed, r.episode_return, r.success, r.steps, r.steps_without_action
    );
}

/// `hil-sim plant`: lockstep episodes against a controller on another process's bus.
fn plant_command(
    addr: SocketAddr,
    ep: &EpisodeArgs,
    actions: Option<PathBuf>,
    fd: bool,
) -> Result<()> {
    let (episodes, seed) = (ep.episodes, ep.seed);
    let mut plant = make_plant(ep.plant, &ep.task, ep.steps)?;
    let layout = if fd {
        FrameLayout::Fd
    } else {
        FrameLayout::Classic
    };
    let mut node = PlantNode::connect_remote(addr, PlantTiming::Lockstep, 0x10)
        .with_context(|| format!("cannot reach the bus at {addr}"))?
        .with_layout(layout);
    node.start_controller()?;
    let r = node.episodes(plant.as_mut(), episodes, seed, true, &mut print_episode)?;
    let successes = r.successes;
    let mut lines = String::new();
    for (e, actions) in r.actions.iter().enumerate() {
        for (t, a) in actions.iter().enumerate() {
            lines.push_str(&dex_runtime::action_trace::action_line(e as u64, t, a));
        }
    }
    if !node.emergencies().is_empty() {
        println!("emergencies: {:04X?}", node.emergencies());
    }
    println!(
        "success {successes}/{episodes} ({:.1}%) mode lockstep-remote",
        100.0 * f64::from(successes) / f64::from(episodes.max(1))
    );
    if let Some(path) = actions {
        std::fs::write(&path, lines).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

fn make_plant(kind: PlantKind, task: &str, steps: u32) -> Result<Box<dyn Plant>> {
    match kind {
        PlantKind::Synthetic => {
            let _ = task;
            Ok(Box::new(SyntheticPlant::new(steps)))
        }
        #[cfg(feature = "mujoco")]
        PlantKind::Mujoco => {
            let task: dex_env::Task = task.parse().map_err(|e| anyhow::anyhow!("{e:?}"))?;
            Ok(Box::new(dex_hil_sim::plant::MujocoPlant::new(task)?))
        }
        #[cfg(not(feature = "mujoco"))]
        PlantKind::Mujoco => bail!(
            "built without the `mujoco` feature: use --plant synthetic, or build with \
             `cargo build -p dex-hil-sim --features mujoco` (after scripts/setup-mujoco.sh)"
        ),
    }
}

fn bench_command(cycles: usize, realtime: bool, policy: Option<PathBuf>) -> Result<()> {
    let policy = match policy {
        Some(p) => std::fs::read(&p).with_context(|| format!("reading {}", p.display()))?,
        None => dex_runtime::synthetic::jaco_policy(&[256, 256], 1)?,
    };
    let r = run_bench(&BenchConfig {
        cycles,
        real_time: realtime,
        policy,
    })?;
    println!(
        "mode {} cycles {} missed {}",
        if realtime {
            "realtime-20Hz"
        } else {
            "back-to-back"
        },
        r.cycles,
        r.missed
    );
    println!(
        "obs-to-action latency through the bus (us): {}",
        r.latency_us
    );
    if realtime {
        println!(
            "observation send lateness vs 50 ms grid (us): {}",
            r.send_lateness_us
        );
        println!(
            "action period jitter |dt - 50 ms| (us): {}",
            r.period_jitter_us
        );
    }
    println!(
        "frames per cycle {:.2}; bits per cycle {:.0} (no stuffing) .. {:.0} (worst-case stuffing); \
         8-byte frame {:?} bits",
        r.frames_per_cycle,
        r.bits_per_cycle.0,
        r.bits_per_cycle.1,
        frame_bits(8)
    );
    for rate in [500_000.0, 1_000_000.0] {
        let (lo, hi) = r.load_percent(rate);
        println!("bus load at {} kbit/s: {lo:.2}% .. {hi:.2}%", rate / 1000.0);
    }
    println!("queue drops {}", r.queue_drops);
    println!("controller: {}", r.controller_status);
    if r.missed > 0 && !realtime {
        bail!("{} cycles got no action", r.missed);
    }
    Ok(())
}

fn make_policy(
    out: &PathBuf,
    hidden: &[u16],
    seed: u64,
    mismatched: bool,
    int8: bool,
    faulting: bool,
) -> Result<()> {
    let bytes = if faulting {
        dex_runtime::synthetic::jaco_policy_faulting(hidden.first().copied().unwrap_or(8), seed)?
    } else if mismatched {
        use dex_policy::synth::{SynthSpec, synth_policy};
        use dex_runtime::interface::ACTION_JOINTS;
        let action: Vec<(&str, f32, f32, f32)> = ACTION_JOINTS
            .iter()
            .map(|j| (j.name, j.scale, j.min, j.max))
            .collect();
        synth_policy(&SynthSpec {
            task: dex_policy::Task::Stack,
            observation: &[("some_other_layout", 44)],
            action: &action,
            hidden,
            hidden_activation: dex_policy::Activation::Relu,
            output_activation: dex_policy::Activation::Tanh,
            seed,
        })?
    } else {
        dex_runtime::synthetic::jaco_policy(hidden, seed)?
    };
    let bytes = if int8 {
        let aligned = dex_runtime::aligned::aligned_copy(&bytes);
        let view = dex_policy::PolicyView::decode(aligned.as_bytes())?;
        dex_policy::int8::quantise_policy(&view, |_| true, None)?
    } else {
        bytes
    };
    std::fs::write(out, bytes).with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}
