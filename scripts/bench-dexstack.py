"""Environment steps/s of the dexstack package from Python: one JacoEnv, and the native vector env
(N environments on Rust threads), uniform random actions, autoreset included.

    .venv/bin/python scripts/bench-dexstack.py [STEPS] [--task grasp] [--num-envs 2]
"""
import argparse
import time

import numpy as np

import dexstack


def single(task: str, steps: int) -> float:
    env = dexstack.JacoEnv(task=task)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, 9)).astype(np.float32)
    env.reset(seed=0)
    t = time.perf_counter()
    for a in actions:
        _, _, _, truncated, _ = env.step(a)
        if truncated:
            env.reset()
    return steps / (time.perf_counter() - t)


def vector(task: str, steps: int, n: int) -> float:
    env = dexstack.VectorEnv(num_envs=n, task=task)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps // n, n, 9)).astype(np.float32)
    env.reset(seed=0)
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    return len(actions) * n / (time.perf_counter() - t)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("steps", nargs="?", type=int, default=3000)
    p.add_argument("--task", default="grasp")
    p.add_argument("--num-envs", type=int, default=2)
    a = p.parse_args()
    print(f"{a.task}: one env {single(a.task, a.steps):.0f} steps/s; "
          f"vector env N={a.num_envs} {vector(a.task, a.steps, a.num_envs):.0f} steps/s")


if __name__ == "__main__":
    main()
