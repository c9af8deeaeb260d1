//! Writing policy files: into a caller-owned buffer (no allocator) or, with `std`, into a `Vec`.
//!
//! The encoder writes the oldest format version that can carry the policy: version 1 when every
//! layer is f32 (the same bytes a version 1 encoder wrote), version 2 when a layer is int8.

use crate::body::{Body, BodyV1};
use crate::error::FormatError;
use crate::header::{
    CRC_OFFSET, FORMAT_VERSION, HEADER_LEN, Header, MIN_FORMAT_VERSION, file_crc, values_offset,
};
use crate::view::{body_layout_hash, validate};
use crate::weights::Values;

/// Encodes `body` and `values` (normalisation means, normalisation scales, then per layer the
/// input-major weights and the biases) into `out`; returns the number of bytes written.
/// For all-f32 networks; [`encode_data_into`] takes a data section with int8 layers.
///
/// The policy is validated exactly as the decoder would validate it, so an invalid policy is never
/// written.
pub fn encode_into(body: &Body<'_>, values: &[f32], out: &mut [u8]) -> Result<usize, FormatError> {
    encode_with(body, values.len() * 4, out, |data| {
        for (chunk, v) in data.chunks_exact_mut(4).zip(values) {
            chunk.copy_from_slice(&v.to_le_bytes());
        }
    })
}

/// Encodes `body` and a raw data section `data` (the stored words as little-endian bytes, in the
/// order of docs/policy-format.md: normalisation, then per layer f32 weights and biases, or packed
/// int8 weights, scales and biases) into `out`; returns the number of bytes written.
pub fn encode_data_into(
    body: &Body<'_>,
    data: &[u8],
    out: &mut [u8],
) -> Result<usize, FormatError> {
    if !data.len().is_multiple_of(4) {
        return Err(FormatError::WeightCountMismatch {
            expected: body.stored_values().unwrap_or(usize::MAX),
            stored: data.len() / 4,
        });
    }
    encode_with(body, data.len(), out, |dst| dst.copy_from_slice(data))
}

/// Serialises the body in the wire form of `version`.
fn write_body(body: &Body<'_>, version: u16, out: &mut [u8]) -> Result<usize, FormatError> {
    let written = if version == MIN_FORMAT_VERSION {
        let v1 = BodyV1::from_body(body).ok_or(FormatError::MalformedBody)?;
        postcard::to_slice(&v1, out).map(|b| b.len())
    } else {
        postcard::to_slice(body, out).map(|b| b.len())
    };
    written.map_err(|_| FormatError::BufferTooSmall {
        needed: HEADER_LEN + 4096,
    })
}

/// Version the encoder writes for `body`.
fn version_for(body: &Body<'_>) -> u16 {
    if body.has_int8() {
        FORMAT_VERSION
    } else {
        MIN_FORMAT_VERSION
    }
}

fn encode_with(
    body: &Body<'_>,
    data_len: usize,
    out: &mut [u8],
    fill: impl FnOnce(&mut [u8]),
) -> Result<usize, FormatError> {
    let version = version_for(body);
    let body_len = {
        let after_header = out
            .get_mut(HEADER_LEN..)
            .ok_or(FormatError::BufferTooSmall { needed: HEADER_LEN })?;
        write_body(body, version, after_header).map_err(|_| FormatError::BufferTooSmall {
            needed: out_len_hint(data_len),
        })?
    };
    let start = values_offset(body_len);
    let total = start + data_len;
    if out.len() < total {
        return Err(FormatError::BufferTooSmall { needed: total });
    }
    out[HEADER_LEN + body_len..start].fill(0);
    fill(&mut out[start..total]);
    validate(body, &Values::new(&out[start..total]))?;
    let mut header = Header {
        version,
        flags: 0,
        layout_hash: body_layout_hash(body),
        body_len: u32::try_from(body_len).map_err(|_| FormatError::MalformedBody)?,
        value_count: u32::try_from(data_len / 4).map_err(|_| FormatError::MalformedBody)?,
        crc: 0,
    };
    let head: &mut [u8; HEADER_LEN] = (&mut out[..HEADER_LEN])
        .try_into()
        .map_err(|_| FormatError::BufferTooSmall { needed: total })?;
    header.write(head);
    header.crc = file_crc(&out[..total]);
    out[CRC_OFFSET..HEADER_LEN].copy_from_slice(&header.crc.to_le_bytes());
    Ok(total)
}

fn out_len_hint(data_len: usize) -> usize {
    HEADER_LEN + 4096 + data_len
}

/// Length of the body in its wire form (std only: sizes the output vector).
#[cfg(feature = "std")]
fn body_len(body: &Body<'_>) -> Result<usize, FormatError> {
    let bytes = if version_for(body) == MIN_FORMAT_VERSION {
        let v1 = BodyV1::from_body(body).ok_or(FormatError::MalformedBody)?;
        postcard::to_stdvec(&v1)
    } else {
        postcard::to_stdvec(body)
    };
    bytes
        .map(|b| b.len())
        .map_err(|_| FormatError::MalformedBody)
}

/// Encodes an all-f32 policy into a new vector (see [`encode_into`]).
#[cfg(feature = "std")]
pub fn encode_to_vec(body: &Body<'_>, values: &[f32]) -> Result<std::vec::Vec<u8>, FormatError> {
    let mut out = std::vec![0u8; values_offset(body_len(body)?) + values.len() * 4];
    let n = encode_into(body, values, &mut out)?;
    out.truncate(n);
    Ok(out)
}

/// Encodes a policy from a raw data section into a new vector (see [`encode_data_into`]).
#[cfg(feature = "std")]
pub fn encode_data_to_vec(body: &Body<'_>, data: &[u8]) -> Result<std::vec::Vec<u8>, FormatError> {
    let mut out = std::vec![0u8; values_offset(body_len(body)?) + data.len()];
    let n = encode_data_into(body, data, &mut out)?;
    out.truncate(n);
    Ok(out)
}
