"""Shared helpers of the dexstack tests (tests/test_dexstack_*.py): building the Rust binaries
that write the reference traces, and skipping cleanly where the package is not installed."""
import functools
import subprocess

from conftest import ROOT, cargo_target_dir


#: `cargo build` of dex-trainer's binaries with the features of the dexstack build.
TRAINER_BUILD = ["cargo", "build", "-q", "-p", "dex-trainer", "-p", "dexstack"]


@functools.cache
def rust_binary(name: str):
    """Builds `dex-trainer`'s binary `name` (the optimised dev profile, like the other tests).

    `-p dexstack` is selected too so that cargo resolves the features as for the package that
    `scripts/setup-python.sh` built (PyO3's macros widen `syn`'s): the libraries both use (dex-env
    and below) are then reused, not compiled a second time."""
    subprocess.run(TRAINER_BUILD + ["--bin", name], cwd=ROOT, check=True)
    path = cargo_target_dir() / "debug" / name
    assert path.exists(), path
    return path
