//! The flashing tool's side: the staging slot of a segmented transfer and the flash server's
//! verification of a received file.

use dex_policy::PolicyView;
use dex_runtime::{Controller, ControllerConfig};

use super::WIDTH;

/// The staging slot of a transfer (the protocol of `hil-sim`'s flash server, reduced to what
/// reaches the controller: the file that `load_policy` gets).
#[derive(Debug)]
pub(crate) enum Staging {
    Empty,
    Receiving { image: usize, data: Vec<u8> },
    Verified { image: usize, data: Vec<u8> },
}

/// Whether a fresh controller takes `view` (the flash server's verification).
pub(crate) fn verifies(view: &PolicyView<'_>, cfg: ControllerConfig) -> bool {
    Controller::<WIDTH>::new(cfg).load_policy(view).is_ok()
}
