//! The policy-gradient update of one iteration: group advantages, the clipped surrogate, the anchors.

use dex_runtime::interface::ACT_DIM;

use crate::learn::Rng;
use crate::learn::adam::{AdamConfig, AdamLocal, AdamShared, adam_step};
use crate::learn::nets::MlpScratch;
use crate::pipeline::file_actor::FileActor;

use super::rollouts::Episode;
use super::{GroupPg, GroupPgError, IterationReport};

/// The group advantages, then `epochs` passes of the clipped surrogate (and the anchors) over the
/// kept steps: those of groups whose rewards differ (both outcomes, or with
/// [`GroupPg::contact_cost`] touches of brick 2 in some episodes only) and, with `fresh_anchor`, every step of the
/// first `seed_groups` groups (the start-seed ones).
#[allow(clippy::too_many_arguments)]
pub(super) fn update(
    s: &GroupPg,
    actor: &mut FileActor,
    episodes: &[Episode],
    seed_groups: usize,
    iteration: u32,
    adam: &AdamConfig,
    local: &mut AdamLocal,
    shared: &mut AdamShared,
    scratch: &mut MlpScratch,
) -> Result<IterationReport, GroupPgError> {
    let reps = s.replicates as usize;
    let d = actor.net.input_dim();
    let (mut inputs, mut noise, mut adv) = (Vec::new(), Vec::new(), Vec::new());
    // Each kept step's anchor weight.
    let mut weight = Vec::new();
    let mut mixed = 0u32;
    let mut row = vec![0.0f32; d];
    // An episode's reward: its success, less the contact cost when it touched brick 2 (or its
    // share when a fingertip came within the margin). With no
    // cost the rewards are the outcomes, and a group has a gradient when both outcomes occur.
    let reward = |e: &Episode| {
        f32::from(u8::from(e.success)) - s.contact_cost * s.contact_share(e.touched, e.clearance)
    };
    for (index, group) in episodes.chunks(reps).enumerate() {
        let total: f32 = group.iter().map(reward).sum();
        let both = group.iter().any(|e| reward(e) != reward(&group[0]));
        let fresh = if index < seed_groups {
            s.fresh_anchor
        } else {
            0.0
        };
        if !both && fresh == 0.0 {
            continue;
        }
        mixed += u32::from(both);
        let mean = total / group.len() as f32;
        for e in group {
            // A group whose rewards are all equal is kept for its anchor only: no advantage.
            let a = if both { reward(e) - mean } else { 0.0 };
            let w = if both { s.anchor + fresh } else { fresh };
            for (o, n) in e.obs.iter().zip(&e.noise) {
                actor.input(o, &mut row);
                inputs.extend_from_slice(&row);
                noise.extend_from_slice(n);
                adv.push(a);
                weight.push(w);
            }
        }
    }
    let samples = adv.len();
    let successes = episodes.iter().filter(|e| e.success).count() as u32;
    let mut report = IterationReport {
        iteration,
        episodes: episodes.len() as u32,
        successes,
        mixed_groups: mixed,
        samples: samples as u64,
        clipped: 0.0,
        drift: 0.0,
        env_steps: 0,
        stall_groups: 0,
        stall_successes: 0,
        stall_pool: 0,
        close_groups: 0,
        close_successes: 0,
        failed_groups: 0,
        failed_successes: 0,
        touched: episodes.iter().filter(|e| e.touched).count() as u32,
        close_touched: 0,
    };
    if samples == 0 {
        return Ok(report);
    }
    let inv_var: [f32; ACT_DIM] = std::array::from_fn(|j| 1.0 / (s.sigma(j) * s.sigma(j)));
    let old = actor.outputs(&actor.params, &inputs, scratch)?;
    let clone = actor.outputs(&actor.clone, &inputs, scratch)?;
    let mut order: Vec<usize> = (0..samples).collect();
    let mut rng = Rng::derive(s.seed, 0x6770_8000 + u64::from(iteration));
    let mb = s.minibatch as usize;
    let (mut batch_in, mut dout) = (vec![0.0f32; mb * d], vec![0.0f32; mb * ACT_DIM]);
    let mut mu = vec![0.0f32; mb * ACT_DIM];
    let mut grads = vec![0.0f32; actor.params.len()];
    let (mut clipped, mut seen) = (0u64, 0u64);
    for _ in 0..s.epochs {
        for i in (1..samples).rev() {
            order.swap(i, rng.below(i + 1));
        }
        for chunk in order.chunks(mb) {
            let rows = chunk.len();
            for (r, &i) in chunk.iter().enumerate() {
                batch_in[r * d..(r + 1) * d].copy_from_slice(&inputs[i * d..(i + 1) * d]);
            }
            mu[..rows * ACT_DIM].copy_from_slice(actor.net.forward(
                &actor.params,
                &batch_in[..rows * d],
                rows,
                scratch,
            )?);
            let scale = 1.0 / rows as f32;
            for (r, &i) in chunk.iter().enumerate() {
                let (mo, ep, mc) = (
                    &old[i * ACT_DIM..(i + 1) * ACT_DIM],
                    &noise[i * ACT_DIM..(i + 1) * ACT_DIM],
                    &clone[i * ACT_DIM..(i + 1) * ACT_DIM],
                );
                let mn = &mu[r * ACT_DIM..(r + 1) * ACT_DIM];
                // a = mo + ep; log ratio = sum_j ((a - mo)^2 - (a - mn)^2) / (2 sigma^2).
                let mut log_ratio = 0.0f32;
                for j in 0..ACT_DIM {
                    let diff = mo[j] + ep[j] - mn[j];
                    log_ratio += (ep[j] * ep[j] - diff * diff) * 0.5 * inv_var[j];
                }
                let ratio = log_ratio.clamp(-20.0, 20.0).exp();
                let a = adv[i];
                let cut = (a > 0.0 && ratio > 1.0 + s.clip) || (a < 0.0 && ratio < 1.0 - s.clip);
                seen += 1;
                clipped += u64::from(cut);
                let g = &mut dout[r * ACT_DIM..(r + 1) * ACT_DIM];
                for j in 0..ACT_DIM {
                    let pg = if cut {
                        0.0
                    } else {
                        -a * ratio * (mo[j] + ep[j] - mn[j]) * inv_var[j]
                    };
                    g[j] = (pg + weight[i] * (mn[j] - mc[j]) * inv_var[j]) * scale;
                }
            }
            actor.net.backward(
                &actor.params,
                &batch_in[..rows * d],
                scratch,
                &dout[..rows * ACT_DIM],
                Some(&mut grads),
                None,
            )?;
            adam_step(adam, &mut actor.params, &grads, local, shared);
        }
    }
    let now = actor.outputs(&actor.params, &inputs, scratch)?;
    let mut sq = 0.0f64;
    for (i, (x, c)) in now.iter().zip(&clone).enumerate() {
        let z = f64::from((x - c) / s.sigma(i % ACT_DIM));
        sq += z * z;
    }
    report.clipped = clipped as f64 / seen.max(1) as f64;
    report.drift = (sq / now.len().max(1) as f64).sqrt();
    Ok(report)
}
