//! Borrowed access to the stored little-endian f32 values.

use crate::error::FormatError;

/// The stored values of a policy file: normalisation, then weights (f32, or packed int8 in
/// version 2), int8 scales and biases layer by layer, as 4-byte little-endian words.
/// Borrowed from the file bytes; nothing is copied until asked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Values<'a> {
    bytes: &'a [u8],
}

impl<'a> Values<'a> {
    /// Wraps raw little-endian bytes; `bytes.len()` must be a multiple of 4.
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Values { bytes }
    }

    /// Number of stored f32 values.
    pub fn len(&self) -> usize {
        self.bytes.len() / 4
    }

    /// Whether no values are stored.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// Value `index`, or `None` past the end.
    pub fn get(&self, index: usize) -> Option<f32> {
        let start = index.checked_mul(4)?;
        let b = self.bytes.get(start..start.checked_add(4)?)?;
        Some(f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// `len` bytes of packed int8 weights starting at word `word`; `None` past the end.
    pub fn int8(&self, word: usize, len: usize) -> Option<&'a [i8]> {
        let start = word.checked_mul(4)?;
        let bytes = self.bytes.get(start..start.checked_add(len)?)?;
        Some(bytemuck::cast_slice(bytes))
    }

    /// The raw little-endian bytes of all stored words.
    pub fn bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// All values in order (packed int8 words of version 2 files read as f32 bit patterns).
    pub fn iter(&self) -> impl Iterator<Item = f32> + 'a {
        self.bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// The values as an `&[f32]` without copying: possible on little-endian targets when the file
    /// buffer keeps the values 4-byte aligned (they sit at a 4-aligned offset from the file start).
    pub fn as_slice(&self) -> Result<&'a [f32], FormatError> {
        if cfg!(target_endian = "little") {
            bytemuck::try_cast_slice(self.bytes).map_err(|_| FormatError::MisalignedWeights)
        } else {
            Err(FormatError::MisalignedWeights)
        }
    }

    /// Copies the values into a caller-owned buffer and returns the filled part.
    pub fn copy_into<'b>(&self, buffer: &'b mut [f32]) -> Result<&'b [f32], FormatError> {
        let n = self.len();
        let out = buffer
            .get_mut(..n)
            .ok_or(FormatError::BufferTooSmall { needed: n })?;
        for (dst, v) in out.iter_mut().zip(self.iter()) {
            *dst = v;
        }
        Ok(out)
    }
}
