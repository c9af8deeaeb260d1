//! `dex-runtime`: the controller that runs an exported policy at 20 Hz behind CAN frames.
#![no_std]
#![deny(missing_docs)]

pub mod interface;
