"""Render a recorded demonstrator episode (env-tool record) to PNG frames with MuJoCo's offscreen renderer.

    target-env/release/env-tool record --task stack --seed 0 --out runs/demo
    MUJOCO_GL=egl .venv-dmc/bin/python scripts/render-demo.py runs/demo [EVERY]

Needs EGL (Debian: libegl-mesa0 + libgl1-mesa-dri, software llvmpipe is fine) or OSMesa (MUJOCO_GL=osmesa,
libosmesa6). Writes DIR/frame_NNN.png for every EVERY-th control step, and DIR/strip.png (6 frames side by
side).
"""

import os
import struct
import sys
import zlib
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MESHES = ROOT / "third_party/assets/kinova/meshes_decimated"


def write_png(path: Path, rgb: np.ndarray) -> None:
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def main(run_dir: str, every: int) -> None:
    d = Path(run_dir)
    assets = {p.name: p.read_bytes() for p in MESHES.glob("*.stl")}
    model = mujoco.MjModel.from_xml_string((d / "scene.xml").read_text(), assets)
    # Brick 1 red, brick 2 blue (the Duplo model is grey).
    for body, rgba in (("brick1", (0.85, 0.15, 0.15, 1)), ("brick2", (0.15, 0.3, 0.85, 1))):
        bid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
        for g in range(model.ngeom):
            if model.geom_bodyid[g] == bid and model.geom_group[g] == 0:
                model.geom_rgba[g] = rgba
                model.geom_matid[g] = -1
    data = mujoco.MjData(model)
    qpos = np.loadtxt(d / "qpos.csv", delimiter=",", ndmin=2)
    renderer = mujoco.Renderer(model, height=360, width=480)
    frames = []
    for i, q in enumerate(qpos):
        if i % every and i != len(qpos) - 1:
            continue
        data.qpos[:] = q
        mujoco.mj_forward(model, data)
        renderer.update_scene(data, camera="front")
        img = renderer.render()
        write_png(d / f"frame_{i:03d}.png", img)
        frames.append(img)
    pick = [frames[round(k * (len(frames) - 1) / 5)] for k in range(6)]
    write_png(d / "strip.png", np.concatenate(pick, axis=1))
    print(f"wrote {len(frames)} frames and strip.png to {d} (MUJOCO_GL={os.environ.get('MUJOCO_GL')})")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "runs/demo", int(sys.argv[2]) if len(sys.argv) > 2 else 10)
