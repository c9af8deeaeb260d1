//! The policy evaluator: observation normalisation, a dense MLP and action scaling, with capacity
//! fixed at compile time and the weights borrowed from the policy file (flash on a controller).
//!
//! The file decides, layer by layer, which kernel runs ([`dex_policy::LayerDtype`]):
//!
//! - f32 layers: every output is `bias + w[0]*x[0] + w[1]*x[1] + ...` in that order. Rust never
//!   fuses a multiply and an add unless `mul_add` is called, and `tanh` comes from the pure-Rust
//!   `libm`, so results are bit-identical on every target.
//! - int8 layers ("W8A16", packed as in [`dex_policy::int8`]): the layer's inputs are quantised per call to int16
//!   with one scale `s_x = max|x| / 32767`, each output is an exact int32 sum of int8 x int16
//!   products (exact, so its order is free), then `y[j] = acc as f32 * (scale[j] * s_x) + bias[j]`
//!   in that order of f32 operations. Bit-identical on every target as well.

use dex_policy::{
    Activation, Capacity, CapacityItem, FormatError, LayerDtype, MAX_ACTIONS, MAX_LAYERS,
    PolicyView, int8::padded,
};
use heapless::Vec;

use crate::error::EvalError;
use crate::int8::{dense_int8, quantise_inputs, quantise_inputs_with_max};

/// How a layer's weights are stored, with what the kind needs beyond weights and biases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    /// f32 weights, input-major.
    F32,
    /// Packed int8 weights with per-output scales starting at this value index.
    Int8 {
        /// Index of the first scale.
        scales: usize,
    },
}

/// One dense layer, as offsets into the stored values (4-byte words).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Layer {
    inputs: usize,
    outputs: usize,
    weights: usize,
    biases: usize,
    activation: Activation,
    kind: Kind,
}

/// int16 activations of an int8 layer, word-aligned so that pairs can be read as one `u32`.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(4))]
struct Int16Buffer<const WIDTH: usize>([i16; WIDTH]);

/// How one network output becomes a joint command: `clamp(y * scale, min, max)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct JointMap {
    scale: f32,
    min: f32,
    max: f32,
}

/// What a network needs of its file besides the values: small, unlike the scratch buffers.
#[derive(Debug, Clone)]
struct Layout<const WIDTH: usize> {
    layers: Vec<Layer, MAX_LAYERS>,
    joints: Vec<JointMap, MAX_ACTIONS>,
    obs_dim: usize,
    clip: f32,
}

/// A loaded policy with its scratch buffers; `WIDTH` is the widest layer (or input) it accepts
/// (for int8 layers the input width rounded up to a multiple of 4).
///
/// Holds two `[f32; WIDTH]` activations buffers and one `[i16; WIDTH]` buffer for the quantised
/// inputs of int8 layers, and borrows the weights: a 48-256-256-9 policy needs 2.5 kB of RAM here
/// while its weights (323 kB f32, 81 kB int8) stay in the file (flash). A [`Network`] with the
/// file's values borrowed for `'a`.
#[derive(Debug, Clone)]
pub struct Mlp<'a, const WIDTH: usize> {
    values: &'a [f32],
    net: Network<WIDTH>,
}

impl<'a, const WIDTH: usize> Mlp<'a, WIDTH> {
    /// This evaluator's capacity.
    pub const CAPACITY: Capacity = Network::<WIDTH>::CAPACITY;

    /// Builds an evaluator over a decoded policy, borrowing its values (which must be 4-byte aligned
    /// in memory; see [`dex_policy::Values::as_slice`]).
    pub fn new(view: &PolicyView<'a>) -> Result<Self, FormatError> {
        let values = view.values().as_slice()?;
        Ok(Mlp {
            values,
            net: Network::from_layout(Network::<WIDTH>::layout(view)?, values, 0),
        })
    }

    /// Observation dimension the policy expects.
    pub fn obs_dim(&self) -> usize {
        self.net.obs_dim
    }

    /// Number of joint commands the policy produces.
    pub fn act_dim(&self) -> usize {
        self.net.joints.len()
    }

    /// Number of layers evaluated with int8 weights.
    pub fn int8_layers(&self) -> usize {
        self.net.int8_layers()
    }

    /// Evaluates the policy: normalises and clips `obs`, runs the network and writes one clamped
    /// joint command per joint into `action`. Work is bounded by the policy's size, which is bounded
    /// by `WIDTH` and [`MAX_LAYERS`].
    pub fn act(&mut self, obs: &[f32], action: &mut [f32]) -> Result<(), EvalError> {
        self.net.run(self.values, obs, action)
    }
}

/// A policy's network without its values: layer layout as offsets, joint maps and scratch
/// buffers, and where the values lie in the file. It borrows nothing, so it can be kept while
/// the file's storage is not (a flash slot, [`crate::slots::PolicySlots`]): every evaluation takes
/// the file's bytes ([`Network::act`]). Same arithmetic, and so the same bits, as [`Mlp`].
#[derive(Debug, Clone)]
pub struct Network<const WIDTH: usize> {
    /// Byte offset of the first value in the file.
    values_at: usize,
    /// Number of 4-byte values.
    values_len: usize,
    xq: Int16Buffer<WIDTH>,
    layers: Vec<Layer, MAX_LAYERS>,
    joints: Vec<JointMap, MAX_ACTIONS>,
    obs_dim: usize,
    clip: f32,
    front: [f32; WIDTH],
    back: [f32; WIDTH],
}

impl<const WIDTH: usize> Network<WIDTH> {
    /// This evaluator's capacity.
    pub const CAPACITY: Capacity = Capacity {
        max_obs: WIDTH,
        max_act: if WIDTH < MAX_ACTIONS {
            WIDTH
        } else {
            MAX_ACTIONS
        },
        max_width: WIDTH,
        max_layers: MAX_LAYERS,
    };

    /// Builds the network of `view`, which was decoded from `file` (`PolicyView::decode(file)`);
    /// later evaluations take the same file's bytes. Fails like [`Mlp::new`], and with
    /// [`FormatError::MalformedBody`] when the view's values do not lie inside `file`.
    pub fn new(view: &PolicyView<'_>, file: &[u8]) -> Result<Self, FormatError> {
        let values = view.values().as_slice()?;
        let start = (values.as_ptr() as usize).wrapping_sub(file.as_ptr() as usize);
        let inside = (values.as_ptr() as usize) >= (file.as_ptr() as usize)
            && start
                .checked_add(core::mem::size_of_val(values))
                .is_some_and(|end| end <= file.len());
        if !inside {
            return Err(FormatError::MalformedBody);
        }
        Ok(Self::from_layout(Self::layout(view)?, values, start))
    }

    /// The network around `layout`, whose values (`values`) start `values_at` bytes into its file.
    /// Built in the caller's return slot (`#[inline(always)]`): the scratch buffers are large, and
    /// an intermediate copy would cost their size again in stack.
    #[inline(always)]
    fn from_layout(layout: Layout<WIDTH>, values: &[f32], values_at: usize) -> Self {
        Network {
            values_at,
            values_len: values.len(),
            xq: Int16Buffer([0; WIDTH]),
            layers: layout.layers,
            joints: layout.joints,
            obs_dim: layout.obs_dim,
            clip: layout.clip,
            front: [0.0; WIDTH],
            back: [0.0; WIDTH],
        }
    }

    /// The layer layout and joint maps of `view`, checked against this capacity.
    fn layout(view: &PolicyView<'_>) -> Result<Layout<WIDTH>, FormatError> {
        view.check_capacity(&Self::CAPACITY)?;
        let body = view.body();
        let mut layers = Vec::new();
        for (l, spec) in view.layers().zip(body.layers.iter()) {
            let kind = match (l.dtype, l.scales) {
                (LayerDtype::Int8, Some(scales)) => {
                    if padded(l.inputs) > WIDTH {
                        return Err(FormatError::ExceedsCapacity {
                            what: CapacityItem::Width,
                            value: padded(l.inputs),
                            max: WIDTH,
                        });
                    }
                    Kind::Int8 { scales }
                }
                (LayerDtype::Int8, None) => return Err(FormatError::MalformedBody),
                (LayerDtype::F32, _) => Kind::F32,
            };
            layers
                .push(Layer {
                    inputs: l.inputs,
                    outputs: l.outputs,
                    weights: l.weights,
                    biases: l.biases,
                    activation: spec.activation,
                    kind,
                })
                .map_err(|_| FormatError::ExceedsCapacity {
                    what: CapacityItem::Layers,
                    value: body.layers.len(),
                    max: MAX_LAYERS,
                })?;
        }
        let mut joints = Vec::new();
        for j in &body.action {
            joints
                .push(JointMap {
                    scale: j.scale,
                    min: j.min,
                    max: j.max,
                })
                .map_err(|_| FormatError::ExceedsCapacity {
                    what: CapacityItem::Action,
                    value: body.action.len(),
                    max: MAX_ACTIONS,
                })?;
        }
        Ok(Layout {
            layers,
            joints,
            obs_dim: body.obs_dim(),
            clip: body.obs_clip,
        })
    }

    /// Observation dimension the policy expects.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }

    /// Number of joint commands the policy produces.
    pub fn act_dim(&self) -> usize {
        self.joints.len()
    }

    /// Number of layers evaluated with int8 weights.
    pub fn int8_layers(&self) -> usize {
        self.layers
            .iter()
            .filter(|l| matches!(l.kind, Kind::Int8 { .. }))
            .count()
    }

    /// Evaluates the policy over `file`, the bytes it was built from ([`Network::new`]), as
    /// [`Mlp::act`] does. [`EvalError::PolicyBytes`] when `file` is too short for the values or
    /// they are not 4-byte aligned in it.
    pub fn act(&mut self, file: &[u8], obs: &[f32], action: &mut [f32]) -> Result<(), EvalError> {
        let bytes = self
            .values_len
            .checked_mul(4)
            .and_then(|n| file.get(self.values_at..self.values_at.checked_add(n)?))
            .ok_or(EvalError::PolicyBytes)?;
        let values: &[f32] = bytemuck::try_cast_slice(bytes).map_err(|_| EvalError::PolicyBytes)?;
        self.run(values, obs, action)
    }

    /// The evaluation over `values` (the file's, `values_len` of them: [`Network::act`] and
    /// [`Mlp`] check that); every offset was checked against them when the network was built.
    fn run(&mut self, values: &[f32], obs: &[f32], action: &mut [f32]) -> Result<(), EvalError> {
        if values.len() != self.values_len {
            return Err(EvalError::PolicyBytes);
        }
        let words: &[u32] = bytemuck::cast_slice(values);
        if obs.len() != self.obs_dim {
            return Err(EvalError::ObservationLength {
                expected: self.obs_dim,
                got: obs.len(),
            });
        }
        if action.len() != self.joints.len() {
            return Err(EvalError::ActionLength {
                expected: self.joints.len(),
                got: action.len(),
            });
        }
        let n = self.obs_dim;
        let (mean, rest) = values.split_at(n);
        let scale = &rest[..n];
        for (i, x) in obs.iter().enumerate() {
            if !x.is_finite() {
                return Err(EvalError::NonFiniteObservation { index: i });
            }
            let z = (x - mean[i]) / scale[i];
            self.front[i] = z.clamp(-self.clip, self.clip);
        }
        // `max |x|` of the next layer's inputs with their count, when the int8 kernel that wrote
        // them computed it (then the next int8 layer skips its scan): `(max, count, non-negative)`.
        let mut known_max: Option<(f32, usize, bool)> = None;
        // Ping-pong between the two buffers: even layers read `front`, odd layers read `back`.
        for (l, layer) in self.layers.iter().enumerate() {
            let b = &values[layer.biases..layer.biases + layer.outputs];
            let (src, dst) = if l % 2 == 0 {
                (&self.front, &mut self.back)
            } else {
                (&self.back, &mut self.front)
            };
            let dst = &mut dst[..layer.outputs];
            match layer.kind {
                Kind::F32 => {
                    let w = &values[layer.weights..layer.biases];
                    dense(&src[..layer.inputs], w, b, dst);
                    activate(layer.activation, dst);
                    known_max = None;
                }
                Kind::Int8 { scales } => {
                    let in_pad = padded(layer.inputs);
                    // Never fails: the buffer is 4-aligned and `in_pad` is a multiple of 4.
                    let xw: &mut [u32] =
                        bytemuck::try_cast_slice_mut(&mut self.xq.0[..in_pad]).unwrap_or(&mut []);
                    let x = &src[..layer.inputs];
                    let sx = match known_max {
                        Some((max, n, nonneg)) if n == x.len() => {
                            quantise_inputs_with_max(x, max, nonneg, xw)
                        }
                        _ => quantise_inputs(x, xw),
                    };
                    let xw = &*xw;
                    let w = &words[layer.weights..scales];
                    let s = &values[scales..layer.biases];
                    // ReLU (and the max of the outputs) fused into the kernel's rescale.
                    let relu = layer.activation == Activation::Relu;
                    let max = dense_int8(xw, w, s, b, sx, relu, dst);
                    known_max = match layer.activation {
                        Activation::Relu => Some((max, dst.len(), true)),
                        Activation::Linear => Some((max, dst.len(), false)),
                        Activation::Tanh => {
                            activate(layer.activation, dst);
                            None
                        }
                    };
                }
            }
        }
        let result = if self.layers.len() % 2 == 1 {
            &self.back
        } else {
            &self.front
        };
        for (j, (out, map)) in action.iter_mut().zip(&self.joints).enumerate() {
            let y = result[j];
            if !y.is_finite() {
                return Err(EvalError::NonFiniteAction { index: j });
            }
            *out = (y * map.scale).clamp(map.min, map.max);
        }
        Ok(())
    }
}

/// Outputs computed together in registers by [`dense`].
const BLOCK: usize = 16;

/// `out = bias + sum_i w[i] * input[i]` with weights input-major (`w[i * outputs + j]`).
///
/// Hand-written kernel (measured: the plain axpy loop stores and reloads every output once per
/// input; keeping a block of 16 outputs in registers across all inputs is ~2x faster on the host).
/// Each output still sums `bias + w0*x0 + w1*x1 + ...` in input order, so results are bit-identical
/// to the scalar loop on every target. Kept out of line so the arguments are known not to alias.
#[inline(never)]
fn dense(input: &[f32], w: &[f32], bias: &[f32], out: &mut [f32]) {
    let outputs = out.len();
    let mut j0 = 0;
    while j0 + BLOCK <= outputs {
        let mut acc = [0.0f32; BLOCK];
        acc.copy_from_slice(&bias[j0..j0 + BLOCK]);
        for (x, row) in input.iter().zip(w.chunks_exact(outputs)) {
            let row = &row[j0..j0 + BLOCK];
            for (a, wv) in acc.iter_mut().zip(row) {
                *a += wv * x;
            }
        }
        out[j0..j0 + BLOCK].copy_from_slice(&acc);
        j0 += BLOCK;
    }
    if j0 < outputs {
        let tail = &mut out[j0..];
        tail.copy_from_slice(&bias[j0..]);
        for (x, row) in input.iter().zip(w.chunks_exact(outputs)) {
            for (o, wv) in tail.iter_mut().zip(&row[j0..]) {
                *o += wv * x;
            }
        }
    }
}

fn activate(activation: Activation, v: &mut [f32]) {
    match activation {
        Activation::Relu => v
            .iter_mut()
            .for_each(|x| *x = if *x > 0.0 { *x } else { 0.0 }),
        Activation::Tanh => v.iter_mut().for_each(|x| *x = libm::tanhf(*x)),
        Activation::Linear => {}
    }
}
