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

/// Quantises `x` to int16 into the packed words `xw` (two per word, `x[2k]` in the low half of
/// `xw[k]`) with one symmetric scale and zeroes the rest of `xw` (the padding inputs); returns the
/// scale `s_x = max|x| / 32767` (1 when all are zero).
///
/// `x_q = round(x * (1 / s_x))`, half away from zero, saturated to +-32767: the same f32 operations
/// on every target, so the same integers.
pub(crate) fn quantise_inputs(x: &[f32], xw: &mut [u32]) -> f32 {
    quantise_inputs_with_max(x, max_abs(x), false, xw)
}

/// `max |x|` over `x`, ignoring NaN, 0 for an empty slice: the same value as
/// `x.iter().fold(0.0, |m, v| m.max(v.abs()))` (`f32::max` returns the other operand for NaN, and
/// `abs` never gives -0), written as a compare so that no `fmaxf` call is made on the Cortex-M4.
pub(crate) fn max_abs(x: &[f32]) -> f32 {
    x.iter().fold(0.0f32, |m, v| keep_max(m, v.abs()))
}

/// `a` if `a > m`, else `m` (NaN `a` leaves `m`).
#[inline(always)]
fn keep_max(m: f32, a: f32) -> f32 {
    if a > m { a } else { m }
}

/// [`quantise_inputs`] with `max = max_abs(x)` already known (fused into the previous layer's
/// output loop by [`dense_int8`]). `nonneg` promises `x[i] >= 0` for all `i` (ReLU outputs): then
/// every `x * (1 / s_x)` is `>= 0` or NaN, where [`round_i16`] is `(v + 0.5) as i32` clamped to
/// `[0, 32767]` (one `USAT` on Arm): the same integers with less work.
pub(crate) fn quantise_inputs_with_max(x: &[f32], max: f32, nonneg: bool, xw: &mut [u32]) -> f32 {
    debug_assert!(!nonneg || x.iter().all(|v| *v >= 0.0));
    let sx = if max > 0.0 { max / X_MAX } else { 1.0 };
    let inv = 1.0 / sx;
    let (pairs, last) = x.as_chunks::<2>();
    let mut words = xw.iter_mut();
    // `pairs` first: a word is taken only for an existing pair.
    if nonneg {
        for ([a, b], q) in pairs.iter().zip(words.by_ref()) {
            let round = |v: f32| ((v + 0.5) as i32).clamp(0, 32767) as u32;
            *q = round(a * inv) | (round(b * inv) << 16);
        }
    } else {
        for ([a, b], q) in pairs.iter().zip(words.by_ref()) {
            *q = pack(round_i16(a * inv), round_i16(b * inv));
        }
    }
    if let [a] = last
        && let Some(q) = words.next()
    {
        *q = pack(round_i16(a * inv), 0);
    }
    for q in words {
        *q = 0;
    }
    sx
}

/// Two int16 as one word, `lo` in the low half.
#[inline(always)]
fn pack(lo: i16, hi: i16) -> u32 {
    u32::from(lo as u16) | (u32::from(hi as u16) << 16)
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
/// `xw.len()` = padded inputs / 2), then ReLU when `relu` (`y > 0 ? y : 0`, as the evaluator's
/// `activate`). Returns `max |out|` (as [`max_abs`]), so that the next int8 layer need not scan
/// its inputs again.
///
/// Hand-written kernel, justified by a benchmark: under QEMU `-icount` on the 44-256-256-9 policy
/// the firmware's int8 evaluation took 199,471 instructions per step with the earlier two-output
/// kernel over unpermuted weights, 150,862 with LLVM's loop over this layout (23 instructions per
/// group), against the numbers in docs/firmware.md for this one (with feature `dsp` on Arm the
/// block's whole loop is assembly, [`block_dot`]); the portable path is measured there too.
#[inline(never)]
pub(crate) fn dense_int8(
    xw: &[u32],
    w: &[u32],
    scales: &[f32],
    bias: &[f32],
    sx: f32,
    relu: bool,
    out: &mut [f32],
) -> f32 {
    let groups = xw.len() / 2;
    let mut max = 0.0f32;
    if groups == 0 {
        return max;
    }
    let xw = &xw[..2 * groups];
    let mut blocks = w.chunks_exact(4 * groups);
    let (o4, o_tail) = out.as_chunks_mut::<4>();
    let (s4, s_tail) = scales.as_chunks::<4>();
    let (b4, b_tail) = bias.as_chunks::<4>();
    // `blocks` last: a block is taken only when its outputs exist (the tail is done below).
    for (((o, s), b), block) in o4.iter_mut().zip(s4).zip(b4).zip(blocks.by_ref()) {
        rescale(o, s, b, &block_dot(block, xw), sx, relu, &mut max);
    }
    if !o_tail.is_empty()
        && let Some(block) = blocks.next()
    {
        rescale(
            o_tail,
            s_tail,
            b_tail,
            &block_dot(block, xw),
            sx,
            relu,
            &mut max,
        );
    }
    max
}

/// `o[r] = relu?(acc[r] as f32 * (s[r] * sx) + b[r])` for the outputs of one block, and their
/// `max |o[r]|` folded into `max`.
#[inline(always)]
fn rescale(
    o: &mut [f32],
    s: &[f32],
    b: &[f32],
    acc: &[i32; 4],
    sx: f32,
    relu: bool,
    max: &mut f32,
) {
    for (((o, &s), &b), &a) in o.iter_mut().zip(s).zip(b).zip(acc) {
        let y = a as f32 * (s * sx) + b;
        // ReLU as the evaluator's `activate` writes it (NaN becomes 0).
        let y = if !relu || y > 0.0 { y } else { 0.0 };
        *o = y;
        *max = keep_max(*max, y.abs());
    }
}

/// The four exact int32 dot products of one block: `block` holds `4 * groups` weight words
/// (group after group, one word per output), `xw` the `2 * groups` input words (`groups >= 1`).
#[cfg(not(all(feature = "dsp", target_arch = "arm")))]
#[inline(always)]
fn block_dot(block: &[u32], xw: &[u32]) -> [i32; 4] {
    let mut acc = [0i32; 4];
    for (wg, xg) in block.chunks_exact(4).zip(xw.chunks_exact(2)) {
        group(&mut acc, wg, xg[0], xg[1]);
    }
    acc
}

/// One group of [`block_dot`]'s assembly loop: one `LDRD` of the two input words (int16 pairs),
/// two `LDRD` of the four outputs' weight words, and per output two `SXTB16` + two `SMLAD` (as
/// [`group`] computes it); the pointers advance by post-increment.
#[cfg(all(feature = "dsp", target_arch = "arm"))]
macro_rules! group_asm {
    () => {
        concat!(
            "ldrd {x0}, {x1}, [{px}], #8\n",
            "ldrd {w0}, {w1}, [{pw}], #8\n",
            "sxtb16 {t}, {w0}\n",
            "smlad {a0}, {t}, {x0}, {a0}\n",
            "sxtb16 {t}, {w0}, ror #8\n",
            "smlad {a0}, {t}, {x1}, {a0}\n",
            "sxtb16 {t}, {w1}\n",
            "smlad {a1}, {t}, {x0}, {a1}\n",
            "sxtb16 {t}, {w1}, ror #8\n",
            "smlad {a1}, {t}, {x1}, {a1}\n",
            "ldrd {w0}, {w1}, [{pw}], #8\n",
            "sxtb16 {t}, {w0}\n",
            "smlad {a2}, {t}, {x0}, {a2}\n",
            "sxtb16 {t}, {w0}, ror #8\n",
            "smlad {a2}, {t}, {x1}, {a2}\n",
            "sxtb16 {t}, {w1}\n",
            "smlad {a3}, {t}, {x0}, {a3}\n",
            "sxtb16 {t}, {w1}, ror #8\n",
            "smlad {a3}, {t}, {x1}, {a3}\n",
        )
    };
}

/// [`block_dot`] as one assembly loop: four groups per pass ([`group_asm`], 19 instructions each)
/// and one compare-and-branch, accumulators in registers; a group count that is not a multiple of
/// four enters the loop at its second, third or fourth group. 19.5 instructions per group against
/// LLVM's 23 for [`group`] (docs/firmware.md).
#[cfg(all(feature = "dsp", target_arch = "arm"))]
#[inline(always)]
fn block_dot(block: &[u32], xw: &[u32]) -> [i32; 4] {
    let groups = (block.len() / 4).min(xw.len() / 2);
    if groups == 0 {
        return [0; 4];
    }
    let (w, x) = (&block[..4 * groups], &xw[..2 * groups]);
    let x_end = x.as_ptr_range().end;
    let (mut a0, mut a1, mut a2, mut a3) = (0i32, 0i32, 0i32, 0i32);
    // SAFETY: reads `4 * groups` words from `w` and `2 * groups` words from `x`, both in bounds
    // (the slices above) and word-aligned (`LDRD` needs 4-byte alignment on Armv7-M): the entry
    // point runs `groups % 4` groups (all four when 0) before the first compare, then whole passes
    // of four, so the input pointer reaches `x_end` exactly (8 bytes per group, `groups >= 1`).
    // Writes only the named registers and the flags; feature `dsp` promises the DSP extension.
    unsafe {
        core::arch::asm!(
            "sub {t}, {xe}, {px}",
            "and {t}, {t}, #24",
            "cmp {t}, #16",
            "beq 4f",
            "bhi 3f",
            "cmp {t}, #8",
            "beq 5f",
            "2:",
            group_asm!(),
            "3:",
            group_asm!(),
            "4:",
            group_asm!(),
            "5:",
            group_asm!(),
            "cmp {px}, {xe}",
            "bne 2b",
            pw = inout(reg) w.as_ptr() => _,
            px = inout(reg) x.as_ptr() => _,
            xe = in(reg) x_end,
            a0 = inout(reg) a0,
            a1 = inout(reg) a1,
            a2 = inout(reg) a2,
            a3 = inout(reg) a3,
            w0 = out(reg) _,
            w1 = out(reg) _,
            x0 = out(reg) _,
            x1 = out(reg) _,
            t = out(reg) _,
            options(nostack, readonly),
        );
    }
    [a0, a1, a2, a3]
}

/// Adds one group of four inputs (`x01`, `x23`: two int16 each) times the four outputs' weight
/// words `w` to the accumulators.
#[cfg_attr(all(feature = "dsp", target_arch = "arm"), allow(dead_code))]
#[inline(always)]
fn group(acc: &mut [i32; 4], w: &[u32], x01: u32, x23: u32) {
    for (a, &wv) in acc.iter_mut().zip(w) {
        *a = smlad(sxtb16(wv), x01, *a);
        *a = smlad(sxtb16_ror8(wv), x23, *a);
    }
}

/// Bytes 0 and 2 of `x`, sign-extended to two i16 halves (Arm `SXTB16`).
#[cfg_attr(all(feature = "dsp", target_arch = "arm"), allow(dead_code))]
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
#[cfg_attr(all(feature = "dsp", target_arch = "arm"), allow(dead_code))]
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
#[cfg_attr(all(feature = "dsp", target_arch = "arm"), allow(dead_code))]
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

    /// The int16 values of packed words.
    fn unpack(w: &[u32]) -> std::vec::Vec<i16> {
        w.iter()
            .flat_map(|&v| [v as u16 as i16, (v >> 16) as u16 as i16])
            .collect()
    }

    #[test]
    fn inputs_round_half_away_and_saturate() {
        let mut w = [7u32; 4];
        let sx = quantise_inputs(&[2.0, -0.5, 0.0, -2.0, 1e-9], &mut w);
        let q = unpack(&w);
        assert_eq!(sx, 2.0 / 32767.0);
        assert_eq!((q[0], q[2], q[3], q[4]), (32767, 0, -32767, 0));
        assert!((i32::from(q[1]) + 8192).abs() <= 1, "{q:?}");
        assert_eq!(&q[5..], &[0, 0, 0]);
        assert_eq!(round_i16(2.5), 3);
        assert_eq!(round_i16(-2.5), -3);
        assert_eq!(round_i16(1e9), 32767);
        let mut w = [1u32; 2];
        assert_eq!(quantise_inputs(&[0.0; 3], &mut w), 1.0);
        assert_eq!(w, [0; 2]);
    }

    #[test]
    fn max_abs_matches_f32_max() {
        let x = [0.5, -3.0, f32::NAN, 2.0, -0.0, f32::INFINITY, -7.5];
        for n in 0..=x.len() {
            let want = x[..n].iter().fold(0.0f32, |m, v| m.max(v.abs()));
            assert_eq!(max_abs(&x[..n]).to_bits(), want.to_bits(), "n = {n}");
        }
    }

    #[test]
    fn nonnegative_path_gives_the_same_integers() {
        // Pseudo-random non-negative inputs with exact ties, zeros, tiny and huge maxima.
        let mut rng = dex_policy::synth::SplitMix64::new(0x1234_5678);
        let mut next = move || (rng.next_u64() >> 32) as u32;
        for case in 0..200 {
            let n = 1 + (next() % 40) as usize;
            let mag = [1.0f32, 1e-3, 1e30, 1e-40, 3.0][case % 5];
            let x: std::vec::Vec<f32> = (0..n)
                .map(|i| match next() % 5 {
                    0 => 0.0,
                    1 => (i as f32 + 0.5) * mag,
                    _ => (next() % 100_000) as f32 / 100_000.0 * mag,
                })
                .collect();
            let mut a = [0xdead_beefu32; 24];
            let mut b = [0x0bad_f00du32; 24];
            let sa = quantise_inputs(&x, &mut a);
            let sb = quantise_inputs_with_max(&x, max_abs(&x), true, &mut b);
            assert_eq!(sa.to_bits(), sb.to_bits());
            assert_eq!(a, b, "case {case}: {x:?}");
        }
    }

    #[test]
    fn fused_rescale_matches_separate_passes() {
        // 6 inputs (2 groups after padding to 8), 5 outputs (2 blocks, the second partial).
        let (inputs, outputs) = (6usize, 5usize);
        let q: std::vec::Vec<i8> = (0..inputs * outputs)
            .map(|k| ((k * 37) % 255) as i8)
            .collect();
        let packed = dex_policy::int8::pack(inputs, outputs, &q);
        let w: std::vec::Vec<u32> = packed
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let x = [0.25f32, -1.5, 3.0, 0.0, -0.75, 2.0];
        let mut xw = [0u32; 4];
        let sx = quantise_inputs(&x, &mut xw);
        let xq = unpack(&xw);
        let scales = [0.01f32, 0.02, 0.5, 0.003, 1.0];
        let bias = [0.1f32, -0.2, 0.3, -5.0, 0.0];
        for relu in [false, true] {
            let mut out = [9.0f32; 5];
            let max = dense_int8(&xw, &w, &scales, &bias, sx, relu, &mut out);
            for j in 0..outputs {
                let acc: i32 = (0..inputs)
                    .map(|i| i32::from(q[j * inputs + i]) * i32::from(xq[i]))
                    .sum();
                let y = acc as f32 * (scales[j] * sx) + bias[j];
                let y = if !relu || y > 0.0 { y } else { 0.0 };
                assert_eq!(out[j].to_bits(), y.to_bits(), "output {j}, relu {relu}");
            }
            assert_eq!(max.to_bits(), max_abs(&out).to_bits());
        }
    }
}
