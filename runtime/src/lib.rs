//! `dex-runtime`: the controller that runs an exported policy at 20 Hz behind CAN frames.
//!
//! - [`mlp::Mlp`] evaluates a policy file's network with compile-time capacity, borrowing the
//!   weights from the file, bit-identically on every target; f32 and int8 layers (format version
//!   2) alike, chosen by the file.
//! - [`controller::Controller`] wraps it in a CANopen-style state machine with a watchdog: it takes
//!   frames ([`embedded_can::Frame`]) and time ([`clock::Clock`]) and returns frames to send.
//! - [`slots::PolicySlots`] keeps two policy slots in caller-provided regions (flash sectors):
//!   CANopen program download writes the inactive one, which is verified before the controller
//!   activates it; roll-back to the previous policy, by request or after a faulty first evaluation.
//! - [`can`] holds the frame type, AUTOSAR-E2E-profile-11-style protection and the cell's messages;
//!   [`interface`] the observation and action layout they carry.
//! - [`canopen`] holds the CiA 301 pieces of the controller as a device: the SDO server over an
//!   object dictionary, with CiA 301 abort codes, and program download (CiA 302-3) onto the slots;
//!   the controller serves it on `0x600 + node` ([`Controller::on_frame_slots`]).
//! - [`seeds`] holds [`seeds::episode_seed`], the start seed of each evaluation episode, shared by
//!   every program that runs episodes.
//! - [`aligned`] (`std` only) holds [`aligned::aligned_copy`], the 8-byte-aligned copy of a policy
//!   file that host programs decode and evaluate in place; [`synthetic`] (`std`) seeded synthetic
//!   policies and observation traces (a policy where there is no trained one, benchmarks);
//!   [`action_trace`] (`std`) the line format of action traces; `testkit` (`std`) test vectors
//!   and frames for tests.
//!
//! `#![no_std]`, no `alloc`, no heap: every buffer has a size fixed at compile time, and one call
//! does bounded work (at most one forward pass). It does not drive a CAN peripheral: a board
//! support crate moves frames between the peripheral and the controller.
#![no_std]
#![deny(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

#[cfg(feature = "std")]
pub mod action_trace;
#[cfg(feature = "std")]
pub mod aligned;
pub mod can;
pub mod canopen;
pub mod clock;
pub mod controller;
#[cfg(feature = "std")]
pub mod dbc;
pub mod envelope;
pub mod error;
pub mod features;
mod int8;
pub mod interface;
pub mod jaco_kinematics;
pub mod kinematics;
pub mod mlp;
pub mod observation;
pub mod seeds;
pub mod slots;
#[cfg(feature = "std")]
pub mod synthetic;
#[cfg(feature = "std")]
pub mod testkit;

pub use clock::{Clock, MockClock};
pub use controller::{Controller, ControllerConfig, Diagnostics, FaultCode, Outbox, State};
pub use error::{EvalError, LoadError};
pub use mlp::{Mlp, Network};
pub use slots::{PolicySlots, SlotError};
