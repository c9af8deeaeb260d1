//! `dex-policy-tool`: policy files in and out of the toolkit.
//!
//! The `policy` command line (feature `cli`: inspect, verify, quantise, `import` and
//! `export-onnx`) and the library behind its conversions, which the Python package uses too:
//!
//! - [`onnx_import`]: an ONNX model of an MLP policy (what `torch.onnx.export` writes for a
//!   PyTorch or Stable-Baselines3 actor) as a `.dxpl` file with the cell's layout;
//! - [`onnx_export`]: a `.dxpl` file as an ONNX model that onnxruntime, Netron and converters read,
//!   with its normalisation, action scaling and channel names;
//! - [`onnx_schema`]: the ONNX protobuf messages they need (`prost`).
//!
//! docs/policy-format.md has the recipe and the rules of both directions.
#![deny(missing_docs)]

pub mod error;
pub mod onnx_export;
pub mod onnx_import;
pub mod onnx_schema;

pub use error::OnnxError;
pub use onnx_export::{export_onnx, model as onnx_model};
pub use onnx_import::{ImportSettings, Imported, OutputUnits, import_onnx};
