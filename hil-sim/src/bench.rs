//! Latency and timing benchmark through the bus: a driver plays the plant with synthetic
//! observations; the controller node runs in real-time mode on its own thread; everything passes
//! the TCP bus (two hops each way: driver -> bus -> controller, controller -> bus -> driver).

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use dex_runtime::can::e2e::E2eSender;
use dex_runtime::can::messages::{NmtCommand, OBS_FRAMES, encode_observation, nmt_frame};
use dex_runtime::interface::CONTROL_PERIOD_US;
use dex_runtime::synthetic::observation_trace;
use embedded_can::Frame;

use crate::bus::{Bus, BusConfig};
use crate::client::{BusClient, ClientError, Received};
use crate::node::{NodeError, TimeMode, spawn_controller_node};
use crate::plant::ActionAssembler;

/// Errors of the benchmark.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// Bus start-up failed.
    #[error(transparent)]
    Bus(#[from] crate::bus::BusError),
    /// A connection failed.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// The controller node failed.
    #[error(transparent)]
    Node(#[from] NodeError),
    /// The controller did not start.
    #[error("controller did not become operational")]
    NotOperational,
}

/// Benchmark settings.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// Cycles to measure.
    pub cycles: usize,
    /// Pace cycles at 20 Hz of wall clock (else back to back).
    pub real_time: bool,
    /// Policy file for the controller node.
    pub policy: Vec<u8>,
}

/// p50, p99 and max of a sample, in the sample's unit.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Percentiles {
    /// Samples.
    pub n: usize,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Percentiles {
    /// Percentiles of `v` (sorted in place).
    pub fn of(v: &mut [f64]) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let pick = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Percentiles {
            n: v.len(),
            p50: pick(0.5),
            p99: pick(0.99),
            max: pick(1.0),
        }
    }
}

impl std::fmt::Display for Percentiles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "n={} p50 {:.1} p99 {:.1} max {:.1}",
            self.n, self.p50, self.p99, self.max
        )
    }
}

/// Bits of a classic base-format data frame with `dlc` bytes: (without stuffing, worst-case
/// stuffing). SOF..EOF plus 3 bits intermission = 47 + 8 dlc; stuffing can add one bit per 4 of the
/// 34 + 8 dlc stuffed bits.
pub const fn frame_bits(dlc: usize) -> (usize, usize) {
    let nominal = 47 + 8 * dlc;
    (nominal, nominal + (34 + 8 * dlc - 1) / 4)
}

/// Results.
#[derive(Debug, Clone, Default)]
pub struct BenchReport {
    /// Cycles run.
    pub cycles: usize,
    /// Last observation frame written to first... last action frame read, microseconds.
    pub latency_us: Percentiles,
    /// Real time: deviation of the observation send instants from the 50 ms grid, microseconds.
    pub send_lateness_us: Percentiles,
    /// Real time: |interval between completed actions - 50 ms|, microseconds.
    pub period_jitter_us: Percentiles,
    /// Cycles whose action did not arrive within the period.
    pub missed: usize,
    /// Frames on the bus per cycle.
    pub frames_per_cycle: f64,
    /// Bits per cycle (no stuffing, worst-case stuffing).
    pub bits_per_cycle: (f64, f64),
    /// Controller diagnostics at the end.
    pub controller_status: String,
    /// Bus counters at the end.
    pub queue_drops: u64,
}

impl BenchReport {
    /// Bus load at `bitrate` bit/s for 20 Hz cycles: (no stuffing, worst case), in percent.
    pub fn load_percent(&self, bitrate: f64) -> (f64, f64) {
        let hz = 1e6 / f64::from(CONTROL_PERIOD_US);
        (
            100.0 * self.bits_per_cycle.0 * hz / bitrate,
            100.0 * self.bits_per_cycle.1 * hz / bitrate,
        )
    }
}

/// Runs the benchmark.
pub fn run_bench(cfg: &BenchConfig) -> Result<BenchReport, BenchError> {
    let bus = Bus::start(BusConfig::default())?;
    let stop = Arc::new(AtomicBool::new(false));
    let status = bus.status_slot();
    let node = spawn_controller_node(
        bus.addr(),
        Some(cfg.policy.clone()),
        dex_runtime::ControllerConfig::default(),
        TimeMode::RealTime,
        Arc::clone(&stop),
        Some(Arc::clone(&status)),
    )?;
    let result = drive(&bus, cfg);
    stop.store(true, Ordering::SeqCst);
    let _ = node.join();
    let mut report = result?;
    report.controller_status = status.lock().map(|s| s.clone()).unwrap_or_default();
    report.queue_drops = bus.stats().queue_drops;
    bus.shutdown();
    Ok(report)
}

fn drive(bus: &Bus, cfg: &BenchConfig) -> Result<BenchReport, BenchError> {
    let mut client = BusClient::connect(bus.addr(), "vcan0")?;
    let mut actions = ActionAssembler::new(0x10);
    // Start: wait for pre-operational, NMT start, wait for operational.
    let mut state = None;
    let deadline = Instant::now() + Duration::from_secs(3);
    let mut started = false;
    while state != Some(0x05) {
        if Instant::now() > deadline {
            return Err(BenchError::NotOperational);
        }
        if let Some(Received::Frame(f, _)) = client.receive_timeout(Duration::from_millis(10))?
            && f.standard_id() == Some(0x710)
        {
            state = f.data().first().copied();
        }
        if state == Some(0x7F) && !started {
            client.queue(&nmt_frame(NmtCommand::Start, 0x10));
            client.flush()?;
            started = true;
        }
    }
    let trace = observation_trace(64, 7);
    let mut tx = [E2eSender::default(); OBS_FRAMES];
    let period = Duration::from_micros(u64::from(CONTROL_PERIOD_US));
    let before = bus.stats().frames_on_bus;
    let mut seen_dlc: HashMap<u16, (usize, u64)> = HashMap::new();
    let mut latency = Vec::with_capacity(cfg.cycles);
    let mut lateness = Vec::new();
    let mut arrivals: Vec<Option<Instant>> = Vec::with_capacity(cfg.cycles);
    let mut missed = 0;
    let t_start = Instant::now() + period;
    for i in 0..cfg.cycles {
        let sample = (i % 16) as u8;
        if cfg.real_time {
            let due = t_start + period * i as u32;
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
            lateness.push(Instant::now().saturating_duration_since(due).as_secs_f64() * 1e6);
        }
        for f in encode_observation(0x10, &trace[i % trace.len()], sample, &mut tx) {
            client.queue(&f);
        }
        let t0 = Instant::now();
        client.flush()?;
        let limit = if cfg.real_time {
            period.mul_f32(0.9)
        } else {
            Duration::from_secs(1)
        };
        let deadline = t0 + limit;
        let mut done = None;
        while done.is_none() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            match client.receive_timeout(left)? {
                Some(Received::Frame(f, _)) => {
                    if let Some(id) = f.standard_id() {
                        let e = seen_dlc.entry(id).or_insert((f.data().len(), 0));
                        e.1 += 1;
                    }
                    if actions.push(&f) == Some(sample) {
                        done = Some(Instant::now());
                    }
                }
                // The bench runs on a classic bus: no FD frames come.
                Some(Received::Error(..) | Received::Fd(..)) => {}
                None => break,
            }
        }
        match done {
            Some(t1) => latency.push((t1 - t0).as_secs_f64() * 1e6),
            None => missed += 1,
        }
        arrivals.push(done);
    }
    let cycles = cfg.cycles.max(1) as f64;
    let on_bus = bus.stats().frames_on_bus.saturating_sub(before) as f64;
    // Bits: the driver's 15 observation frames per cycle plus what it received from the controller.
    let obs_bits = frame_bits(8);
    let mut bits = (
        OBS_FRAMES as f64 * obs_bits.0 as f64 * cycles,
        OBS_FRAMES as f64 * obs_bits.1 as f64 * cycles,
    );
    for (dlc, count) in seen_dlc.values() {
        let b = frame_bits(*dlc);
        bits.0 += b.0 as f64 * *count as f64;
        bits.1 += b.1 as f64 * *count as f64;
    }
    let mut jitter: Vec<f64> = arrivals
        .windows(2)
        .filter_map(|w| match (w[0], w[1]) {
            (Some(a), Some(b)) if cfg.real_time => {
                Some(((b - a).as_secs_f64() * 1e6 - period.as_secs_f64() * 1e6).abs())
            }
            _ => None,
        })
        .collect();
    Ok(BenchReport {
        cycles: cfg.cycles,
        latency_us: Percentiles::of(&mut latency),
        send_lateness_us: Percentiles::of(&mut lateness),
        period_jitter_us: Percentiles::of(&mut jitter),
        missed,
        frames_per_cycle: on_bus / cycles,
        bits_per_cycle: (bits.0 / cycles, bits.1 / cycles),
        controller_status: String::new(),
        queue_drops: 0,
    })
}
