//! The byte layout of an int8 layer's weights (format version 2), and, with `std`, the
//! post-training quantiser that writes it.
//!
//! An int8 layer with `inputs` inputs and `outputs` outputs stores `q[j][i]` (output `j`, input `i`)
//! with the weight `w[i][j] = q[j][i] * scale[j]` (one f32 scale per output channel). Both widths
//! are padded to multiples of [`BLOCK`] with zero weights, and the bytes are ordered for a kernel
//! that keeps four outputs in registers and walks the inputs four at a time:
//!
//! - blocks of four outputs `j = 4b..4b+4`, block after block;
//! - inside a block, groups of four inputs `i = 4g..4g+4`, group after group;
//! - inside a group, one 4-byte word per output (`j = 4b, 4b+1, 4b+2, 4b+3`), holding the four
//!   weights of inputs `(4g, 4g+2, 4g+1, 4g+3)` in byte order.
//!
//! That lane order lets the Arm `SXTB16` instruction sign-extend bytes 0 and 2 (inputs `4g`,
//! `4g+1`) and, rotated by 8, bytes 1 and 3 (inputs `4g+2`, `4g+3`) into 16-bit pairs that line up
//! with activations packed in natural order, two per word, for `SMLAD`. [`byte_index`] is the
//! whole mapping.

/// Outputs per block and inputs per group of the packed weights.
pub const BLOCK: usize = 4;

/// Most inputs (after padding to [`BLOCK`]) an int8 layer may have, so that an int32 sum of
/// int8 x int16 products cannot overflow: `512 * 128 * 32767 < 2^31`.
pub const MAX_INPUTS: usize = 512;

/// `n` rounded up to a multiple of [`BLOCK`].
pub const fn padded(n: usize) -> usize {
    n.div_ceil(BLOCK) * BLOCK
}

/// Bytes of packed weights of an int8 layer (a multiple of 16). `None` on overflow.
pub fn packed_bytes(inputs: usize, outputs: usize) -> Option<usize> {
    padded(inputs).checked_mul(padded(outputs))
}

/// 4-byte words of packed weights of an int8 layer. `None` on overflow.
pub fn packed_words(inputs: usize, outputs: usize) -> Option<usize> {
    Some(packed_bytes(inputs, outputs)? / 4)
}

/// Position, inside a layer's packed weights, of the weight linking input `i` to output `j`
/// (`inputs` is the layer's unpadded input width).
pub const fn byte_index(inputs: usize, i: usize, j: usize) -> usize {
    const LANE: [usize; BLOCK] = [0, 2, 1, 3];
    let groups = padded(inputs) / BLOCK;
    let (block, row) = (j / BLOCK, j % BLOCK);
    let (group, k) = (i / BLOCK, i % BLOCK);
    ((block * groups + group) * BLOCK + row) * BLOCK + LANE[k]
}

/// Whether packed byte `index` of a layer is padding (an input or output beyond the real widths);
/// padding must be zero.
pub const fn is_padding(inputs: usize, outputs: usize, index: usize) -> bool {
    const INPUT_OF_LANE: [usize; BLOCK] = [0, 2, 1, 3];
    let groups = padded(inputs) / BLOCK;
    let word = index / BLOCK;
    let row = word % BLOCK;
    let group = (word / BLOCK) % groups;
    let block = word / BLOCK / groups;
    let i = group * BLOCK + INPUT_OF_LANE[index % BLOCK];
    let j = block * BLOCK + row;
    i >= inputs || j >= outputs
}

#[cfg(feature = "std")]
pub use quantise::{
    QuantisedLayer, on_grid, pack, policy_on_grid, quantise_layer, quantise_policy,
};

#[cfg(feature = "std")]
mod quantise {
    use std::vec;
    use std::vec::Vec;

    use super::{byte_index, packed_bytes};
    use crate::body::{Body, LayerDtype};
    use crate::encode::encode_data_to_vec;
    use crate::error::FormatError;
    use crate::view::PolicyView;

    /// Largest int8 weight magnitude the quantiser writes (symmetric: -127..=127).
    const Q_MAX: f32 = 127.0;

    /// One layer after post-training quantisation.
    #[derive(Debug, Clone, PartialEq)]
    pub struct QuantisedLayer {
        /// Output-major int8 weights: `q[j * inputs + i]`.
        pub weights: Vec<i8>,
        /// One scale per output: `w[i][j] ~= q[j][i] * scales[j]`.
        pub scales: Vec<f32>,
    }

    /// Symmetric per-output-channel quantisation of input-major f32 weights
    /// (`w[i * outputs + j]`): `scale[j] = max_i |w[i][j]| / 127` (1 for an all-zero output),
    /// `q = round(w / scale[j])`, half away from zero.
    pub fn quantise_layer(inputs: usize, outputs: usize, w: &[f32]) -> QuantisedLayer {
        let mut weights = vec![0i8; inputs * outputs];
        let mut scales = vec![1.0f32; outputs];
        for j in 0..outputs {
            let max = (0..inputs)
                .filter_map(|i| w.get(i * outputs + j))
                .fold(0.0f32, |m, v| m.max(v.abs()));
            let s = if max > 0.0 { max / Q_MAX } else { 1.0 };
            scales[j] = s;
            for i in 0..inputs {
                let v = w.get(i * outputs + j).copied().unwrap_or(0.0);
                weights[j * inputs + i] = (v / s).round().clamp(-Q_MAX, Q_MAX) as i8;
            }
        }
        QuantisedLayer { weights, scales }
    }

    /// Whether input-major f32 weights already lie on the grid of [`quantise_layer`] (as those of a
    /// quantisation-aware trained layer do): quantising them again reproduces every weight to
    /// within `1e-6` of its output channel's largest magnitude (the f32 rounding of a recomputed
    /// scale), so the int8 layer computes the same function as the f32 one. An all-zero layer is
    /// on the grid; a non-finite weight is not.
    pub fn on_grid(inputs: usize, outputs: usize, w: &[f32]) -> bool {
        if w.len() != inputs * outputs || w.iter().any(|v| !v.is_finite()) {
            return false;
        }
        let q = quantise_layer(inputs, outputs, w);
        (0..outputs).all(|j| {
            let s = q.scales[j];
            let max = s * Q_MAX;
            (0..inputs).all(|i| {
                let back = f32::from(q.weights[j * inputs + i]) * s;
                (back - w[i * outputs + j]).abs() <= 1e-6 * max
            })
        })
    }

    /// Whether every f32 layer of a decoded policy lies on the int8 grid ([`on_grid`]; int8 layers
    /// count as on it): then [`quantise_policy`] loses nothing but the runtime's int16 activations.
    pub fn policy_on_grid(view: &PolicyView<'_>) -> Result<bool, FormatError> {
        let values = view.values();
        for l in view.layers().filter(|l| l.dtype == LayerDtype::F32) {
            let w = (l.weights..l.weights + l.inputs * l.outputs)
                .map(|k| values.get(k).ok_or(FormatError::MalformedBody))
                .collect::<Result<Vec<f32>, _>>()?;
            if !on_grid(l.inputs, l.outputs, &w) {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// Packs output-major int8 weights (`q[j * inputs + i]`) into the file's block order, with
    /// zero padding (see the module docs).
    pub fn pack(inputs: usize, outputs: usize, q: &[i8]) -> Vec<u8> {
        let mut out = vec![0u8; packed_bytes(inputs, outputs).unwrap_or(0)];
        for j in 0..outputs {
            for i in 0..inputs {
                if let (Some(dst), Some(&v)) =
                    (out.get_mut(byte_index(inputs, i, j)), q.get(j * inputs + i))
                {
                    *dst = v as u8;
                }
            }
        }
        out
    }

    /// Post-training quantisation of a decoded policy: every f32 layer for which `select(layer)`
    /// holds becomes an int8 layer (weights per output channel, biases stay f32); normalisation,
    /// layouts, activations and the other layers are copied. Returns the new file (version 2 when
    /// a layer was quantised). `provenance` replaces the source's provenance when given.
    pub fn quantise_policy(
        view: &PolicyView<'_>,
        select: impl Fn(usize) -> bool,
        provenance: Option<crate::body::Provenance<'_>>,
    ) -> Result<Vec<u8>, FormatError> {
        let values = view.values();
        let f32s = |start: usize, n: usize| -> Result<Vec<f32>, FormatError> {
            (start..start + n)
                .map(|k| values.get(k).ok_or(FormatError::MalformedBody))
                .collect()
        };
        let mut body: Body<'_> = view.body().clone();
        if let Some(p) = provenance {
            body.provenance = p;
        }
        let obs = body.obs_dim();
        let mut data: Vec<u8> = Vec::new();
        let push = |data: &mut Vec<u8>, v: &[f32]| {
            data.extend(v.iter().flat_map(|x| x.to_le_bytes()));
        };
        push(&mut data, &f32s(0, 2 * obs)?);
        for (index, l) in view.layers().enumerate() {
            let biases = f32s(l.biases, l.outputs)?;
            match l.dtype {
                LayerDtype::F32 if select(index) => {
                    let w = f32s(l.weights, l.inputs * l.outputs)?;
                    let q = quantise_layer(l.inputs, l.outputs, &w);
                    data.extend(pack(l.inputs, l.outputs, &q.weights));
                    push(&mut data, &q.scales);
                    push(&mut data, &biases);
                    if let Some(spec) = body.layers.get_mut(index) {
                        spec.dtype = LayerDtype::Int8;
                    }
                }
                LayerDtype::F32 => {
                    push(&mut data, &f32s(l.weights, l.inputs * l.outputs)?);
                    push(&mut data, &biases);
                }
                LayerDtype::Int8 => {
                    let packed = view.int8_weights(index).ok_or(FormatError::MalformedBody)?;
                    data.extend(packed.iter().map(|&b| b as u8));
                    push(&mut data, &f32s(l.scales.unwrap_or(0), l.outputs)?);
                    push(&mut data, &biases);
                }
            }
        }
        encode_data_to_vec(&body, &data)
    }
}
