//! The int8 kernel ("W8A16"): int8 weights with one f32 scale per output channel, inputs quantised
//! per call to int16, exact int32 accumulation, f32 rescale.
//!
//! The weights come packed from the file ([`dex_policy::int8`]): blocks of four outputs, groups of
//! four inputs, one word per output holding the weights of inputs `(0, 2, 1, 3)` of the group.
//! The inputs are packed two int16 to a word in natural order. Then per group and output:
//! `SXTB16(w)` gives the weights of inputs 0 and 1 as two int16, `SXTB16(w ROR 8)` those of inputs
//! 2 and 3, and two `SMLAD` (two 16 x 16-bit multiply-adds into an int32 each) add all four
//! products. Four outputs share every loaded input word.
//!
//! Exactness: `|q| <= 128`, `|x_q| <= 32767` and at most [`dex_policy::int8::MAX_INPUTS`] inputs,
//! so no int32 sum overflows; the result does not depend on the order of additions and the
//! portable Rust path gives the same integers as the Arm DSP instructions.

/// Largest quantised activation magnitude (int16, symmetric).
const X_MAX: f32 = 32767.0;

/// Quantises `x` to int16 into `xq[..x.len()]` with one symmetric scale and zeroes the rest of
/// `xq` (the padding inputs); returns the scale `s_x = max|x| / 32767` (1 when all are zero).
///
/// `x_q = round(x * (1 / s_x))`, half away from zero, saturated to +-32767: the same f32 operations
/// on every target, so the same integers.
pub(crate) fn quantise_inputs(x: &[f32], xq: &mut [i16]) -> f32 {
    let max = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let sx = if max > 0.0 { max / X_MAX } else { 1.0 };
    let inv = 1.0 / sx;
    for (q, v) in xq.iter_mut().zip(x) {
        *q = round_i16(v * inv);
    }
    for q in xq.iter_mut().skip(x.len()) {
        *q = 0;
    }
    sx
}

/// `v` rounded half away from zero and saturated to `[-32767, 32767]` (no libm call; `as i32`
/// saturates and maps NaN to 0 on every target).
#[inline(always)]
fn round_i16(v: f32) -> i16 {
    let half = if v < 0.0 { -0.5 } else { 0.5 };
    ((v + half) as i32).clamp(-32767, 32767) as i16
}

/// `out[j] = acc[j] as f32 * (scales[j] * sx) + bias[j]` with `acc[j]` the exact dot product of
/// output `j`'s int8 weights (packed words `w`) and the packed int16 inputs `xw` (two per word,
/// `xw.len()` = padded inputs / 2).
///
/// Hand-written kernel, justified by a benchmark: under QEMU `-icount` on the 44-256-256-9 policy
/// the firmware's int8 evaluation took 199,471 instructions per step with the earlier two-output
/// kernel over unpermuted weights, against the numbers in docs/firmware.md for this one (four
/// outputs per loaded input pair, weights pre-permuted in the file); the `SXTB16`/`SMLAD` inline
/// assembly (feature `dsp`) against the portable path is measured there too.
#[inline(never)]
pub(crate) fn dense_int8(
    xw: &[u32],
    w: &[u32],
    scales: &[f32],
    bias: &[f32],
    sx: f32,
    out: &mut [f32],
) {
    let groups = xw.len() / 2;
    if groups == 0 {
        return;
    }
    for (b, block) in w.chunks_exact(4 * groups).enumerate() {
        let mut acc = [0i32; 4];
        for (wg, xg) in block.chunks_exact(4).zip(xw.chunks_exact(2)) {
            group(&mut acc, wg, xg[0], xg[1]);
        }
        for (r, &a) in acc.iter().enumerate() {
            let j = 4 * b + r;
            if let (Some(o), Some(s), Some(bj)) = (out.get_mut(j), scales.get(j), bias.get(j)) {
                *o = a as f32 * (s * sx) + bj;
            }
        }
    }
}

/// Adds one group of four inputs (`x01`, `x23`: two int16 each) times the four outputs' weight
/// words `w` to the accumulators.
#[inline(always)]
fn group(acc: &mut [i32; 4], w: &[u32], x01: u32, x23: u32) {
    for (a, &wv) in acc.iter_mut().zip(w) {
        *a = smlad(sxtb16(wv), x01, *a);
        *a = smlad(sxtb16_ror8(wv), x23, *a);
    }
}

/// Bytes 0 and 2 of `x`, sign-extended to two i16 halves (Arm `SXTB16`).
#[inline(always)]
fn sxtb16(x: u32) -> u32 {
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let r: u32;
        // SAFETY: a pure register-to-register DSP instruction of Armv7E-M (feature `dsp` promises
        // the target has it).
        unsafe {
            core::arch::asm!("sxtb16 {0}, {1}", out(reg) r, in(reg) x,
                options(pure, nomem, nostack, preserves_flags));
        }
        r
    }
    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
    {
        let half = |b: u32| u32::from(b as u8 as i8 as i16 as u16);
        half(x) | (half(x >> 16) << 16)
    }
}

/// Bytes 1 and 3 of `x`, sign-extended to two i16 halves (Arm `SXTB16` with `ROR #8`).
#[inline(always)]
fn sxtb16_ror8(x: u32) -> u32 {
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let r: u32;
        // SAFETY: as in `sxtb16`.
        unsafe {
            core::arch::asm!("sxtb16 {0}, {1}, ror #8", out(reg) r, in(reg) x,
                options(pure, nomem, nostack, preserves_flags));
        }
        r
    }
    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
    {
        sxtb16(x.rotate_right(8))
    }
}

/// `acc + lo(a) * lo(b) + hi(a) * hi(b)` over signed 16-bit halves (Arm `SMLAD`; exact here).
#[inline(always)]
fn smlad(a: u32, b: u32, acc: i32) -> i32 {
    #[cfg(all(feature = "dsp", target_arch = "arm"))]
    {
        let mut r = acc;
        // SAFETY: as in `sxtb16` (it may set the Q flag, which nothing reads). The accumulator is
        // read and written in the same register (fewer registers live in the kernel's loop).
        unsafe {
            core::arch::asm!("smlad {0}, {1}, {2}, {0}", inout(reg) r, in(reg) a, in(reg) b,
                options(pure, nomem, nostack));
        }
        r
    }
    #[cfg(not(all(feature = "dsp", target_arch = "arm")))]
    {
        let lo = |v: u32| i32::from(v as u16 as i16);
        let hi = |v: u32| i32::from((v >> 16) as u16 as i16);
        acc.wrapping_add(lo(a) * lo(b)).wrapping_add(hi(a) * hi(b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dsp_helpers_match_their_definitions() {
        // Bytes 01, ff, 7f, 80 (little-endian): 1, -1, 127, -128.
        assert_eq!(sxtb16(0x80_7f_ff_01), 0x007f_0001);
        assert_eq!(sxtb16_ror8(0x80_7f_ff_01), 0xff80_ffff);
        assert_eq!(smlad(0x0002_fffd, 0x0004_0005, 10), 10 + (-3 * 5) + 2 * 4);
    }

    #[test]
    fn inputs_round_half_away_and_saturate() {
        let mut q = [7i16; 8];
        let sx = quantise_inputs(&[2.0, -0.5, 0.0, -2.0, 1e-9], &mut q);
        assert_eq!(sx, 2.0 / 32767.0);
        assert_eq!((q[0], q[2], q[3], q[4]), (32767, 0, -32767, 0));
        assert!((i32::from(q[1]) + 8192).abs() <= 1, "{q:?}");
        assert_eq!(&q[5..], &[0, 0, 0]);
        assert_eq!(round_i16(2.5), 3);
        assert_eq!(round_i16(-2.5), -3);
        assert_eq!(round_i16(1e9), 32767);
        let mut q = [1i16; 4];
        assert_eq!(quantise_inputs(&[0.0; 3], &mut q), 1.0);
        assert_eq!(q, [0; 4]);
    }
}
