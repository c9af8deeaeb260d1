//! The observation-to-action time of the cell's frames on a classic CAN bus, from the wire model
//! (`dex_hil_sim::wire`) and the controller's instruction count on the Cortex-M4F
//! (`firmware/budget.txt`): the plant queues the 15 observation frames at once, the controller
//! computes after the last one arrives, then sends the 3 action frames.
//!
//! Then the same with CAN FD (`dex_hil_sim::wire_fd`): the runtime's FD layout
//! (`dex_runtime::can::fd_messages`), the observation's values (2 bytes each, as in the classic
//! frames) in two frames of an FD length with the 2-byte E2E header each, the action in one; a
//! calculation, which `hil-sim latency --fd` measures on the bus.
//!
//! `cargo run -p dex-hil-sim --example wire_budget [INSTRUCTIONS_PER_STEP] [CPU_HZ]`
//! (defaults: `controller_step` of firmware/budget.txt, 168 MHz, one instruction per cycle: a
//! lower bound of the compute time on a Cortex-M4F, whose loads and multiplies can take more).

use dex_hil_sim::compute::{DEFAULT_CPU_HZ, StepCompute};
use dex_hil_sim::wire::{Offer, bits_ns, schedule, unstuffed_bits, worst_case_bits};
use dex_hil_sim::wire_fd::{FdWire, fd_bits};
use dex_runtime::ControllerConfig;
use dex_runtime::can::fd_messages::{FD_ACTION_LEN, FD_OBS_FRAMES, FD_OBS_LEN};
use dex_runtime::can::messages::{ACTION_FRAMES, OBS_FRAMES, rpdo_cob_id, tpdo_cob_id};

fn main() -> Result<(), dex_hil_sim::compute::ComputeError> {
    let args: Vec<String> = std::env::args().collect();
    let compute = StepCompute::new(
        args.get(1).and_then(|a| a.parse().ok()),
        args.get(2)
            .and_then(|a| a.parse().ok())
            .unwrap_or(DEFAULT_CPU_HZ),
    )?;
    let (instructions, hz) = (compute.instructions, compute.cpu_hz);
    let compute_ns = compute.ns();
    println!(
        "controller: {instructions} instructions per step at {} MHz = {:.2} ms",
        hz / 1_000_000,
        compute_ns as f64 / 1e6
    );
    println!(
        "| bitrate | stuffing | observation on the wire | compute | actions on the wire | observation to last action |"
    );
    println!("|---|---|---:|---:|---:|---:|");
    for bitrate in [125_000u32, 250_000, 500_000, 1_000_000] {
        for (name, bits) in [
            ("none", unstuffed_bits(8)),
            ("worst case", worst_case_bits(8)),
        ] {
            let obs: Vec<Offer> = (0..OBS_FRAMES)
                .map(|k| Offer {
                    ready_ns: 0,
                    id: rpdo_cob_id(ControllerConfig::default().node_id, k),
                    bits,
                })
                .collect();
            let obs_end = schedule(&obs, bitrate, 0)
                .iter()
                .map(|s| s.end_ns)
                .max()
                .unwrap_or(0);
            let ready = obs_end + compute_ns;
            let act: Vec<Offer> = (0..ACTION_FRAMES)
                .map(|k| Offer {
                    ready_ns: ready,
                    id: tpdo_cob_id(ControllerConfig::default().node_id, k),
                    bits,
                })
                .collect();
            let act_end = schedule(&act, bitrate, obs_end)
                .iter()
                .map(|s| s.end_ns)
                .max()
                .unwrap_or(ready);
            let ms = |ns: u64| ns as f64 / 1e6;
            println!(
                "| {} kbit/s | {name} | {:.2} ms | {:.2} ms | {:.2} ms | {:.2} ms |",
                bitrate / 1000,
                ms(obs_end),
                ms(compute_ns),
                ms(act_end - ready),
                ms(act_end)
            );
            debug_assert_eq!(
                act_end - ready,
                bits_ns(bits, bitrate) * ACTION_FRAMES as u64
            );
        }
    }
    fd_table(compute_ns, hz);
    Ok(())
}

/// The observation in two FD frames, the action in one: the loop's time at three bit-rate pairs.
fn fd_table(compute_ns: u64, hz: u64) {
    const OBS_FD_FRAMES: usize = FD_OBS_FRAMES;
    const GOAL_NS: u64 = 1_500_000;
    let (obs_len, act_len) = (FD_OBS_LEN, FD_ACTION_LEN);
    println!();
    println!(
        "CAN FD (model): observation in {OBS_FD_FRAMES} frames of {obs_len} bytes, action in one of \
         {act_len} bytes"
    );
    println!(
        "| nominal / data bit rate | stuffing | observation on the wire | compute | actions on the wire | observation to last action | compute that fits 1.5 ms |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|");
    for (nominal, data) in [
        (500_000u32, 2_000_000u32),
        (1_000_000, 2_000_000),
        (1_000_000, 5_000_000),
    ] {
        let wire = FdWire {
            nominal_bitrate: nominal,
            data_bitrate: data,
        };
        for (name, worst) in [("none", false), ("worst case", true)] {
            let obs = OBS_FD_FRAMES as u64 * wire.frame_ns(fd_bits(false, obs_len, worst));
            let act = wire.frame_ns(fd_bits(false, act_len, worst));
            let total = obs + compute_ns + act;
            let left_ns = GOAL_NS.saturating_sub(obs + act);
            let ms = |ns: u64| ns as f64 / 1e6;
            println!(
                "| {} kbit/s / {} Mbit/s | {name} | {:.3} ms | {:.2} ms | {:.3} ms | {:.2} ms | {:.2} ms = {} instructions |",
                nominal / 1000,
                data / 1_000_000,
                ms(obs),
                ms(compute_ns),
                ms(act),
                ms(total),
                ms(left_ns),
                u128::from(left_ns) * u128::from(hz) / 1_000_000_000
            );
        }
    }
}
