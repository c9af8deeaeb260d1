//! Experimental int8 evaluation (feature `int8`): post-training quantisation of an f32 policy with
//! int8 weights and per-output-channel scales, dynamically quantised int16 activations and int32
//! accumulation ("W8A16": `SMLAD` multiplies 16-bit halves, so int16 activations cost nothing over
//! int8 ones and remove most of the activation rounding error).
//!
//! A prototype for the int8 work that needs no policy-format change: [`quantize`] turns a
//! decoded f32 policy into int8 weights in caller-owned buffers (at boot here; in the exporter once
//! the format carries them) and [`QuantMlp`] evaluates them. Per layer:
//!
//! - weights, stored output-major (`q[j * inputs + i]`): `s_w[j] = max_i |w[i][j]| / 127`,
//!   `q = round(w / s_w[j])`;
//! - inputs: `s_x = max_i |x[i]| / 32767`, `x_q = round(x * (1 / s_x))` as int16 (per call, no
//!   calibration set);
//! - `y[j] = (sum_i q[j][i] * x_q[i]) as f32 * (s_w[j] * s_x) + b[j]`, then the activation.
//!
//! The integer sum is exact (at most 516 inputs: 516 * 127 * 32767 < 2^31), so its order is free and the results
//! stay bit-identical across targets like the f32 path. Normalisation, biases, activations and the
//! action mapping are the f32 evaluator's.

use dex_policy::{Activation, PolicyView};
use dex_runtime::interface::ACT_DIM;

/// Largest quantised weight magnitude (int8).
const Q_MAX: f32 = 127.0;

/// Largest quantised activation magnitude: activations are int16, which `SMLAD` multiplies at
/// no extra cost over int8 (weights are sign-extended to 16 bits anyway).
const X_MAX: f32 = 32767.0;

/// Most inputs per layer for which the int32 sum cannot overflow: 516 * 127 * 32767 < 2^31.
const MAX_INPUTS: usize = 516;

/// Why quantisation or evaluation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QuantError {
    /// The caller's weight or scale buffer is too small for the policy.
    Buffer {
        /// Values needed.
        needed: usize,
        /// Values available.
        available: usize,
    },
    /// A layer is wider than the evaluator's `WIDTH`, or the policy's values are not borrowable.
    Shape,
    /// Wrong observation or action length, or a non-finite observation or output.
    Input,
}

/// Int8 weights and their per-output scales, in the order of the policy's layers.
#[derive(Debug, Clone, Copy)]
pub struct QuantWeights<'q> {
    /// Output-major int8 weights, layer after layer.
    pub weights: &'q [i8],
    /// One scale per output, layer after layer.
    pub scales: &'q [f32],
}

/// Quantises every layer of `view` into `weights` and `scales`; returns the filled parts.
pub fn quantize<'q>(
    view: &PolicyView<'_>,
    weights: &'q mut [i8],
    scales: &'q mut [f32],
) -> Result<QuantWeights<'q>, QuantError> {
    let values = view.values().as_slice().map_err(|_| QuantError::Shape)?;
    let need_w: usize = view.layers().map(|l| l.inputs * l.outputs).sum();
    let need_s: usize = view.layers().map(|l| l.outputs).sum();
    if weights.len() < need_w || scales.len() < need_s {
        return Err(QuantError::Buffer {
            needed: need_w.max(need_s),
            available: weights.len().min(scales.len()),
        });
    }
    let (mut wq, mut sq) = (0, 0);
    for l in view.layers() {
        let w = values
            .get(l.weights..l.weights + l.inputs * l.outputs)
            .ok_or(QuantError::Shape)?;
        for j in 0..l.outputs {
            let max = (0..l.inputs).fold(0.0f32, |m, i| m.max(w[i * l.outputs + j].abs()));
            let s = if max > 0.0 { max / Q_MAX } else { 1.0 };
            scales[sq + j] = s;
            for i in 0..l.inputs {
                weights[wq + j * l.inputs + i] = round_i8(w[i * l.outputs + j] / s);
            }
        }
        wq += l.inputs * l.outputs;
        sq += l.outputs;
    }
    Ok(QuantWeights {
        weights: &weights[..need_w],
        scales: &scales[..need_s],
    })
}

/// `round(v)` saturated to `[-127, 127]`.
fn round_i8(v: f32) -> i8 {
    libm::roundf(v).clamp(-Q_MAX, Q_MAX) as i8
}

/// `v` rounded half away from zero and saturated to `[-32767, 32767]`, without a libm call: for
/// the per-call activation quantisation (the same f32 operations on every target, so still
/// bit-identical; it may differ from `roundf` by one step just below a half).
#[inline(always)]
fn fast_round_i16(v: f32) -> i16 {
    let half = if v < 0.0 { -0.5 } else { 0.5 };
    ((v + half) as i32).clamp(-32767, 32767) as i16
}

/// An int8 evaluator over a policy view and its quantised weights.
#[derive(Debug)]
pub struct QuantMlp<'v, 'a, 'q, const WIDTH: usize> {
    view: &'v PolicyView<'a>,
    values: &'a [f32],
    q: QuantWeights<'q>,
    front: [f32; WIDTH],
    back: [f32; WIDTH],
    /// Quantised int16 inputs, packed for [`dot2`]: per 4 inputs `(x0, x2)` then `(x1, x3)`.
    xp: [u32; WIDTH],
}

impl<'v, 'a, 'q, const WIDTH: usize> QuantMlp<'v, 'a, 'q, WIDTH> {
    /// An evaluator for `view` with weights from [`quantize`].
    pub fn new(view: &'v PolicyView<'a>, q: QuantWeights<'q>) -> Result<Self, QuantError> {
        let values = view.values().as_slice().map_err(|_| QuantError::Shape)?;
        if view.body().max_width() > WIDTH || view.body().obs_dim() > WIDTH {
            return Err(QuantError::Shape);
        }
        Ok(QuantMlp {
            view,
            values,
            q,
            front: [0.0; WIDTH],
            back: [0.0; WIDTH],
            xp: [0; WIDTH],
        })
    }

    /// Evaluates the policy like [`dex_runtime::Mlp::act`], with int8 weights and activations.
    pub fn act(&mut self, obs: &[f32], action: &mut [f32; ACT_DIM]) -> Result<(), QuantError> {
        let body = self.view.body();
        let n = body.obs_dim();
        if obs.len() != n || body.act_dim() != ACT_DIM {
            return Err(QuantError::Input);
        }
        let (mean, rest) = self.values.split_at(n);
        let clip = body.obs_clip;
        for (i, x) in obs.iter().enumerate() {
            if !x.is_finite() {
                return Err(QuantError::Input);
            }
            self.front[i] = ((x - mean[i]) / rest[i]).clamp(-clip, clip);
        }
        let (mut wq, mut sq) = (0, 0);
        for (l, spec) in self.view.layers().zip(body.layers.iter()) {
            let x = &self.front[..l.inputs];
            let max = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let sx = if max > 0.0 { max / X_MAX } else { 1.0 };
            let groups = l.inputs / 4;
            if l.inputs % 4 != 0 || 2 * groups > WIDTH || l.inputs > MAX_INPUTS {
                return Err(QuantError::Shape);
            }
            let inv = 1.0 / sx;
            for (pair, v) in self.xp.chunks_exact_mut(2).zip(x.chunks_exact(4)) {
                let q = |k: usize| fast_round_i16(v[k] * inv) as u16 as u32;
                pair[0] = q(0) | (q(2) << 16);
                pair[1] = q(1) | (q(3) << 16);
            }
            let w = self
                .q
                .weights
                .get(wq..wq + l.inputs * l.outputs)
                .ok_or(QuantError::Shape)?;
            let s = self
                .q
                .scales
                .get(sq..sq + l.outputs)
                .ok_or(QuantError::Shape)?;
            let b = self
                .values
                .get(l.biases..l.biases + l.outputs)
                .ok_or(QuantError::Shape)?;
            let xp = &self.xp[..2 * groups];
            let mut pairs = w.chunks_exact(2 * l.inputs);
            let mut j = 0;
            for pair in &mut pairs {
                let (r0, r1) = pair.split_at(l.inputs);
                let (a0, a1) = dot2(r0, r1, xp);
                self.back[j] = a0 as f32 * (s[j] * sx) + b[j];
                self.back[j + 1] = a1 as f32 * (s[j + 1] * sx) + b[j + 1];
                j += 2;
            }
            let last = pairs.remainder();
            if !last.is_empty() {
                let (a0, _) = dot2(last, last, xp);
                self.back[j] = a0 as f32 * (s[j] * sx) + b[j];
            }
            let y = &mut self.back[..l.outputs];
            match spec.activation {
                Activation::Relu => y
                    .iter_mut()
                    .for_each(|v| *v = if *v > 0.0 { *v } else { 0.0 }),
                Activation::Tanh => y.iter_mut().for_each(|v| *v = libm::tanhf(*v)),
                Activation::Linear => {}
            }
            core::mem::swap(&mut self.front, &mut self.back);
            wq += l.inputs * l.outputs;
            sq += l.outputs;
        }
        for (j, (out, map)) in action.iter_mut().zip(&body.action).enumerate() {
            let y = self.front[j];
            if !y.is_finite() {
                return Err(QuantError::Input);
            }
            *out = (y * map.scale).clamp(map.min, map.max);
        }
        Ok(())
    }
}

/// Exact int32 dot products of two int8 weight rows with the packed inputs `xp` (two words per
/// four inputs; the rows' length is a multiple of 4). Per four weights: one word load, two
/// `SXTB16` and two `SMLAD` (two 16-bit multiply-adds each) per row.
#[inline]
fn dot2(r0: &[i8], r1: &[i8], xp: &[u32]) -> (i32, i32) {
    let word = |r: &[i8], k: usize| {
        u32::from_le_bytes([r[k] as u8, r[k + 1] as u8, r[k + 2] as u8, r[k + 3] as u8])
    };
    let step = |w0: u32, w1: u32, x: &[u32], a: &mut (i32, i32)| {
        a.0 = smlad(sxtb16(w0), x[0], a.0);
        a.0 = smlad(sxtb16_ror8(w0), x[1], a.0);
        a.1 = smlad(sxtb16(w1), x[0], a.1);
        a.1 = smlad(sxtb16_ror8(w1), x[1], a.1);
    };
    let mut a = (0i32, 0i32);
    // Eight inputs per iteration (less loop overhead), then at most one group of four.
    let (c0, c1, cx) = (r0.chunks_exact(8), r1.chunks_exact(8), xp.chunks_exact(4));
    let (t0, t1, tx) = (c0.remainder(), c1.remainder(), cx.remainder());
    for ((w0, w1), x) in c0.zip(c1).zip(cx) {
        step(word(w0, 0), word(w1, 0), &x[..2], &mut a);
        step(word(w0, 4), word(w1, 4), &x[2..], &mut a);
    }
    if t0.len() == 4 && t1.len() == 4 && tx.len() == 2 {
        step(word(t0, 0), word(t1, 0), tx, &mut a);
    }
    a
}

/// Bytes 0 and 2 of `x`, sign-extended to two i16 halves (Arm `SXTB16`).
#[inline(always)]
fn sxtb16(x: u32) -> u32 {
    #[cfg(target_arch = "arm")]
    {
        let r: u32;
        // SAFETY: a pure register-to-register DSP instruction of Armv7E-M.
        unsafe {
            core::arch::asm!("sxtb16 {0}, {1}", out(reg) r, in(reg) x,
                options(pure, nomem, nostack, preserves_flags));
        }
        r
    }
    #[cfg(not(target_arch = "arm"))]
    {
        let half = |b: u32| (b as u8 as i8 as i16 as u16) as u32;
        half(x) | (half(x >> 16) << 16)
    }
}

/// Bytes 1 and 3 of `x`, sign-extended to two i16 halves (Arm `SXTB16` with `ROR #8`).
#[inline(always)]
fn sxtb16_ror8(x: u32) -> u32 {
    #[cfg(target_arch = "arm")]
    {
        let r: u32;
        // SAFETY: a pure register-to-register DSP instruction of Armv7E-M.
        unsafe {
            core::arch::asm!("sxtb16 {0}, {1}, ror #8", out(reg) r, in(reg) x,
                options(pure, nomem, nostack, preserves_flags));
        }
        r
    }
    #[cfg(not(target_arch = "arm"))]
    {
        sxtb16(x.rotate_right(8))
    }
}

/// `acc + lo(a) * lo(b) + hi(a) * hi(b)` over signed 16-bit halves (Arm `SMLAD`; exact here:
/// the sums stay far below 2^31).
#[inline(always)]
fn smlad(a: u32, b: u32, acc: i32) -> i32 {
    #[cfg(target_arch = "arm")]
    {
        let r: i32;
        // SAFETY: a pure register-to-register DSP instruction of Armv7E-M (it may set the Q flag,
        // which nothing reads).
        unsafe {
            core::arch::asm!("smlad {0}, {1}, {2}, {3}", out(reg) r, in(reg) a, in(reg) b,
                in(reg) acc, options(pure, nomem, nostack));
        }
        r
    }
    #[cfg(not(target_arch = "arm"))]
    {
        let lo = |v: u32| i32::from(v as u16 as i16);
        let hi = |v: u32| i32::from((v >> 16) as u16 as i16);
        acc.wrapping_add(lo(a) * lo(b)).wrapping_add(hi(a) * hi(b))
    }
}
