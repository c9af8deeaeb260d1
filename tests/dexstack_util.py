"""Shared helpers of the dexstack tests (tests/test_dexstack_*.py): building the Rust binaries
that write the reference traces, and skipping cleanly where the package is not installed."""
import functools
import subprocess

from conftest import ROOT, cargo_target_dir


@functools.cache
def rust_binary(name: str):
    """Builds `dex-trainer`'s binary `name` (the optimised dev profile, like the other tests)."""
    subprocess.run(["cargo", "build", "-q", "-p", "dex-trainer", "--bin", name], cwd=ROOT, check=True)
    path = cargo_target_dir() / "debug" / name
    assert path.exists(), path
    return path
