//! Files in and out of the learner: what a run reads and writes besides its checkpoints.
//!
//! - [`atomic_write`]: the one atomic, durable file write (temporary file, fsync, rename, fsync of
//!   the folder) behind every file that must survive a crash: checkpoints, demo and policy files,
//!   run settings and logs.
//! - [`comparison_record`]: a `trainer compare` record, and records of disjoint starts pooled
//!   into one comparison (a long paired test run in chunks).
//! - [`demos`]: demonstrations recorded as data (versioned, checksummed `.dxdm` files).
//! - [`export`]: a trained actor as a `dex-policy` file; [`int8_export`]: its int8 twin
//!   (calibrate, equalise, quantise, measure).
//! - [`record_settings`]: how demonstrations are recorded (noise, close bursts, which episodes
//!   are kept); read back from files of earlier builds.
//! - [`policy_import`]: a policy file back into the learner's actor (the start of RL fine-tuning).
//! - [`result_record`]: an evaluation as a `docs/results/` record.
//! - [`soup`]: a weight-space average of policy files of one network (seeds of a fine-tune, and
//!   the clone they started from).

pub mod atomic_write;
pub mod comparison_record;
pub mod demos;
pub mod export;
pub mod int8_export;
pub mod policy_import;
pub mod record_settings;
pub mod result_record;
pub mod soup;
