"""Speed of dm_control's Jaco tasks (`stack_2_bricks_features` by default, or any
`dm_control.manipulation` task name, e.g. `lift_brick_features`; MuJoCo 3.17.0) with random actions,
one process.

Prints control steps per second (resets included), the control timestep and simulated seconds per wall
second, as one JSON line. Run through scripts/bench-dm-control.sh, which makes the throwaway venv;
scripts/sb3-side-by-side.py imports `bench` to time these tasks beside dexstack in one process.

    python scripts/bench-dm-control.py [STEPS] [TASK]
"""

import json
import sys
import time

import numpy as np
from dm_control import manipulation


def bench(name: str, steps: int) -> dict:
    env = manipulation.load(name, seed=0)
    spec = env.action_spec()
    rng = np.random.default_rng(0)
    dt = env.control_timestep()
    t_reset = time.perf_counter()
    ts = env.reset()
    reset_s = time.perf_counter() - t_reset
    n = 0
    resets = 1
    start = time.perf_counter()
    while n < steps:
        a = rng.uniform(spec.minimum, spec.maximum).astype(spec.dtype)
        ts = env.step(a)
        n += 1
        if ts.last():
            env.reset()
            resets += 1
    wall = time.perf_counter() - start
    return {
        "env": f"dm_control {name}",
        "control_timestep_s": dt,
        "steps": n,
        "resets": resets,
        "wall_s": round(wall, 3),
        "steps_per_s": round(n / wall, 1),
        "sim_s_per_wall_s": round(n * dt / wall, 2),
        "first_reset_s": round(reset_s, 3),
    }


def main(steps: int, name: str) -> None:
    print(json.dumps(bench(name, steps)))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2000,
         sys.argv[2] if len(sys.argv) > 2 else "stack_2_bricks_features")
