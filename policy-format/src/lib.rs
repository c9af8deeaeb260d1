//! `dex-policy`: the compact, versioned, checksummed file a trained policy travels in.
//!
//! A file is a 24-byte [`Header`] (magic `DXPL`, format version, layout hash, sizes, CRC-32), a
//! postcard-encoded [`Body`] (task, observation and action layouts, control period, network
//! description, provenance) and the stored values (observation normalisation, then weights and
//! biases layer by layer), 4-byte aligned. Version 2 adds int8 layers ([`LayerDtype::Int8`]:
//! int8 weights packed as in [`int8`], one f32 scale per output channel, f32 biases); version 1
//! files still decode. `docs/policy-format.md` is the byte-level specification.
//!
//! [`PolicyView::decode`] checks everything a file can get wrong and borrows from the file bytes:
//! no allocator is needed. The values can be borrowed as `&[f32]` ([`Values::as_slice`]) or
//! copied into a caller-owned buffer ([`Values::copy_into`]). [`encode_into`] writes into a
//! caller-owned buffer; with the `std` feature [`encode_to_vec`] returns a vector.
//!
//! This crate does not evaluate networks: `dex-runtime` does.
#![no_std]
#![deny(missing_docs)]

#[cfg(feature = "std")]
extern crate std;

mod body;
mod encode;
mod error;
mod header;
pub mod int8;
#[cfg(feature = "std")]
pub mod synth;
mod view;
mod weights;

pub use body::{
    ActionJoint, Activation, Body, LayerDtype, LayerSpec, MAX_ACTIONS, MAX_LAYERS, MAX_NAME_LEN,
    MAX_OBS_FIELDS, ObsField, Provenance, Task,
};
pub use encode::{encode_data_into, encode_into};
#[cfg(feature = "std")]
pub use encode::{encode_data_to_vec, encode_to_vec};
pub use error::{CapacityItem, FormatError};
pub use header::{
    CRC_OFFSET, CRC32, FORMAT_VERSION, HEADER_LEN, Header, MAGIC, MIN_FORMAT_VERSION, file_crc,
    layout_hash, values_offset,
};
pub use view::{Capacity, LayerLayout, PolicyView, body_layout_hash};
pub use weights::Values;
