//! `dex-hil-sim`: software-in-the-loop for the controller, over a virtual CAN bus.
//!
//! - [`bus`]: a TCP server speaking the socketcand subset that python-can's `socketcand` interface
//!   needs ([`protocol`]; CAN FD frames with socketcand's `fdsend` / `fdframe` verbs); one global frame order, bus-time stamps, per-client bounded queues,
//!   fault injection (drop, corrupt, delay, bus-off) and a candump log.
//! - [`client`]: a socketcand client implementing `embedded_can::blocking::Can`: the adapter that
//!   puts a node on the bus.
//! - [`node`]: the controller node, the `dex_runtime::Controller` a microcontroller runs, in
//!   real-time (wall clock) or lockstep (bus time, SYNC-driven) mode.
//! - [`plant`]: the plant node (synthetic plant, or the MuJoCo environment with feature `mujoco`)
//!   that sends observations every 50 ms and applies the newest valid action; also the NMT master.
//! - [`closed_loop`]: closed-loop episodes (`hil-sim run`): the plant node and the controller
//!   node over a bus in this process.
//! - [`flash`]: policy flashing over CAN: the node's slot storage, and the tool's SDO client
//!   (CiA 302-3 program download: 0x1F50 data, 0x1F51 start, 0x1F56 check).
//! - [`bench`]: observation-to-action latency, period jitter, frames and bus load.
//! - [`slcan_bridge`]: joins an SLCAN serial line (the firmware node under QEMU) to the bus.
//! - [`wire`]: classic CAN frames' time on the wire (bit stuffing) and arbitration, the model of the
//!   wire-time figures.
//! - [`wire_fd`]: CAN FD frames' time on the wire (two bit rates; exact or worst-case stuffing):
//!   the FD bus's wire (`hil-sim bus --fd --data-bitrate D`) and the budget model.
//! - [`compute`]: the controller's compute per step on the Cortex-M4F (`firmware/budget.txt`), the
//!   time a lockstep node's answer takes in bus time.
//! - [`latency`]: observation to action in bus time from a timed bus's frame trace: wire time,
//!   compute, queuing.
//! - [`arbitration`]: the wire as the bus uses it (`hil-sim bus --bitrate`): frames wait while it
//!   is busy, the lowest identifier goes next, timestamps at the end of frame.
//!
//! With feature `socketcan`, [`port`] runs the controller node on a Linux SocketCAN interface
//! (untested here: the development machines have no `AF_CAN`).
#![deny(missing_docs)]

pub mod arbitration;
pub mod bench;
pub mod bus;
pub mod client;
pub mod closed_loop;
pub mod compute;
pub mod flash;
pub mod latency;
pub mod node;
pub mod plant;
#[cfg(feature = "socketcan")]
pub mod port;
pub mod protocol;
pub mod slcan_bridge;
pub mod wire;
pub mod wire_fd;
