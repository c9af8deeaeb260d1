//! A residual actor on a frozen starting policy (beyond the paper; `run.ddpg.residual`).
//!
//! Residual reinforcement learning on a behaviour-cloned base (Policy Decorator, Yuan et al.
//! 2024; ResiP, Ankile et al. 2024): the clone stays as it is and RL learns a correction on top,
//! so the fine-tune cannot unlearn the clone. Here the correction is added *before* the output's
//! tanh, `a = tanh(z_base(s) + z_res(s))`, which makes the pair one plain MLP: every hidden layer
//! is the base's units followed by `width` residual units, the residual units read the layer's
//! whole input (the observation, or the base's and their own features of the layer below), no
//! residual unit feeds a base unit (those weights are zero and stay zero), and the output layer
//! sums the base's head and the residual's. The exported file is therefore exactly the policy
//! that was trained (hidden widths `base + width`), with no distillation.
//!
//! The base's parameters (its weights, biases and head) and the zero blocks are frozen by
//! zeroing their gradients before the Adam step ([`freeze_base`]): with a zero gradient Adam's
//! first moment stays zero and the parameter does not move, bit for bit. The residual's head
//! starts at zero ([`compose`]), so the run starts from the base policy exactly; the residual
//! units start from the actor's usual random initialisation.

use std::ops::Range;

use super::LearnError;
use super::nets::Mlp;

/// One layer's place in the composed actor.
#[derive(Debug, Clone, Copy)]
struct Block {
    /// Offset of the layer's weights (input-major, `fan_in x fan_out`), followed by its biases.
    w: usize,
    fan_in: usize,
    fan_out: usize,
    /// The base's inputs (the first `base_in` of the layer's inputs).
    base_in: usize,
    /// The base's outputs (the first `base_out` of the layer's outputs).
    base_out: usize,
    /// The output layer (the sum of both heads).
    last: bool,
}

impl Block {
    /// Whether weight `(i, j)` (input `i`, output `j`) belongs to the residual.
    fn trains(&self, i: usize, j: usize) -> bool {
        if self.last {
            i >= self.base_in
        } else {
            j >= self.base_out
        }
    }
}

/// The hidden widths of the composed actor: each of the base's plus `width`.
pub fn widened(base_hidden: &[usize], width: usize) -> Vec<usize> {
    base_hidden.iter().map(|h| h + width).collect()
}

fn blocks(actor: &Mlp, base_hidden: &[usize]) -> Result<Vec<Block>, LearnError> {
    let spans: Vec<_> = actor.weight_spans().collect();
    if spans.len() != base_hidden.len() + 1 {
        return Err(LearnError::BadNetwork(
            "the residual actor has another depth than its base",
        ));
    }
    let mut out = Vec::with_capacity(spans.len());
    for (l, &(w, fan_in, fan_out)) in spans.iter().enumerate() {
        let last = l + 1 == spans.len();
        let base_in = if l == 0 { fan_in } else { base_hidden[l - 1] };
        let base_out = if last { fan_out } else { base_hidden[l] };
        if base_in > fan_in || base_out > fan_out {
            return Err(LearnError::BadNetwork(
                "the residual actor is narrower than its base",
            ));
        }
        out.push(Block {
            w,
            fan_in,
            fan_out,
            base_in,
            base_out,
            last,
        });
    }
    Ok(out)
}

/// Base-shaped parameter offsets: per layer, the start of its weights in a vector of the base's
/// layout (`base_in x base_out` weights, then `base_out` biases).
fn base_offsets(blocks: &[Block]) -> Vec<usize> {
    let mut at = 0;
    blocks
        .iter()
        .map(|b| {
            let o = at;
            at += b.base_in * b.base_out + b.base_out;
            o
        })
        .collect()
}

/// The composed actor's parameters: the base's (`base`, in the base network's layout) in its
/// blocks, the residual units' weights and biases from `fresh` (the composed actor's own random
/// initialisation), the residual's head and the blocks from residual to base units zero. The
/// composed actor computes exactly what the base does (up to the order of the sums).
pub fn compose(
    actor: &Mlp,
    base_hidden: &[usize],
    base: &[f32],
    fresh: &[f32],
) -> Result<Vec<f32>, LearnError> {
    let blocks = blocks(actor, base_hidden)?;
    let offsets = base_offsets(&blocks);
    let want = blocks
        .iter()
        .map(|b| b.base_in * b.base_out + b.base_out)
        .sum::<usize>();
    if base.len() != want {
        return Err(LearnError::Shape {
            what: "base actor parameters",
            expected: want,
            got: base.len(),
        });
    }
    if fresh.len() != actor.num_params() {
        return Err(LearnError::Shape {
            what: "residual actor parameters",
            expected: actor.num_params(),
            got: fresh.len(),
        });
    }
    let mut p = fresh.to_vec();
    for (b, &o) in blocks.iter().zip(&offsets) {
        for i in 0..b.fan_in {
            for j in 0..b.fan_out {
                let k = b.w + i * b.fan_out + j;
                p[k] = if i < b.base_in && j < b.base_out {
                    base[o + i * b.base_out + j]
                } else if b.trains(i, j) && !b.last {
                    fresh[k]
                } else {
                    0.0
                };
            }
        }
        let bias = b.w + b.fan_in * b.fan_out;
        let base_bias = o + b.base_in * b.base_out;
        for j in 0..b.fan_out {
            p[bias + j] = if j < b.base_out {
                base[base_bias + j]
            } else {
                fresh[bias + j]
            };
        }
    }
    Ok(p)
}

/// The parameters that are not the residual's (the base's blocks and the zero blocks from
/// residual to base units), as ranges of the actor's flat parameter vector: per row of a hidden
/// layer its first `base_out` weights, that layer's first `base_out` biases, and the output
/// layer's rows from the base's units. Computed once per network ([`super::ddpg::Networks`]).
pub fn frozen_ranges(actor: &Mlp, base_hidden: &[usize]) -> Result<Vec<Range<usize>>, LearnError> {
    let mut out = Vec::new();
    for b in blocks(actor, base_hidden)? {
        if b.last {
            out.push(b.w..b.w + b.base_in * b.fan_out);
            continue;
        }
        for i in 0..b.fan_in {
            let row = b.w + i * b.fan_out;
            out.push(row..row + b.base_out);
        }
        let bias = b.w + b.fan_in * b.fan_out;
        out.push(bias..bias + b.base_out);
    }
    Ok(out)
}

/// Zeroes the gradient of every parameter in `frozen` ([`frozen_ranges`]), so that Adam leaves
/// them as they are.
pub fn zero_frozen(frozen: &[Range<usize>], grads: &mut [f32]) -> Result<(), LearnError> {
    let len = grads.len();
    for r in frozen {
        grads
            .get_mut(r.clone())
            .ok_or(LearnError::Shape {
                what: "actor gradient",
                expected: r.end,
                got: len,
            })?
            .fill(0.0);
    }
    Ok(())
}

/// [`frozen_ranges`] and [`zero_frozen`] in one call.
pub fn freeze_base(
    actor: &Mlp,
    base_hidden: &[usize],
    grads: &mut [f32],
) -> Result<(), LearnError> {
    if grads.len() != actor.num_params() {
        return Err(LearnError::Shape {
            what: "actor gradient",
            expected: actor.num_params(),
            got: grads.len(),
        });
    }
    zero_frozen(&frozen_ranges(actor, base_hidden)?, grads)
}

/// How many of the composed actor's parameters train (the residual's).
pub fn trainable(actor: &Mlp, base_hidden: &[usize]) -> Result<usize, LearnError> {
    let frozen: usize = frozen_ranges(actor, base_hidden)?
        .iter()
        .map(|r| r.len())
        .sum();
    Ok(actor.num_params() - frozen)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::Rng;
    use crate::learn::kernel::Engine;
    use crate::learn::nets::{Activation, MlpSpec};

    fn actor(hidden: &[usize]) -> Mlp {
        Mlp::new(
            MlpSpec::stack(7, hidden, Activation::Relu, false, 3, Activation::Tanh),
            Engine::default(),
        )
        .unwrap()
    }

    #[test]
    fn the_composed_actor_computes_the_base_and_trains_only_the_residual() {
        let base_hidden = [6, 5];
        let base = actor(&base_hidden);
        let wide = actor(&widened(&base_hidden, 4));
        let mut rng = Rng::seed_from_u64(3);
        let bp = base.init_params(&mut rng, 0.5);
        let fresh = wide.init_params(&mut rng, 0.5);
        let p = compose(&wide, &base_hidden, &bp, &fresh).unwrap();
        let x: Vec<f32> = (0..7 * 5).map(|_| rng.normal(0.0, 1.0)).collect();
        let mut sb = base.scratch(5);
        let mut sw = wide.scratch(5);
        let yb = base.forward(&bp, &x, 5, &mut sb).unwrap().to_vec();
        let yw = wide.forward(&p, &x, 5, &mut sw).unwrap().to_vec();
        for (a, b) in yb.iter().zip(&yw) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        // The frozen entries: the base's parameters (6*7+6 + 5*6+5 + 3*5+3) and the zero blocks
        // from residual units to base units (layer 1: 4 x 5).
        let frozen = (7 * 6 + 6) + (6 * 5 + 5) + (5 * 3) + 4 * 5;
        assert_eq!(
            trainable(&wide, &base_hidden).unwrap(),
            wide.num_params() - frozen
        );
        // A gradient step on the unfrozen entries moves the output, and changing a frozen entry
        // after freezing is impossible: its gradient is zero.
        let mut g: Vec<f32> = (0..wide.num_params()).map(|i| i as f32 + 1.0).collect();
        freeze_base(&wide, &base_hidden, &mut g).unwrap();
        let spans: Vec<_> = wide.weight_spans().collect();
        let (w1, _, fo1) = spans[1];
        // Residual unit 7 of layer 1 into base unit 2 of layer 2: zero block, frozen.
        assert_eq!(g[w1 + 7 * fo1 + 2], 0.0);
        assert_eq!(p[w1 + 7 * fo1 + 2], 0.0);
        // Base unit 2 into residual unit 6: trains (the residual reads the base's features).
        assert_ne!(g[w1 + 2 * fo1 + 6], 0.0);
        // The head: base inputs frozen, residual inputs train (and start at zero).
        let (w2, _, fo2) = spans[2];
        assert_eq!(g[w2 + 4 * fo2], 0.0);
        assert_ne!(g[w2 + 6 * fo2], 0.0);
        assert_eq!(p[w2 + 6 * fo2], 0.0);
    }

    #[test]
    fn mismatched_shapes_are_refused() {
        let base_hidden = [6, 5];
        let wide = actor(&widened(&base_hidden, 4));
        let fresh = vec![0.0; wide.num_params()];
        assert!(compose(&wide, &base_hidden, &[0.0; 3], &fresh).is_err());
        assert!(compose(&wide, &[6], &[0.0; 3], &fresh).is_err());
        assert!(compose(&wide, &[60, 5], &[0.0; 3], &fresh).is_err());
        assert!(freeze_base(&wide, &base_hidden, &mut [0.0; 4]).is_err());
    }
}
