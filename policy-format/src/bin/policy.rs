//! `policy`: inspect, verify and quantise policy files.
//!
//! `policy inspect FILE` prints metadata, sizes and the checksum; `policy verify FILE` checks the file
//! and exits non-zero with the reason when it is not valid; `policy quantise IN OUT` writes the int8
//! twin of an f32 file (format version 2).

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use dex_policy::{Activation, LayerDtype, PolicyView};

#[derive(Parser)]
#[command(
    name = "policy",
    version,
    about = "Inspect, verify and quantise dexterous-stack policy files"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the metadata, layouts, network, sizes and checksum of a policy file.
    Inspect {
        /// Policy file (.dxpl).
        file: PathBuf,
    },
    /// Check a policy file; exit status 0 when valid, 1 with the reason when not.
    Verify {
        /// Policy file (.dxpl).
        file: PathBuf,
    },
    /// Write the int8 twin of a policy file: every f32 layer quantised per output channel
    /// (`scale = max |w| / 127`, format version 2), the rest copied; the success rate in the
    /// provenance belonged to the f32 weights and is cleared. Lossless up to the runtime's int16
    /// activations for a policy trained for int8 (`trainer train --quantise-aware-from`); for any
    /// other, `trainer export --int8` (calibrated equalisation first, error measured) is the better
    /// tool.
    Quantise {
        /// f32 policy file (.dxpl).
        input: PathBuf,
        /// Output file.
        output: PathBuf,
    },
}

fn read(path: &PathBuf) -> anyhow::Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))
}

fn activation(a: Activation) -> &'static str {
    match a {
        Activation::Relu => "relu",
        Activation::Tanh => "tanh",
        Activation::Linear => "linear",
    }
}

fn inspect(bytes: &[u8]) -> anyhow::Result<()> {
    let view = PolicyView::decode(bytes).context("invalid policy file")?;
    let h = view.header();
    let b = view.body();
    println!("format version  {}", h.version);
    println!("file size       {} bytes", bytes.len());
    println!("crc32           {:#010x}", h.crc);
    println!("layout hash     {:#010x}", h.layout_hash);
    println!("task            {:?}", b.task);
    println!("control period  {} us", b.control_period_us);
    println!(
        "observation     {} values, clip +-{}",
        b.obs_dim(),
        b.obs_clip
    );
    for f in &b.observation {
        println!("  {:<24} {}", f.name, f.size);
    }
    println!("action          {} joints", b.act_dim());
    for j in &b.action {
        println!(
            "  {:<24} scale {:<8} limits [{}, {}]",
            j.name, j.scale, j.min, j.max
        );
    }
    let mut chain = b.obs_dim().to_string();
    for l in &b.layers {
        let dtype = match l.dtype {
            LayerDtype::F32 => "",
            LayerDtype::Int8 => " int8",
        };
        chain.push_str(&format!(
            " -> {} {}{dtype}",
            l.outputs,
            activation(l.activation)
        ));
    }
    println!("network         {chain}");
    let values = view.values().len();
    let normalisation = 2 * b.obs_dim();
    if b.has_int8() {
        println!(
            "stored words    {values} ({} bytes): {normalisation} normalisation, weights {} bytes, the rest f32 scales and biases",
            values * 4,
            view.weight_bytes()
        );
    } else {
        println!(
            "stored values   {values} f32 ({} bytes): {} parameters + {normalisation} normalisation",
            values * 4,
            values - normalisation
        );
    }
    println!("weight bytes    {}", view.weight_bytes());
    let p = &b.provenance;
    println!("trainer         {}", p.trainer_version);
    println!("seed            {}", p.seed);
    println!("transitions     {}", p.transitions);
    match p.success_rate {
        Some(rate) => println!(
            "success rate    {:.1}% over {} episodes",
            rate * 100.0,
            p.eval_episodes
        ),
        None => println!("success rate    not evaluated"),
    }
    Ok(())
}

/// `policy quantise`.
fn quantise(input: &PathBuf, output: &PathBuf) -> anyhow::Result<()> {
    let bytes = read(input)?;
    let view = PolicyView::decode(&bytes).context("invalid policy file")?;
    let f32_layers = view.layers().filter(|l| l.dtype == LayerDtype::F32).count();
    let on_grid = dex_policy::int8::policy_on_grid(&view)?;
    let provenance = dex_policy::Provenance {
        success_rate: None,
        eval_episodes: 0,
        ..view.body().provenance
    };
    let out = dex_policy::int8::quantise_policy(&view, |_| true, Some(provenance))?;
    std::fs::write(output, &out).with_context(|| format!("cannot write {}", output.display()))?;
    let q = PolicyView::decode(&out).context("quantised file")?;
    println!(
        "wrote {} (format version {}, weights {} bytes, f32 {}; {} bytes in all)",
        output.display(),
        q.header().version,
        q.weight_bytes(),
        view.weight_bytes(),
        out.len()
    );
    if f32_layers == 0 {
        println!("the file was already int8: copied");
    } else if on_grid {
        println!("the f32 weights were on the int8 grid: the int8 weights are the same numbers");
    } else {
        println!(
            "note: the f32 weights were not on the int8 grid (not trained for int8): expect a larger \
             action error; `trainer export --int8` equalises first and measures it"
        );
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Inspect { file } => inspect(&read(&file)?),
        Command::Quantise { input, output } => quantise(&input, &output),
        Command::Verify { file } => {
            let bytes = read(&file)?;
            match PolicyView::decode(&bytes) {
                Ok(view) => {
                    println!(
                        "OK: {} ({} bytes, crc32 {:#010x})",
                        file.display(),
                        bytes.len(),
                        view.header().crc
                    );
                    Ok(())
                }
                Err(e) => {
                    eprintln!("INVALID: {}: {e}", file.display());
                    std::process::exit(1);
                }
            }
        }
    }
}
