"""Rendering cost of the dexstack package: frames per second of MuJoCo's offscreen renderer drawing
the Rust environment's state, per OpenGL backend, against the same steps without a render mode.

    .venv/bin/python scripts/bench-render.py [--size 480] [--frames 100] [--backends egl,osmesa]

Each backend runs in its own Python process (MuJoCo reads MUJOCO_GL once, at import). Per backend:
the first frame (the `mujoco` import, the scene's model, the OpenGL context), `draw` alone (state
copy + mj_forward + drawing + read-back of one state, the renderer's whole cost per frame), and
Stack episodes with the scripted demonstrator stepped and drawn at every step (what
`render_mode="rgb_array"` with RecordVideo or `python -m dexstack.render` costs), against the same
steps without a render mode. Prints a Markdown table (docs/benchmarks.md).
"""

import argparse
import json
import os
import platform
import subprocess
import sys
import time

CHILD = r"""
import json, sys, time
import numpy as np
import dexstack
from dexstack import renderer as R

size, frames = int(sys.argv[1]), int(sys.argv[2])

def steps_per_s(render):
    options = {"render_mode": "rgb_array", "width": size, "height": size} if render else {}
    env = dexstack.JacoEnv(task="stack", **options)
    demo = dexstack.Demonstrator("stack")
    env.reset(seed=0)
    if render:
        env.render()
        for _ in range(5):  # warm-up: llvmpipe compiles its shaders on the first frames
            env.render()
    n, t0, truncated = 0, time.perf_counter(), False
    while n < frames:
        _, _, _, truncated, _ = env.step(demo.act(env))
        if render:
            frame = env.render()
            assert frame.shape == (size, size, 3)
        n += 1
        if truncated:
            env.reset()
    dt = time.perf_counter() - t0
    env.close()
    return n / dt

t0 = time.perf_counter()
r = R.Renderer(camera="front", width=size, height=size)
env = dexstack.JacoEnv(task="stack")
env.reset(seed=1)
state = env._core.render_state()
r.draw(state)
first = time.perf_counter() - t0
for _ in range(5):
    r.draw(state)
t = time.perf_counter()
for _ in range(frames):
    r.draw(state)
draw = frames / (time.perf_counter() - t)
t = time.perf_counter()
for _ in range(frames):
    r.set_state(state)
copy = frames / (time.perf_counter() - t)
from OpenGL import GL  # noqa: E402 - with the context current: which rasteriser draws
gl = GL.glGetString(GL.GL_RENDERER).decode()
r.close()
print(json.dumps({"gl": gl, "first_s": first, "draw_fps": draw, "copy_per_s": copy,
                  "step_render_fps": steps_per_s(True), "step_fps": steps_per_s(False)}))
"""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", type=int, default=480)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--backends", default="egl,osmesa")
    a = p.parse_args()
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    rows = []
    for backend in a.backends.split(","):
        run = subprocess.run([sys.executable, "-c", CHILD, str(a.size), str(a.frames)], capture_output=True,
                             text=True, env={**env, "MUJOCO_GL": backend})
        if run.returncode != 0:
            print(f"{backend}: failed\n{run.stderr[-2000:]}", file=sys.stderr)
            continue
        rows.append((backend, json.loads(run.stdout.strip().splitlines()[-1])))
    load = os.getloadavg()[0]
    print(f"{a.size}x{a.size}, {a.frames} frames each, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, load average {load:.1f}, {time.strftime('%Y-%m-%d')}\n")
    print("| MUJOCO_GL (GL renderer) | first frame | draw (state copy + mj_forward + draw + read-back) "
          "| step + render | step alone (no render mode) | state copy + mj_forward |")
    print("|---|---:|---:|---:|---:|---:|")
    for backend, r in rows:
        print(f"| {backend} ({r['gl']}) | {r['first_s']:.2f} s "
              f"| **{r['draw_fps']:.1f} frames/s** ({1000 / r['draw_fps']:.1f} ms) "
              f"| {r['step_render_fps']:.1f} steps/s | {r['step_fps']:.0f} steps/s | {r['copy_per_s']:.0f}/s |")


if __name__ == "__main__":
    main()
