//! CANopen (CiA 301) pieces of the controller as a device: the object dictionary as the SDO server
//! sees it ([`od`]), the SDO server itself ([`sdo`]: expedited, segmented and block transfers),
//! the communication and manufacturer objects ([`device`]), the PDO objects ([`pdo`]), program download onto the policy
//! slots (CiA 302-3: [`program`]) and the abort codes every refusal is answered with ([`abort`]).
//! No heap: a transfer streams into the dictionary, which decides where the bytes go (a policy
//! slot for program data). The controller serves them on `0x600 + node` / `0x580 + node`
//! ([`crate::Controller::on_frame_slots`], its timeout through [`crate::Controller::poll_slots`]).

pub mod abort;
pub mod device;
#[cfg(feature = "std")]
pub mod eds;
pub mod od;
pub mod pdo;
pub mod program;
pub mod sdo;

pub use abort::SdoAbort;
pub use od::{Access, DataType, Entry, Object, ObjectDictionary, ObjectKind, SubObject, Value};
pub use sdo::{SdoFrame, SdoServer, abort_frame};
