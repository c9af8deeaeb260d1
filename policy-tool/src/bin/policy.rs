//! `policy`: inspect, verify, quantise and convert policy files.
//!
//! `policy inspect FILE` prints metadata, sizes and the checksum; `policy verify FILE` checks the file
//! and exits non-zero with the reason when it is not valid; `policy quantise IN OUT` writes the int8
//! twin of an f32 file (format version 2); `policy import MODEL.onnx --out FILE.dxpl --task T`
//! turns an ONNX MLP (PyTorch, Stable-Baselines3) into a policy file; `policy export-onnx FILE.dxpl
//! --out MODEL.onnx` writes a policy file as an ONNX model.

use std::path::PathBuf;

use anyhow::Context;
use clap::{Parser, Subcommand};
use dex_policy::{Activation, LayerDtype, PolicyView};

#[derive(Parser)]
#[command(
    name = "policy",
    version,
    about = "Inspect, verify, quantise and convert (ONNX) dexterous-stack policy files"
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
    /// Write a policy file from an ONNX model of an MLP (what `torch.onnx.export` writes for a
    /// PyTorch or Stable-Baselines3 actor): Gemm or MatMul + Add layers with Relu or Tanh, input
    /// normalisation (Sub/Div/Mul/Add by constants, one symmetric Clip) and output scaling and
    /// limits folded in; any other operator is refused by name. A graph without output scaling
    /// gives actions in [-1, 1] (the dexstack action space), mapped by the layout's joint scales.
    Import {
        /// ONNX model (.onnx).
        model: PathBuf,
        /// Policy file to write (.dxpl); nothing is written when the model is refused.
        #[arg(long)]
        out: PathBuf,
        /// Task of the policy (reach, grasp, stack-in-hand, stack); default: the layout file's,
        /// else the model's `dexstack.task` metadata.
        #[arg(long, value_parser = parse_task)]
        task: Option<dex_policy::Task>,
        /// Take the observation and action layout (and joint scales and limits) from this policy
        /// file instead of the Jaco cell's.
        #[arg(long)]
        layout: Option<PathBuf>,
    },
    /// Write a policy file as an ONNX model (opset 17): normalisation, layers, joint scaling and
    /// limits, the channel names in the graph's descriptions and metadata. int8 layers are written
    /// as their dequantised f32 twin.
    ExportOnnx {
        /// Policy file (.dxpl).
        file: PathBuf,
        /// ONNX model to write (.onnx).
        #[arg(long)]
        out: PathBuf,
    },
}

fn parse_task(name: &str) -> Result<dex_policy::Task, String> {
    dex_policy::Task::from_name(name)
        .ok_or_else(|| format!("unknown task {name:?} (reach, grasp, stack-in-hand, stack)"))
}

/// `policy import`.
fn import(
    model: &PathBuf,
    out: &PathBuf,
    task: Option<dex_policy::Task>,
    layout: Option<&PathBuf>,
) -> anyhow::Result<()> {
    let bytes = read(model)?;
    let layout_bytes = layout.map(read).transpose()?;
    let layout_view = layout_bytes
        .as_deref()
        .map(PolicyView::decode)
        .transpose()
        .context("invalid layout file")?;
    let settings = dex_policy_tool::ImportSettings {
        task,
        layout: layout_view.as_ref(),
    };
    let imported = dex_policy_tool::import_onnx(&bytes, &settings)
        .with_context(|| format!("cannot import {}", model.display()))?;
    std::fs::write(out, &imported.file)
        .with_context(|| format!("cannot write {}", out.display()))?;
    let view = PolicyView::decode(&imported.file).context("imported file")?;
    let chain: Vec<String> = imported
        .layers
        .iter()
        .map(|(_, o, a)| format!("{o} {}", activation(*a)))
        .collect();
    println!(
        "wrote {} ({} policy, {} -> {}, {} bytes, crc32 {:#010x})",
        out.display(),
        imported.task.name(),
        imported.layers.first().map_or(0, |l| l.0),
        chain.join(" -> "),
        imported.file.len(),
        view.header().crc
    );
    println!(
        "outputs: {}",
        match imported.outputs {
            dex_policy_tool::OutputUnits::Physical =>
                "physical joint commands (the graph's output scaling and limits are the file's)",
            dex_policy_tool::OutputUnits::Normalised =>
                "normalised actions in [-1, 1] (the layout's joint scales and limits apply)",
        }
    );
    if !imported.folded.is_empty() {
        let folded: Vec<String> = imported
            .folded
            .iter()
            .map(|(what, n)| format!("{n} x {what}"))
            .collect();
        println!("folded: {}", folded.join(", "));
    }
    println!(
        "next: `trainer eval {}` measures it through the runtime",
        out.display()
    );
    Ok(())
}

/// `policy export-onnx`.
fn export_onnx(file: &PathBuf, out: &PathBuf) -> anyhow::Result<()> {
    let bytes = read(file)?;
    let view = PolicyView::decode(&bytes).context("invalid policy file")?;
    let onnx = dex_policy_tool::export_onnx(&bytes)?;
    std::fs::write(out, &onnx).with_context(|| format!("cannot write {}", out.display()))?;
    println!(
        "wrote {} (ONNX opset {}, {} bytes): observation [batch, {}] -> action [batch, {}]",
        out.display(),
        dex_policy_tool::onnx_export::OPSET,
        onnx.len(),
        view.body().obs_dim(),
        view.body().act_dim()
    );
    if view.body().has_int8() {
        println!(
            "note: the int8 layers are written as their dequantised f32 twin; the controller's int8 \
             kernel also rounds each layer's inputs to 16 bits, so its actions differ slightly"
        );
    }
    Ok(())
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
        Command::Import {
            model,
            out,
            task,
            layout,
        } => import(&model, &out, task, layout.as_ref()),
        Command::ExportOnnx { file, out } => export_onnx(&file, &out),
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
