"""The shipped Stack policy as an outside tool would deploy it: flashed into a controller that has
no policy yet, with the `canopen` library's SDO client over the virtual bus (program download into
0x1F50, start on 0x1F51, 0x1F56 checked: tests/test_sil_flash.py), then 10 MuJoCo episodes in
lockstep with the plant in another process (`hil-sim plant --connect`). Success and every applied
command equal `trainer eval`'s for the same starts (the runtime evaluator with the CAN
quantisation)."""
import re
import shutil
import subprocess

from conftest import ROOT, Sim, cargo_target_dir
from test_sil_flash import flash, flash_status, sdo_node

EPISODES = 10
SEED = 1_000_000  # trainer eval's default start seed
POLICY = ROOT / "policies" / "stack.dxpl"


def build(tmp_path, package, binary, features=()):
    """Builds a binary (the optimised dev profile) and copies it out of target/, which other
    tests rebuild with other features."""
    args = ["cargo", "build", "-q", "-p", package, "--bin", binary]
    if package == "dex-trainer":
        # With the dexstack package selected, cargo resolves features as for the build of
        # scripts/setup-python.sh and reuses its libraries (dex-env and below; tests/dexstack_util.py).
        args += ["-p", "dexstack"]
    if features:
        args += ["--features", ",".join(features)]
    subprocess.run(args, cwd=ROOT, check=True)
    copy = tmp_path / binary
    shutil.copy2(cargo_target_dir() / "debug" / binary, copy)
    return copy


def successes(text):
    return [m == "true" for m in re.findall(r"^episode \d+ .*success (true|false)", text, re.M)]


def test_stack_policy_flashed_over_the_bus_runs_like_trainer_eval(tmp_path):
    hil_sim = build(tmp_path, "dex-hil-sim", "hil-sim", ["mujoco"])
    trainer = build(tmp_path, "dex-trainer", "trainer")
    image = POLICY.read_bytes()

    s = Sim(hil_sim, None, tmp_path / "bus.log", ["--lockstep"])
    try:
        node = sdo_node(s)
        flash(node, image)  # download, start, 0x1F56 equal to the file's CRC-32
        assert flash_status(node) == (False, 0, False)
        node.network.disconnect()  # the tool leaves the bus before the episodes
        plant = subprocess.run(
            [hil_sim, "plant", "--connect", f"127.0.0.1:{s.port}", "--task", "stack",
             "--episodes", str(EPISODES), "--seed", str(SEED), "--actions", tmp_path / "bus.txt"],
            capture_output=True, text=True, timeout=600,
        )
        assert plant.returncode == 0, plant.stdout + plant.stderr
        assert "steps_without_action 0" in plant.stdout
        # Only the safety envelope's warnings (0xFF10 sustained limiting, 0x0000 its end) may occur.
        emcy = [l for l in plant.stdout.splitlines() if l.startswith("emergencies")]
        assert all(set(re.findall(r"[0-9A-F]{4}", l)) <= {"FF10", "0000"} for l in emcy), plant.stdout
    finally:
        s.close()

    direct = subprocess.run(
        # The controller node runs the safety envelope (its default): so does the evaluation.
        [trainer, "eval", POLICY, "--episodes", str(EPISODES), "--seed", str(SEED), "--envelope",
         "--actions", tmp_path / "eval.txt"],
        capture_output=True, text=True, timeout=600,
    )
    assert direct.returncode == 0, direct.stdout + direct.stderr
    over_bus, evaluated = successes(plant.stdout), successes(direct.stdout)
    assert len(over_bus) == EPISODES and over_bus == evaluated, (over_bus, evaluated)
    a = (tmp_path / "bus.txt").read_text().splitlines()
    b = (tmp_path / "eval.txt").read_text().splitlines()
    assert len(a) == EPISODES * 150 and a == b, next(
        ((i, x, y) for i, (x, y) in enumerate(zip(a, b)) if x != y), (len(a), len(b))
    )
    # The policy does its job over the bus too (its CI bound is 75% over 50 starts).
    assert sum(over_bus) >= 5, over_bus
