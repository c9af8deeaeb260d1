//! Writing policy files: into a caller-owned buffer (no allocator) or, with `std`, into a `Vec`.

use crate::body::Body;
use crate::error::FormatError;
use crate::header::{CRC_OFFSET, FORMAT_VERSION, HEADER_LEN, Header, file_crc, values_offset};
use crate::view::{body_layout_hash, validate};
use crate::weights::Values;

/// Encodes `body` and `values` (normalisation means, normalisation scales, then per layer the
/// input-major weights and the biases) into `out`; returns the number of bytes written.
///
/// The policy is validated exactly as the decoder would validate it, so an invalid policy is never
/// written.
pub fn encode_into(body: &Body<'_>, values: &[f32], out: &mut [u8]) -> Result<usize, FormatError> {
    let body_len = {
        let after_header = out
            .get_mut(HEADER_LEN..)
            .ok_or(FormatError::BufferTooSmall { needed: HEADER_LEN })?;
        postcard::to_slice(body, after_header)
            .map_err(|_| FormatError::BufferTooSmall {
                needed: out_len_hint(values.len()),
            })?
            .len()
    };
    let start = values_offset(body_len);
    let total = start + values.len() * 4;
    if out.len() < total {
        return Err(FormatError::BufferTooSmall { needed: total });
    }
    out[HEADER_LEN + body_len..start].fill(0);
    for (chunk, v) in out[start..total].chunks_exact_mut(4).zip(values) {
        chunk.copy_from_slice(&v.to_le_bytes());
    }
    validate(body, &Values::new(&out[start..total]))?;
    let mut header = Header {
        version: FORMAT_VERSION,
        flags: 0,
        layout_hash: body_layout_hash(body),
        body_len: u32::try_from(body_len).map_err(|_| FormatError::MalformedBody)?,
        value_count: u32::try_from(values.len()).map_err(|_| FormatError::MalformedBody)?,
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

fn out_len_hint(values: usize) -> usize {
    HEADER_LEN + 4096 + values * 4
}

/// Encodes a policy into a new vector (see [`encode_into`]).
#[cfg(feature = "std")]
pub fn encode_to_vec(body: &Body<'_>, values: &[f32]) -> Result<std::vec::Vec<u8>, FormatError> {
    let body_len = postcard::to_stdvec(body)
        .map_err(|_| FormatError::MalformedBody)?
        .len();
    let mut out = std::vec![0u8; values_offset(body_len) + values.len() * 4];
    let n = encode_into(body, values, &mut out)?;
    out.truncate(n);
    Ok(out)
}
