//! The flashing tool's side as the controller sees it: a staged file and its verification,
//! reduced to what reaches the controller (the file `load_policy` gets). The controller's own
//! program download (its SDO server into two slots) is fuzzed by `program_download`
//! (`crate::program`).

use dex_policy::PolicyView;
use dex_runtime::{Controller, ControllerConfig};

use super::WIDTH;

/// The staging slot of a transfer (program download reduced to what reaches the controller: the
/// file that `load_policy` gets).
#[derive(Debug)]
pub(crate) enum Staging {
    Empty,
    Receiving { image: usize, data: Vec<u8> },
    Verified { image: usize, data: Vec<u8> },
}

/// Whether a fresh controller takes `view` (program download's verification).
pub(crate) fn verifies(view: &PolicyView<'_>, cfg: ControllerConfig) -> bool {
    Controller::<WIDTH>::new(cfg).load_policy(view).is_ok()
}
