"""Bit-identical to Rust: `env-tool trace` (the Rust JacoEnv, driven by the scripted demonstrator
plus fixed noise) writes an episode; the Python package, reset to the same seed and given the same
actions, returns the same observations, rewards, success and predicates, bit for bit, and its
Demonstrator plans the same actions."""
import json
import subprocess

import gymnasium as gym
import numpy as np
import pytest

import dexstack
from dexstack_util import rust_binary

CASES = [
    ("reach", "Reach", "reach-shaping", 50),
    ("grasp", "Grasp", "full-composite", 150),
    ("stack-in-hand", "StackInHand", None, 40),
]


def bits(values):
    return np.asarray(values, dtype=np.uint32).view(np.float32)


@pytest.mark.parametrize("task,stem,reward,steps", CASES)
def test_python_env_equals_the_rust_trace(tmp_path, task, stem, reward, steps):
    env = gym.make(f"dexstack/{stem}-v0", **({"reward": reward} if reward else {}))
    _, info = env.reset(seed=2024)
    seed = int(info["episode_seed"])
    out = tmp_path / "trace.json"
    cmd = [rust_binary("env-tool"), "trace", "--task", task, "--seed", str(seed), "--steps", str(steps),
           "--out", out]
    if reward:
        cmd += ["--reward", reward]
    subprocess.run(cmd, check=True, capture_output=True)
    trace = json.loads(out.read_text())
    assert trace["seed"] == seed

    obs, _ = env.reset(options={"episode_seed": seed})
    assert np.array_equal(obs.view(np.uint32), np.asarray(trace["reset"], dtype=np.uint32))
    demo = dexstack.Demonstrator(task)
    for t, rec in enumerate(trace["steps"]):
        planned = demo.act(env)
        assert np.array_equal(planned.view(np.uint32), np.asarray(rec["demo"], np.uint32)), t
        obs, r, terminated, truncated, info = env.step(bits(rec["action"]))
        assert np.array_equal(obs.view(np.uint32), np.asarray(rec["obs"], np.uint32)), t
        assert np.float32(r).view(np.uint32) == rec["reward"], t
        assert (info["success"], info["reach"], info["grasp"], info["stack"]) == (
            rec["success"], rec["reach"], rec["grasp"], rec["stack"]), t
        assert terminated is False and truncated == rec["done"], t
    if task == "grasp":
        # The noisy demonstrator still lifts the brick: the trace covers contacts and a grasp.
        assert any(rec["grasp"] for rec in trace["steps"])
