//! `fw-host`: the firmware's host twin.
//!
//! - `fw-host reference`: runs [`dex_firmware::run`] on the host with the same embedded policy and
//!   trace (same `DEX_POLICY`/`DEX_TRACE` at build time) and prints the same `H`/`L`/`A`/`C` lines
//!   as the board; `scripts/firmware-check.sh` compares them with QEMU's output.
//! - `fw-host make-policy HIDDEN SEED OUT [int8]`: writes a random-weight policy on the cell's
//!   layout (`dex_runtime::testkit::jaco_policy`), e.g. `fw-host make-policy 256,256 3 p.dxpl` for
//!   the default-size 44-256-256-9 network; with `int8` the same policy after post-training
//!   quantisation (`jaco_policy_int8`, format version 2).
//!
//! Build it for the host explicitly (the firmware workspace defaults to thumbv7em):
//! `cargo run --release -p dex-firmware-host --target x86_64-unknown-linux-gnu -- reference`.

use std::fmt;
use std::io::Write;
use std::process::ExitCode;

use dex_firmware::Platform;

/// Prints lines to stdout; measures nothing.
struct Host {
    out: std::io::StdoutLock<'static>,
    failed: bool,
}

impl Platform for Host {
    fn line(&mut self, args: fmt::Arguments<'_>) {
        self.failed |= writeln!(self.out, "{args}").is_err();
    }

    fn measure<R>(&mut self, f: impl FnOnce() -> R) -> (R, Option<u32>) {
        (f(), None)
    }
}

fn reference() -> ExitCode {
    let mut host = Host {
        out: std::io::stdout().lock(),
        failed: false,
    };
    match dex_firmware::run(&mut host) {
        Ok(s) if !host.failed => {
            host.line(format_args!("END ok steps={}", s.steps));
            ExitCode::SUCCESS
        }
        Ok(_) => ExitCode::FAILURE,
        Err(fault) => {
            host.line(format_args!("FAULT {fault}"));
            ExitCode::FAILURE
        }
    }
}

fn make_policy(hidden: &str, seed: &str, out: &str, int8: bool) -> Result<(), String> {
    let hidden: Vec<u16> = hidden
        .split(',')
        .map(|w| w.parse().map_err(|e| format!("hidden width {w:?}: {e}")))
        .collect::<Result<_, _>>()?;
    let seed: u64 = seed.parse().map_err(|e| format!("seed {seed:?}: {e}"))?;
    let bytes = if int8 {
        dex_runtime::testkit::jaco_policy_int8(&hidden, seed)
    } else {
        dex_runtime::testkit::jaco_policy(&hidden, seed)
    }
    .map_err(|e| e.to_string())?;
    std::fs::write(out, &bytes).map_err(|e| format!("{out}: {e}"))?;
    eprintln!(
        "wrote {out}: {} bytes, hidden {hidden:?}, seed {seed}{}",
        bytes.len(),
        if int8 { ", int8" } else { "" }
    );
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    match args.as_slice() {
        ["reference"] => reference(),
        ["make-policy", hidden, seed, out, rest @ ..] if rest.len() <= 1 => {
            let int8 = match rest {
                [] => false,
                ["int8"] => true,
                _ => {
                    eprintln!("fw-host: the optional last argument is `int8`");
                    return ExitCode::from(2);
                }
            };
            match make_policy(hidden, seed, out, int8) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("fw-host: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        _ => {
            eprintln!("usage: fw-host reference | fw-host make-policy HIDDEN SEED OUT [int8]");
            ExitCode::from(2)
        }
    }
}
