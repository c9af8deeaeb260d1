//! `trainer soup OUT.dxpl FILE... [--weights W,...]`: a weight-space average of policy files of one
//! network (`dex_trainer::files::soup`), written atomically.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use dex_trainer::files::atomic_write::write_atomic;
use dex_trainer::files::soup::soup;

/// `trainer soup` flags.
#[derive(Args, Debug)]
pub struct SoupArgs {
    /// The averaged policy file to write.
    out: PathBuf,
    /// Policy files of one network (e.g. the seeds of one fine-tune, and the clone they started from).
    #[arg(required = true)]
    files: Vec<PathBuf>,
    /// One weight per file, comma-separated (normalised to sum to one); equal weights if left out.
    #[arg(long, value_delimiter = ',')]
    weights: Option<Vec<f64>>,
}

/// Runs `trainer soup`.
pub fn soup_files(args: &SoupArgs) -> anyhow::Result<()> {
    let bytes = args
        .files
        .iter()
        .map(|p| std::fs::read(p).with_context(|| format!("cannot read {}", p.display())))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let refs: Vec<&[u8]> = bytes.iter().map(Vec::as_slice).collect();
    let s = soup(&refs, args.weights.as_deref())?;
    write_atomic(&args.out, &s.file)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    for (p, w) in args.files.iter().zip(&s.weights) {
        println!("  {:.4} x {}", w, p.display());
    }
    println!(
        "wrote {} ({} bytes{})",
        args.out.display(),
        s.file.len(),
        if s.folded {
            "; the files' normalisations differed and were folded into the first layer"
        } else {
            ""
        }
    );
    Ok(())
}
