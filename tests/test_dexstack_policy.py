"""A shipped policy file evaluated from Python (dexstack.Policy through the runtime's evaluator,
with the CAN quantisation) equals `trainer eval` on the same starts: every applied command, bit for
bit, and every episode's success."""
import re
import subprocess

import gymnasium as gym
import numpy as np

import dexstack
from conftest import ROOT
from dexstack_util import rust_binary

POLICY = ROOT / "policies" / "grasp.dxpl"
EPISODES = 3
SEED = 1_000_000  # trainer eval's default start seed


def test_policy_file_from_python_equals_trainer_eval(tmp_path):
    out = tmp_path / "eval.txt"
    direct = subprocess.run(
        [rust_binary("trainer"), "eval", POLICY, "--episodes", str(EPISODES), "--seed", str(SEED),
         "--actions", out],
        capture_output=True, text=True, timeout=600,
    )
    assert direct.returncode == 0, direct.stdout + direct.stderr
    expected = [m == "true" for m in re.findall(r"^episode \d+ .*success (true|false)", direct.stdout, re.M)]
    assert len(expected) == EPISODES
    # `trainer eval --actions`: "episode step a0 .. a8", the physical commands (Rust's shortest
    # round-trip formatting, so float32 parses them back exactly).
    commands = {}
    for line in out.read_text().splitlines():
        e, t, *a = line.split()
        commands[(int(e), int(t))] = np.array([np.float32(x) for x in a], dtype=np.float32)
    assert len(commands) == EPISODES * 150

    policy = dexstack.Policy(POLICY)
    assert policy.task == "grasp" and policy.can_quantisation
    scale = np.array([j[1] for j in policy.info()["action"]], dtype=np.float32)
    env = gym.make("dexstack/Grasp-v0")
    got = []
    for e in range(EPISODES):
        obs, _ = env.reset(options={"episode_seed": dexstack.episode_seed(SEED, e)})
        truncated, t = False, 0
        while not truncated:
            action = policy.act(obs)
            # Ours is the environment's action: the physical command over each joint's scale.
            assert np.array_equal(action, commands[(e, t)] / scale), (e, t)
            obs, _, _, truncated, info = env.step(action)
            t += 1
        assert t == 150
        got.append(info["success"])
    assert got == expected, (got, expected)


def test_policy_info_has_the_header_and_layout():
    info = dexstack.Policy(POLICY).info()
    assert info["task"] == "grasp" and info["version"] in (1, 2)
    # The cell's observation, then the task features the shipped policies take (runtime/src/features.rs).
    assert [s for _, s in info["observation"]] == [6, 6, 3, 9, 3, 4, 3, 4, 3, 3] + [
        size for _, size in dexstack.TASK_FEATURE_FIELDS]
    assert [n for n, _ in info["observation"]][10:] == [n for n, _ in dexstack.TASK_FEATURE_FIELDS]
    assert [j[0] for j in info["action"]][:2] == ["arm_joint_1", "arm_joint_2"]
    assert [layer[0] for layer in info["layers"]] == [256, 256, 9]
    assert info["bytes"] == POLICY.stat().st_size and isinstance(info["crc"], int)
    assert "trainer_version" in info["provenance"]
