"""Rendering in the dexstack package: Gymnasium's checks with a render mode, RecordVideo, frames that
show the Rust environment's own state (the red brick 1 is drawn where Rust says it is, and moves
with it), the video command against `trainer eval`, and bad input (a clear exception, the
environment still usable). Headless: EGL on Mesa's llvmpipe (scripts/test.sh installs it)."""
import os
import re
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dexstack
from dexstack import render as video
from dexstack import renderer
from conftest import ROOT
from dexstack_util import rust_binary

POLICY = ROOT / "policies" / "grasp.dxpl"
SMALL = {"width": 64, "height": 64}


def red_mask(frame):
    """Pixels of brick 1 (the only red thing in the scene)."""
    f = frame.astype(np.int32)
    r, g, b = f[..., 0], f[..., 1], f[..., 2]
    return (r > 60) & (r > 2 * g) & (r > 2 * b)


def project(r, point):
    """Pixel (column, row) of a world point in the renderer's `front` camera."""
    model, data = r._model, r.data
    cam = model.camera("front").id
    pos, mat = data.cam_xpos[cam], data.cam_xmat[cam].reshape(3, 3)
    x, y, z = mat.T @ (np.asarray(point, float) - pos)  # camera frame: x right, y up, looking along -z
    f = 0.5 * r.height / np.tan(np.radians(model.cam_fovy[cam]) / 2)
    return np.array([0.5 * r.width + f * x / -z, 0.5 * r.height - f * y / -z])


def centroid(mask):
    rows, cols = np.nonzero(mask)
    return np.array([cols.mean(), rows.mean()])


def test_metadata_and_check_env_with_rendering():
    env = gym.make("dexstack/Stack-v0", render_mode="rgb_array", **SMALL)
    assert env.metadata["render_fps"] == 20 == dexstack.renderer.RENDER_FPS  # one frame per 50 ms step
    assert "rgb_array" in env.metadata["render_modes"]
    assert ("human" in env.metadata["render_modes"]) == renderer.display_available()
    check_env(env.unwrapped)  # render check included: this env, and one made from the spec per mode
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8 and frame.std() > 5
    env.close()
    env.close()  # idempotent


def test_record_video_writes_one_frame_per_step(tmp_path):
    import imageio_ffmpeg

    steps = 12
    env = gym.make("dexstack/Stack-v0", render_mode="rgb_array", episode_steps=steps, width=96, height=96)
    env = gym.wrappers.RecordVideo(env, str(tmp_path / "videos"), episode_trigger=lambda e: e == 0, disable_logger=True)
    env.reset(seed=3)
    truncated, taken = False, 0
    while not truncated:
        _, _, _, truncated, _ = env.step(env.action_space.sample())
        taken += 1
    env.close()
    assert taken == steps
    path = tmp_path / "videos" / "rl-video-episode-0.mp4"
    assert path.exists()
    # Playable: ffmpeg decodes every frame. One frame for the start (reset) and one per step.
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    decoded = sum(1 for _ in reader)
    assert meta["size"] == (96, 96) and meta["fps"] == 20
    assert decoded == steps + 1 == imageio_ffmpeg.count_frames_and_secs(str(path))[0]


def test_same_state_same_frame_in_every_renderer():
    a = dexstack.JacoEnv(task="stack", render_mode="rgb_array", **SMALL)
    b = dexstack.JacoEnv(task="stack", render_mode="rgb_array", **SMALL)
    a.reset(options={"episode_seed": 17})
    b.reset(options={"episode_seed": 17})
    first, again, other = a.render(), a.render(), b.render()
    assert first is not again and np.array_equal(first, again) and np.array_equal(first, other)
    # The vector env draws each environment's own state with one shared renderer: the same frames.
    vec = dexstack.VectorEnv(2, task="stack", render_mode="rgb_array", **SMALL)
    vec.reset(options={"episode_seed": [17, 18]})
    frames = vec.render()
    assert isinstance(frames, tuple) and len(frames) == 2
    assert np.array_equal(frames[0], first) and not np.array_equal(frames[1], first)
    for env in (a, b, vec):
        env.close()


def test_frames_show_the_rust_state_and_follow_brick_1():
    """Brick 1 is drawn (red) where the Rust observation says it is, before and after the policy
    lifts it; a renderer that drew a stale or a default state would put it elsewhere. Moving brick 1
    alone in a copied state changes the frame."""
    env = gym.make("dexstack/Grasp-v0", render_mode="rgb_array", width=160, height=160)
    policy = dexstack.Policy(POLICY)
    obs, _ = env.reset(options={"episode_seed": dexstack.episode_seed(1_000_000, 0)})
    start = env.render()
    r = env.unwrapped._renderer
    assert np.array_equal(r.data.qpos, np.frombuffer(env.unwrapped._core.render_state(), np.float64)[1:1 + r._model.nq])
    at_start = project(r, obs[24:27] + [0, 0, 0.0096])  # obs[24:27]: brick 1's origin (bottom face)
    assert np.linalg.norm(centroid(red_mask(start)) - at_start) < 4
    # The default state (a fresh MjData) has brick 1 somewhere else: the frame is not that.
    default_brick = r._model.body("brick1").pos
    assert np.linalg.norm(project(r, default_brick) - at_start) > 10
    truncated = False
    while not truncated and obs[26] < 0.08:  # until the policy has lifted brick 1 by 8 cm
        obs, _, _, truncated, info = env.step(policy.act(obs))
    assert obs[26] >= 0.08, "grasp.dxpl did not lift brick 1 on trainer eval's first start"
    lifted = env.render()
    mask = red_mask(lifted)
    assert mask.sum() > 10
    now = project(r, obs[24:27] + [0, 0, 0.0096])
    assert np.linalg.norm(centroid(mask) - now) < 8 and np.linalg.norm(now - at_start) > 15

    # Brick 1 alone moved 4 cm in a copy of the state: the frame changes, the red patch follows.
    env.reset(options={"episode_seed": dexstack.episode_seed(1_000_000, 0)})
    state = np.frombuffer(env.unwrapped._core.render_state(), np.float64).copy()
    adr = 1 + r._model.jnt_qposadr[r._model.joint("brick1").id]  # state = [time, qpos, ...]
    state[adr] += 0.04
    moved = r.draw(state.tobytes())
    assert not np.array_equal(moved, start)
    assert centroid(red_mask(moved))[0] - centroid(red_mask(start))[0] > 3  # +x is to the right
    assert np.array_equal(env.render(), start)  # and the environment's own state draws as before
    env.close()


def _trainer_episode(episode):
    run = subprocess.run(
        [rust_binary("trainer"), "eval", POLICY, "--episodes", str(episode + 1), "--seed", "1000000",
         "--actions", os.devnull], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    return re.search(rf"^episode {episode} return (\S+) success (true|false)$", run.stdout, re.M).groups()


def test_video_command_equals_trainer_eval(tmp_path):
    import imageio_ffmpeg
    from PIL import Image

    out = tmp_path / "grasp.mp4"
    cmd = [sys.executable, "-m", "dexstack.render", str(POLICY), "--task", "grasp", "--episodes", "1",
           "--seed", "1000000", "--size", "80", "--every", "5", "--out", str(out)]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    got = re.search(r"^episode 0 return (\S+) success (true|false) seed (\d+) steps 150$", run.stdout, re.M)
    assert got, run.stdout
    assert int(got.group(3)) == dexstack.episode_seed(1_000_000, 0)
    assert got.groups()[:2] == _trainer_episode(0)
    frames = video.frames_per_episode(150, 5)
    assert frames == 31  # the start, steps 5, 10, ..., 150
    assert imageio_ffmpeg.count_frames_and_secs(str(out))[0] == frames
    assert next(imageio_ffmpeg.read_frames(str(out)))["size"] == (80, 80)
    gif = Image.open(out.with_suffix(".gif"))
    assert gif.size == (80, 80) and gif.n_frames == frames
    assert f"wrote {out} ({frames} frames, 80x80, 4 frames/s" in run.stdout


def test_video_command_failures_and_side_by_side(tmp_path, capsys, policies):
    # A random-weight Stack policy fails every start: --failures 2 draws episodes 0 and 1.
    out = tmp_path / "fail.gif"
    assert video.main([str(policies["other"]), "--failures", "2", "--search", "3", "--size", "48",
                       "--every", "50", "--hold", "0.5", "--out", str(out), "--formats", "gif"]) == 0
    text = capsys.readouterr().out
    assert "2 failing episode(s) among 2 searched from episode 0: [0, 1]" in text
    assert len(re.findall(r"^episode [01] return \S+ success false", text, re.M)) == 2
    from PIL import Image
    gif = Image.open(out)
    # 4 frames an episode (steps 0, 50, 100, 150); the 0.5 s hold (2 frames at 4 frames/s) merges
    # into the last frame's duration in a GIF.
    assert gif.size == (48, 48) and gif.n_frames == 2 * 4
    assert not out.with_suffix(".mp4").exists()
    # Side by side: two files from the same starts, one frame beside the other.
    out = tmp_path / "pair.mp4"
    assert video.main([str(POLICY), str(POLICY), "--labels", "f32,twin", "--episodes", "1", "--size", "40",
                       "--every", "75", "--out", str(out), "--formats", "mp4"]) == 0
    text = capsys.readouterr().out
    a = re.search(r"^episode 0 \[f32\] return (\S+) success (\w+)", text, re.M).groups()
    b = re.search(r"^episode 0 \[twin\] return (\S+) success (\w+)", text, re.M).groups()
    assert a == b
    import imageio_ffmpeg
    assert next(imageio_ffmpeg.read_frames(str(out)))["size"] == (82, 40)  # 40 + 2 (divider) + 40


# ---- bad input ---------------------------------------------------------------------------------


def test_bad_render_options_are_refused_clearly():
    for kwargs, message in [
        ({"camera": "ceiling"}, r"unknown camera 'ceiling' \(expected one of: front, overview, side, top\)"),
        ({"camera": 0}, "unknown camera 0"),
        ({"width": 0}, r"width = 0 is out of range: images are 1 to 4096"),
        ({"height": 100_000}, r"height = 100000 is out of range"),
        ({"width": 64.5}, "width must be an integer"),
        ({"height": True}, "height must be an integer"),
        ({"render_mode": "rgb"}, r"render_mode 'rgb' is not supported"),
    ]:
        with pytest.raises(ValueError, match=message):
            gym.make("dexstack/Stack-v0", **{"render_mode": "rgb_array", **kwargs})
        with pytest.raises(ValueError, match=message):
            dexstack.VectorEnv(2, task="stack", **{"render_mode": "rgb_array", **kwargs})
    with pytest.raises(ValueError, match="'rgb_array' only"):
        dexstack.VectorEnv(2, task="stack", render_mode="human")
    if not renderer.display_available():
        with pytest.raises(dexstack.RendererUnavailable, match="needs a display.*rgb_array"):
            gym.make("dexstack/Stack-v0", render_mode="human")
    # The same process still makes and draws environments.
    env = gym.make("dexstack/Stack-v0", render_mode="rgb_array", camera="side", **SMALL)
    env.reset(seed=1)
    assert env.render().shape == (64, 64, 3)
    env.close()


def test_render_before_reset_then_usable():
    for env in [dexstack.JacoEnv(task="grasp", render_mode="rgb_array", **SMALL),
                gym.make("dexstack/Grasp-v0", render_mode="rgb_array", **SMALL),
                dexstack.VectorEnv(2, task="grasp", render_mode="rgb_array", **SMALL)]:
        with pytest.raises(gym.error.ResetNeeded, match="before"):
            env.render()
        env.reset(seed=2)
        frames = env.render()
        env.step(np.zeros(env.action_space.shape, np.float32))
        assert np.asarray(frames).shape[-3:] == (64, 64, 3)
        env.close()


CHILD = textwrap.dedent("""
    import sys, numpy as np
    mode = sys.argv[1]
    if mode == "no-wheel":
        sys.modules["mujoco"] = None                  # the wheel is not installed
    elif mode == "old-wheel":
        import mujoco
        mujoco.__version__ = "3.0.0"                  # another version of the wheel
    import gymnasium as gym, dexstack
    env = gym.make("dexstack/Stack-v0", render_mode="rgb_array", width=32, height=32)
    env.reset(seed=0)
    for _ in range(2):                                # the same clear error each time, no crash
        try:
            env.render()
            print("rendered")
        except dexstack.RendererUnavailable as e:
            assert isinstance(e, RuntimeError) and isinstance(e, gym.error.DependencyNotInstalled)
            print("error:", e)
    obs, *_ = env.step(np.zeros(9, np.float32))       # the environment is still usable
    env.close()
    print("stepped", obs.shape)
""")


@pytest.mark.parametrize("mode,environment,message", [
    ("no-egl-driver", {"MUJOCO_GL": "egl", "__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent/50_mesa.json"},
     r"cannot create an OpenGL context with MUJOCO_GL=egl .*apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri"),
    ("bad-backend", {"MUJOCO_GL": "vulkan"}, r"does not import with MUJOCO_GL=vulkan .*must be egl, osmesa or glfw"),
    ("no-wheel", {}, r"needs the `mujoco` package, which is not installed: pip install mujoco==3\.17\.0"),
    ("old-wheel", {}, r"needs the `mujoco` package 3\.17\.0, .*found 3\.0\.0"),
])
def test_missing_renderer_pieces_raise_clearly(mode, environment, message):
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    run = subprocess.run([sys.executable, "-c", CHILD, mode], capture_output=True, text=True, timeout=120,
                         env={**env, **environment})
    assert run.returncode == 0, run.stdout + run.stderr
    errors = re.findall(r"^error: (.*)$", run.stdout, re.M)
    assert len(errors) == 2 and errors[0] == errors[1], run.stdout
    assert re.search(message, errors[0]), errors[0]
    assert "stepped (44,)" in run.stdout


def test_no_render_mode_costs_nothing():
    """Without a render mode nothing of the renderer is imported or made and no state is copied."""
    child = textwrap.dedent("""
        import sys, warnings, numpy as np, gymnasium as gym, dexstack
        calls = []
        class Spy:
            def __init__(self, core): self.core = core
            def __getattr__(self, name):
                calls.append(name)
                return getattr(self.core, name)
        env = gym.make("dexstack/Stack-v0")
        env.unwrapped._core = Spy(env.unwrapped._core)
        env.reset(seed=0)
        for _ in range(3):
            env.step(np.zeros(9, np.float32))
        with warnings.catch_warnings(record=True):
            warnings.simplefilter("always")
            assert env.render() is None
        vec = dexstack.VectorEnv(2, task="stack")
        vec._core = Spy(vec._core)
        vec.reset(seed=0)
        vec.step(np.zeros((2, 9), np.float32))
        env.close(); vec.close()
        assert "render_state" not in calls and {"reset", "step"} <= set(calls), calls
        assert env.unwrapped._renderer is None and vec._renderer is None
        assert "mujoco" not in sys.modules and "OpenGL" not in sys.modules, "rendering modules imported"
        print("ok")
    """)
    run = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "ok", run.stdout + run.stderr


def test_pins_match_the_mujoco_the_environments_link():
    wanted = dexstack.renderer.MUJOCO_VERSION
    setup = (ROOT / "scripts" / "setup-mujoco.sh").read_text()
    assert re.search(rf"^MUJOCO_VERSION={re.escape(wanted)}$", setup, re.M)
    requirements = (ROOT / "tests" / "requirements.txt").read_text()
    assert re.search(rf"^mujoco=={re.escape(wanted)}$", requirements, re.M)
    for package in ("imageio-ffmpeg", "moviepy", "pillow"):
        assert re.search(rf"^{package}==\S+$", requirements, re.M), package
