//! A weight-space average of policy files of one network ("model soup", Wortsman et al. 2022; with
//! the starting clone among the files it is their WiSE-FT): one plain MLP again, exported and run
//! like any other file, no ensemble at run time.
//!
//! Fine-tunes of one clone stay in one basin of the loss (the RL stage moves the clone's weights
//! by small steps), so the average of their weights is a network in that basin whose errors are
//! not any one seed's; docs/experiments.md (session 19) measures what it does on Stack.
//!
//! Files must share the layout (task, observation and action fields, layer widths and
//! activations; the header's layout hash) and be f32. When all share their input normalisation
//! and clip bit for bit (seeds of one fine-tune), everything is averaged as stored and the
//! normalisation kept. Otherwise (a clone, whose file keeps its normalisation apart, beside its
//! fine-tunes, whose exporter folds it into the first layer) every file's normalisation is
//! folded into its first layer first (`w'[i][j] = w[i][j] / scale[i]`, `b'[j] = b[j] - sum_i
//! w[i][j] mean[i] / scale[i]`, in f64, by the same function as `trainer train --init-policy`), so
//! that all take raw observations; the soup then has the identity normalisation and the RL
//! exporter's clip ([`EXPORT_OBS_CLIP`]). As with the import, a file's own clip is dropped by the
//! fold: its function is kept wherever no normalised input exceeds that clip.

use dex_policy::{LayerDtype, PolicyView, encode_to_vec};

use crate::files::export::EXPORT_OBS_CLIP;
use crate::files::policy_import::fold_normalisation;

/// Why policy files cannot be averaged.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SoupError {
    /// No file was given.
    #[error("a soup needs at least one policy file")]
    NoFiles,
    /// A file does not decode.
    #[error("policy file {index}: {source}")]
    Format {
        /// Position of the file in the list.
        index: usize,
        /// The cause.
        source: dex_policy::FormatError,
    },
    /// A file's network or fields differ from the first file's.
    #[error(
        "policy file {index} is another network than the first (layout hash {found:#010x}, the \
         first {first:#010x}): only files of one network (task, fields, widths) average"
    )]
    Layout {
        /// Position of the file in the list.
        index: usize,
        /// Its layout hash.
        found: u32,
        /// The first file's.
        first: u32,
    },
    /// A file is for another task, or maps its actions to other joint ranges, than the first.
    #[error("policy file {index} has another {what} than the first: average files of one task")]
    Mismatch {
        /// Position of the file in the list.
        index: usize,
        /// What differs.
        what: &'static str,
    },
    /// A file has an int8 layer.
    #[error("layer {layer} of policy file {index} is int8: average the f32 files, then quantise")]
    NotF32 {
        /// Position of the file in the list.
        index: usize,
        /// The layer.
        layer: usize,
    },
    /// The weights are not one non-negative finite weight per file with a positive sum.
    #[error("weights: {why}")]
    Weights {
        /// What is wrong.
        why: &'static str,
    },
    /// A normalisation scale is zero or not finite, or an averaged value is not finite.
    #[error("policy file {index}: value {value} is not finite after folding its normalisation")]
    NotFinite {
        /// Position of the file in the list.
        index: usize,
        /// The stored value's index.
        value: usize,
    },
}

/// What [`soup`] made.
#[derive(Debug, Clone, PartialEq)]
pub struct Soup {
    /// The averaged policy file.
    pub file: Vec<u8>,
    /// Whether the files' normalisations differed and were folded into the first layer.
    pub folded: bool,
    /// The weights used, normalised to sum to one.
    pub weights: Vec<f64>,
}

/// Averages `files` with `weights` (one per file, normalised to sum to one; `None`: equal). The
/// first file's body (task, fields, provenance) is kept.
pub fn soup(files: &[&[u8]], weights: Option<&[f64]>) -> Result<Soup, SoupError> {
    if files.is_empty() {
        return Err(SoupError::NoFiles);
    }
    let weights = normalised_weights(files.len(), weights)?;
    let aligned: Vec<_> = files
        .iter()
        .map(|f| dex_runtime::aligned::aligned_copy(f))
        .collect();
    let views = aligned
        .iter()
        .enumerate()
        .map(|(index, a)| {
            PolicyView::decode(a.as_bytes()).map_err(|source| SoupError::Format { index, source })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let first = views[0].header().layout_hash;
    for (index, v) in views.iter().enumerate() {
        if v.header().layout_hash != first || v.values().len() != views[0].values().len() {
            return Err(SoupError::Layout {
                index,
                found: v.header().layout_hash,
                first,
            });
        }
        if v.body().task != views[0].body().task {
            return Err(SoupError::Mismatch {
                index,
                what: "task",
            });
        }
        if v.body().action != views[0].body().action {
            return Err(SoupError::Mismatch {
                index,
                what: "action map",
            });
        }
        if let Some(layer) = v.layers().position(|l| l.dtype != LayerDtype::F32) {
            return Err(SoupError::NotF32 { index, layer });
        }
    }
    let obs = views[0].body().obs_dim();
    let norm = views[0].normalisation_offset();
    let same_inputs = views.iter().all(|v| {
        v.body().obs_clip.to_bits() == views[0].body().obs_clip.to_bits()
            && v.values().bytes()[norm * 4..(norm + 2 * obs) * 4]
                == views[0].values().bytes()[norm * 4..(norm + 2 * obs) * 4]
    });
    let mut sum = vec![0f64; views[0].values().len()];
    for (index, (v, &w)) in views.iter().zip(&weights).enumerate() {
        let values = if same_inputs {
            v.values().iter().map(f64::from).collect()
        } else {
            folded_values(v).ok_or(SoupError::NotFinite { index, value: 0 })?
        };
        for (s, x) in sum.iter_mut().zip(values) {
            *s += w * x;
        }
    }
    let mut values = Vec::with_capacity(sum.len());
    for (value, s) in sum.into_iter().enumerate() {
        let x = s as f32;
        if !x.is_finite() {
            return Err(SoupError::NotFinite { index: 0, value });
        }
        values.push(x);
    }
    let mut body = views[0].body().clone();
    if !same_inputs {
        body.obs_clip = EXPORT_OBS_CLIP;
    }
    let file =
        encode_to_vec(&body, &values).map_err(|source| SoupError::Format { index: 0, source })?;
    Ok(Soup {
        file,
        folded: !same_inputs,
        weights,
    })
}

fn normalised_weights(n: usize, weights: Option<&[f64]>) -> Result<Vec<f64>, SoupError> {
    let w = match weights {
        None => vec![1.0; n],
        Some(w) if w.len() != n => {
            return Err(SoupError::Weights {
                why: "one weight per file",
            });
        }
        Some(w) => w.to_vec(),
    };
    if w.iter().any(|x| !x.is_finite() || *x < 0.0) {
        return Err(SoupError::Weights {
            why: "each weight finite and not negative",
        });
    }
    let total: f64 = w.iter().sum();
    if total <= 0.0 {
        return Err(SoupError::Weights {
            why: "at least one weight above zero",
        });
    }
    Ok(w.iter().map(|x| x / total).collect())
}

/// The file's values with its normalisation folded into the first layer
/// ([`fold_normalisation`], as `--init-policy` imports a clone) and replaced by the identity
/// (mean 0, scale 1); `None` when a folded value is not finite (a zero scale).
fn folded_values(view: &PolicyView<'_>) -> Option<Vec<f64>> {
    let stored: Vec<f32> = view.values().iter().collect();
    let obs = view.body().obs_dim();
    let norm = view.normalisation_offset();
    let first = view.layer(0)?;
    let (weights, bias) = fold_normalisation(
        stored.get(first.weights..first.weights + first.inputs * first.outputs)?,
        stored.get(first.biases..first.biases + first.outputs)?,
        stored.get(norm..norm + obs)?,
        stored.get(norm + obs..norm + 2 * obs)?,
        first.outputs,
    );
    let mut v: Vec<f64> = stored.iter().map(|&x| f64::from(x)).collect();
    v[first.weights..first.weights + weights.len()].copy_from_slice(&weights);
    v[first.biases..first.biases + bias.len()].copy_from_slice(&bias);
    v[norm..norm + obs].fill(0.0);
    v[norm + obs..norm + 2 * obs].fill(1.0);
    v.iter().all(|x| x.is_finite()).then_some(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use dex_policy::synth::{SynthSpec, golden_small_spec, synth_policy};
    use dex_runtime::mlp::Mlp;

    fn file(seed: u64) -> Vec<u8> {
        synth_policy(&SynthSpec {
            seed,
            ..golden_small_spec()
        })
        .unwrap()
    }

    fn act(file: &[u8], obs: &[f32]) -> Vec<f32> {
        let aligned = dex_runtime::aligned::aligned_copy(file);
        let view = PolicyView::decode(aligned.as_bytes()).unwrap();
        let mut mlp = Mlp::<16>::new(&view).unwrap();
        let mut a = vec![0.0; mlp.act_dim()];
        mlp.act(obs, &mut a).unwrap();
        a
    }

    fn values(file: &[u8]) -> Vec<f32> {
        let aligned = dex_runtime::aligned::aligned_copy(file);
        PolicyView::decode(aligned.as_bytes())
            .unwrap()
            .values()
            .iter()
            .collect()
    }

    #[test]
    fn a_soup_of_one_file_is_that_file() {
        let f = file(7);
        let s = soup(&[&f, &f, &f], None).unwrap();
        assert!(!s.folded);
        assert_eq!(s.file, f);
    }

    #[test]
    fn files_of_one_normalisation_average_weight_by_weight() {
        // Two files that share the normalisation: the second is the first with its layers moved.
        let a = file(7);
        let aligned = dex_runtime::aligned::aligned_copy(&a);
        let view = PolicyView::decode(aligned.as_bytes()).unwrap();
        let obs = view.body().obs_dim();
        let mut moved = values(&a);
        for x in &mut moved[2 * obs..] {
            *x += 0.25;
        }
        let b = encode_to_vec(view.body(), &moved).unwrap();
        let s = soup(&[&a, &b], Some(&[3.0, 1.0])).unwrap();
        assert!(!s.folded);
        assert_eq!(s.weights, vec![0.75, 0.25]);
        let (va, vs) = (values(&a), values(&s.file));
        for (k, (x, y)) in va.iter().zip(&vs).enumerate() {
            let want = if k < 2 * obs { *x } else { *x + 0.0625 };
            assert!((y - want).abs() < 1e-6, "value {k}: {y} against {want}");
        }
    }

    #[test]
    fn different_normalisations_are_folded_and_keep_each_function() {
        let (a, b) = (file(7), file(8));
        // Folding alone (a file with itself at two normalisations is not possible, so: each file
        // beside a copy whose normalisation differs only in the clip) keeps the function.
        for f in [&a, &b] {
            let aligned = dex_runtime::aligned::aligned_copy(f);
            let view = PolicyView::decode(aligned.as_bytes()).unwrap();
            let mut body = view.body().clone();
            body.obs_clip = 4.0;
            let twin = encode_to_vec(&body, &values(f)).unwrap();
            let s = soup(&[f, &twin], None).unwrap();
            assert!(s.folded);
            for k in 0..20 {
                let obs: Vec<f32> = (0..5).map(|i| ((k * 5 + i) as f32 * 0.37).sin()).collect();
                let (want, got) = (act(f, &obs), act(&s.file, &obs));
                for (w, g) in want.iter().zip(&got) {
                    assert!((w - g).abs() < 1e-5, "{want:?} against {got:?}");
                }
            }
        }
        // Two different networks: the folded soup is the average of the folded weights.
        let s = soup(&[&a, &b], None).unwrap();
        assert!(s.folded);
        let aligned = dex_runtime::aligned::aligned_copy(&s.file);
        let view = PolicyView::decode(aligned.as_bytes()).unwrap();
        assert_eq!(view.body().obs_clip, EXPORT_OBS_CLIP);
        let v = values(&s.file);
        assert!(v[..5].iter().all(|&m| m == 0.0) && v[5..10].iter().all(|&sc| sc == 1.0));
    }

    #[test]
    fn what_cannot_be_averaged_is_refused() {
        let a = file(7);
        assert!(matches!(soup(&[], None), Err(SoupError::NoFiles)));
        for w in [&[1.0][..], &[1.0, -1.0], &[0.0, 0.0], &[f64::NAN, 1.0]] {
            assert!(matches!(
                soup(&[&a, &a], Some(w)),
                Err(SoupError::Weights { .. })
            ));
        }
        let wider = synth_policy(&SynthSpec {
            hidden: &[12],
            ..golden_small_spec()
        })
        .unwrap();
        assert!(matches!(
            soup(&[&a, &wider], None),
            Err(SoupError::Layout { index: 1, .. })
        ));
        let other_task = synth_policy(&SynthSpec {
            task: dex_policy::Task::Stack,
            ..golden_small_spec()
        })
        .unwrap();
        assert!(matches!(
            soup(&[&a, &other_task], None),
            Err(SoupError::Mismatch {
                index: 1,
                what: "task"
            })
        ));
        let other_map = synth_policy(&SynthSpec {
            action: &[
                ("joint_a", 0.5, -0.5, 0.5),
                ("joint_b", 1.0, -0.8, 0.8),
                ("finger", 4.0, -4.0, 4.0),
            ],
            ..golden_small_spec()
        })
        .unwrap();
        assert!(matches!(
            soup(&[&a, &other_map], None),
            Err(SoupError::Mismatch {
                index: 1,
                what: "action map"
            })
        ));
        let int8 = dex_policy::synth::golden_small_int8().unwrap();
        assert!(matches!(
            soup(&[&int8], None),
            Err(SoupError::NotF32 { index: 0, layer: 0 })
        ));
        let mut broken = a.clone();
        let last = broken.len() - 1;
        broken[last] ^= 1;
        assert!(matches!(
            soup(&[&a, &broken], None),
            Err(SoupError::Format { index: 1, .. })
        ));
    }
}
