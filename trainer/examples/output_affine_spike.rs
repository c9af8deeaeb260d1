//! Spike (session 31, docs/experiments.md): a policy file with an affine change of its output
//! layer's pre-activations, `z_j -> g_j * z_j + b_j` for each of the nine action joints (arm 1-6,
//! fingers 1-3), written as a new file the runtime runs unchanged.
//!
//! ```text
//! cargo run --release -p dex-trainer --example output_affine_spike -- POLICY.dxpl OUT_DIR \
//!     NAME=g1,...,g9@b1,...,b9 [...]
//! ```

use std::path::PathBuf;

use anyhow::{Context, bail};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        bail!("usage: POLICY OUT_DIR NAME=g1,...,g9@b1,...,b9 ...");
    }
    let bytes = std::fs::read(&args[0]).with_context(|| format!("reading {}", args[0]))?;
    let aligned = dex_runtime::aligned::aligned_copy(&bytes);
    let view = dex_policy::PolicyView::decode(aligned.as_bytes())?;
    let values = view.values().as_slice()?.to_vec();
    let out = view.layers().last().context("no layers")?;
    let dir = PathBuf::from(&args[1]);
    std::fs::create_dir_all(&dir)?;
    for spec in &args[2..] {
        let (name, rest) = spec.split_once('=').context("NAME=...")?;
        let (g, b) = rest.split_once('@').context("GAINS@BIASES")?;
        let parse = |s: &str| -> anyhow::Result<Vec<f32>> {
            let v = s
                .split(',')
                .map(|x| x.parse::<f32>().context("number"))
                .collect::<anyhow::Result<Vec<_>>>()?;
            if v.len() != out.outputs {
                bail!("{} values, need {}", v.len(), out.outputs);
            }
            Ok(v)
        };
        let (g, b) = (parse(g)?, parse(b)?);
        let mut v = values.clone();
        for i in 0..out.inputs {
            for j in 0..out.outputs {
                v[out.weights + i * out.outputs + j] *= g[j];
            }
        }
        for j in 0..out.outputs {
            let k = out.biases + j;
            v[k] = g[j] * v[k] + b[j];
        }
        let file = dex_policy::encode_to_vec(view.body(), &v)?;
        let path = dir.join(format!("{name}.dxpl"));
        std::fs::write(&path, file)?;
        println!("{}", path.display());
    }
    Ok(())
}
