//! Every way a policy file can be wrong, one variant each.

use core::fmt;

/// Which capacity limit a policy exceeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CapacityItem {
    /// Observation dimension (network input width).
    Observation,
    /// Action dimension (network output width).
    Action,
    /// Width of a hidden layer.
    Width,
    /// Number of layers.
    Layers,
    /// Number of stored f32 values (weights, biases and normalisation).
    Weights,
}

impl fmt::Display for CapacityItem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            CapacityItem::Observation => "observation dimension",
            CapacityItem::Action => "action dimension",
            CapacityItem::Width => "layer width",
            CapacityItem::Layers => "layer count",
            CapacityItem::Weights => "stored value count",
        })
    }
}

/// Why a policy file was rejected (decoding, validation or a mismatch with the controller).
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum FormatError {
    /// The file is shorter than its header or than the sizes its header announces.
    Truncated {
        /// Bytes the file must have.
        needed: usize,
        /// Bytes it has.
        got: usize,
    },
    /// The file is longer than its header announces.
    TrailingBytes {
        /// Bytes the header announces.
        expected: usize,
        /// Bytes the file has.
        got: usize,
    },
    /// The first four bytes are not the policy magic `DXPL`.
    BadMagic {
        /// The bytes found.
        found: [u8; 4],
    },
    /// The file's format version is not one this reader understands.
    UnsupportedVersion {
        /// Version in the file.
        found: u16,
        /// Newest version this reader supports.
        supported: u16,
    },
    /// Reserved header flags are set.
    UnknownFlags {
        /// The flag word found.
        flags: u16,
    },
    /// The CRC-32 stored in the header does not match the contents.
    CrcMismatch {
        /// CRC stored in the header.
        stored: u32,
        /// CRC computed over the file.
        computed: u32,
    },
    /// The postcard body could not be decoded (malformed, or a list longer than the format allows).
    MalformedBody,
    /// Padding between body and weights is not zero.
    NonZeroPadding,
    /// The layout hash in the header does not match the layout in the body.
    LayoutHashMismatch {
        /// Hash stored in the header.
        stored: u32,
        /// Hash computed from the body.
        computed: u32,
    },
    /// A layer's size is zero or the layer list is empty.
    EmptyLayer {
        /// Index of the layer (0 = first hidden layer).
        layer: usize,
    },
    /// The network's last layer does not produce one value per action joint.
    OutputMismatch {
        /// Outputs of the last layer.
        outputs: usize,
        /// Joints in the action layout.
        actions: usize,
    },
    /// The number of stored values does not match what the layer chain needs.
    WeightCountMismatch {
        /// Values the layer chain and normalisation need.
        expected: usize,
        /// Values stored.
        stored: usize,
    },
    /// A name in a layout is empty or too long.
    BadName {
        /// Maximum accepted length in bytes.
        max_len: usize,
    },
    /// An observation field has size zero.
    EmptyObservationField {
        /// Index of the field.
        field: usize,
    },
    /// An action joint has a non-finite or inverted scale or limit.
    InvalidActionJoint {
        /// Index of the joint.
        joint: usize,
    },
    /// The observation clip or a normalisation scale is not finite and positive.
    InvalidNormalisation {
        /// Index into the observation vector (or `usize::MAX` for the clip value).
        index: usize,
    },
    /// The control period is zero.
    InvalidControlPeriod,
    /// A stored weight, bias or normalisation value is NaN or infinite.
    NonFiniteWeight {
        /// Index into the stored values.
        index: usize,
    },
    /// An int8 layer's per-output scale is zero or negative (version 2).
    InvalidScale {
        /// Index of the layer.
        layer: usize,
        /// Output channel of the scale.
        output: usize,
    },
    /// An int8 layer's packed weights have a non-zero byte where the padding to whole 4 x 4
    /// blocks must be zero (version 2).
    NonZeroWeightPadding {
        /// Index of the layer.
        layer: usize,
    },
    /// An int8 layer has more inputs than an exact int32 accumulation allows (version 2).
    QuantisedLayerTooWide {
        /// Index of the layer.
        layer: usize,
        /// Its input width, padded to a multiple of 4.
        inputs: usize,
        /// The limit ([`crate::int8::MAX_INPUTS`]).
        max: usize,
    },
    /// The policy needs more than the runtime's compile-time capacity.
    ExceedsCapacity {
        /// What is too large.
        what: CapacityItem,
        /// The policy's value.
        value: usize,
        /// The runtime's limit.
        max: usize,
    },
    /// The policy's observation layout differs from the controller's at field `field`.
    ObservationLayoutMismatch {
        /// First field that differs (or the shorter length when one layout ends early).
        field: usize,
    },
    /// The policy's action layout differs from the controller's at joint `joint`.
    ActionLayoutMismatch {
        /// First joint that differs (or the shorter length when one layout ends early).
        joint: usize,
    },
    /// The weights are not 4-byte aligned in memory, so they cannot be borrowed as `&[f32]`.
    MisalignedWeights,
    /// An output buffer given to the encoder or a copy is too small.
    BufferTooSmall {
        /// Bytes or values needed.
        needed: usize,
    },
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FormatError::Truncated { needed, got } => {
                write!(f, "policy file truncated: needs {needed} bytes, has {got}")
            }
            FormatError::TrailingBytes { expected, got } => write!(
                f,
                "policy file has trailing bytes: header announces {expected} bytes, file has {got}"
            ),
            FormatError::BadMagic { found } => write!(
                f,
                "not a policy file: magic is {found:02x?}, expected \"DXPL\""
            ),
            FormatError::UnsupportedVersion { found, supported } => write!(
                f,
                "unsupported policy format version {found}; this reader supports up to version {supported}"
            ),
            FormatError::UnknownFlags { flags } => {
                write!(f, "reserved header flags set: {flags:#06x}")
            }
            FormatError::CrcMismatch { stored, computed } => write!(
                f,
                "policy file corrupt: CRC-32 stored {stored:#010x}, computed {computed:#010x}"
            ),
            FormatError::MalformedBody => f.write_str("policy body is malformed"),
            FormatError::NonZeroPadding => f.write_str("padding before the weights is not zero"),
            FormatError::LayoutHashMismatch { stored, computed } => write!(
                f,
                "layout hash mismatch: header {stored:#010x}, body {computed:#010x}"
            ),
            FormatError::EmptyLayer { layer } => {
                write!(f, "layer chain inconsistent: layer {layer} is empty")
            }
            FormatError::OutputMismatch { outputs, actions } => write!(
                f,
                "layer chain inconsistent: last layer has {outputs} outputs but the action layout has {actions} joints"
            ),
            FormatError::WeightCountMismatch { expected, stored } => write!(
                f,
                "layer chain inconsistent: the network needs {expected} stored values, the file has {stored}"
            ),
            FormatError::BadName { max_len } => {
                write!(f, "a layout name is empty or longer than {max_len} bytes")
            }
            FormatError::EmptyObservationField { field } => {
                write!(f, "observation field {field} has size zero")
            }
            FormatError::InvalidActionJoint { joint } => write!(
                f,
                "action joint {joint} has a non-finite or inverted scale or limit"
            ),
            FormatError::InvalidNormalisation { index } => {
                if index == usize::MAX {
                    f.write_str("observation clip is not finite and positive")
                } else {
                    write!(f, "observation scale {index} is not finite and positive")
                }
            }
            FormatError::InvalidControlPeriod => f.write_str("control period is zero"),
            FormatError::NonFiniteWeight { index } => {
                write!(f, "stored value {index} is not finite")
            }
            FormatError::InvalidScale { layer, output } => write!(
                f,
                "int8 layer {layer}: scale of output {output} is not positive"
            ),
            FormatError::NonZeroWeightPadding { layer } => write!(
                f,
                "int8 layer {layer}: padding of the packed weights is not zero"
            ),
            FormatError::QuantisedLayerTooWide { layer, inputs, max } => write!(
                f,
                "int8 layer {layer} has {inputs} (padded) inputs; exact int32 accumulation allows {max}"
            ),
            FormatError::ExceedsCapacity { what, value, max } => write!(
                f,
                "policy exceeds the runtime's capacity: {what} {value} > {max}"
            ),
            FormatError::ObservationLayoutMismatch { field } => write!(
                f,
                "observation layout does not match the controller's (first difference at field {field})"
            ),
            FormatError::ActionLayoutMismatch { joint } => write!(
                f,
                "action layout does not match the controller's (first difference at joint {joint})"
            ),
            FormatError::MisalignedWeights => {
                f.write_str("weights are not 4-byte aligned; copy them into a buffer instead")
            }
            FormatError::BufferTooSmall { needed } => {
                write!(f, "output buffer too small: {needed} needed")
            }
        }
    }
}

impl core::error::Error for FormatError {}
