"""Videos of policy files: what a policy does, episode by episode, as MP4 and GIF.

    python -m dexstack.render POLICY.dxpl --episodes 4 --seed 1000000 --out stack.mp4
    python -m dexstack.render POLICY.dxpl --failures 3 --search 200 --out failures.mp4
    python -m dexstack.render A.dxpl B.dxpl --episodes 2 --out a-vs-b.mp4      # side by side

Episode ``i`` starts from ``dexstack.episode_seed(seed, i)``, exactly as in ``trainer eval --seed
seed`` (default 1,000,000), and the policy runs through the runtime's evaluator with the CAN bus's
quantisation as ``trainer eval`` does (``--no-can-quantisation`` to skip it), on the task's own
reward and episode length: the return and success printed for an episode are ``trainer eval``'s
for that start. Each frame is the Rust environment's own MuJoCo state drawn by
:class:`dexstack.renderer.Renderer`, with the file, episode, step, return and success written on it.

``--failures N`` first runs episodes ``first .. first + search - 1`` without drawing, then draws the
first ``N`` that fail (with two files: that either fails). Two files side by side run from the same
starts, each in its own environment, one frame beside the other (an f32 file and its int8 twin, a
cloned and a fine-tuned policy, ...).

The output: ``--out PATH`` with its suffix replaced by each of ``--formats`` (default ``mp4,gif``).
Per episode, the frames are the start and every ``every``-th step after it (and always the last
step), then ``hold`` seconds of the last frame; the videos play at ``20 / every`` frames per
second, real time. MP4 needs ``imageio-ffmpeg``, the text and GIF need Pillow (both pinned in
tests/requirements.txt).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np

from . import _core
from .agents import Policy
from .envs import JacoEnv
from .renderer import (DEFAULT_CAMERA, DEFAULT_SIZE, RENDER_FPS, Renderer, RenderError, RendererUnavailable,
                       camera_names, check_options)

#: ``trainer eval``'s default start seed (``dex_env::seeds::EVAL_SEED``).
EVAL_SEED: int = _core.EVAL_SEED
FORMATS = ("mp4", "gif")


@dataclass
class Run:
    """One policy's episode: its start, return (sum of the rewards, as ``trainer eval`` adds them),
    success (the task's predicate at the last step) and steps."""

    label: str
    index: int
    seed: int
    ret: float = 0.0
    success: bool = False
    steps: int = 0


@dataclass
class Episode:
    """One episode of every policy (one or two) from the same start, and its frames."""

    index: int
    seed: int
    runs: List[Run]
    frames: List[np.ndarray] = field(default_factory=list)

    @property
    def success(self) -> bool:
        """Whether every policy succeeded."""
        return all(r.success for r in self.runs)


def kept_steps(steps: int, every: int) -> List[int]:
    """The steps drawn in an episode of ``steps`` steps: 0 (the start), every ``every``-th, and the last."""
    kept = list(range(0, steps + 1, every))
    if kept[-1] != steps:
        kept.append(steps)
    return kept


def frames_per_episode(steps: int, every: int, hold_frames: int = 0) -> int:
    """How many frames an episode of ``steps`` steps gives."""
    return len(kept_steps(steps, every)) + hold_frames


# ---- text on the frames (Pillow) ---------------------------------------------------------------

_FONTS: dict = {}


def _pillow():
    try:
        from PIL import Image, ImageDraw, ImageFont  # noqa: PLC0415
    except ImportError as e:
        raise RendererUnavailable("the text on the frames and GIF files need Pillow: pip install pillow "
                                  "(tests/requirements.txt pins it)") from e
    return Image, ImageDraw, ImageFont


def _font(size: int):
    if size not in _FONTS:
        _, _, ImageFont = _pillow()
        try:
            _FONTS[size] = ImageFont.load_default(size=size)
        except TypeError:  # Pillow < 10.1: a fixed bitmap font
            _FONTS[size] = ImageFont.load_default()
    return _FONTS[size]


GREEN, RED, WHITE = (90, 220, 110), (240, 90, 80), (240, 240, 240)


def annotate(frame: np.ndarray, top: str, bottom: str, colour=WHITE) -> np.ndarray:
    """``frame`` with ``top`` and ``bottom`` written on dark bands (``bottom`` in ``colour``)."""
    Image, ImageDraw, _ = _pillow()
    h, w = frame.shape[:2]
    size = max(8, min(h, w) // 22)
    band = size + max(2, size // 3)
    out = frame.copy()
    out[:band] = (out[:band] * 0.35).astype(np.uint8)
    out[h - band:] = (out[h - band:] * 0.35).astype(np.uint8)
    image = Image.fromarray(out)
    draw = ImageDraw.Draw(image)
    font = _font(size)
    pad = max(1, size // 6)
    draw.text((pad + 1, pad), top, fill=WHITE, font=font)
    draw.text((pad + 1, h - band + pad), bottom, fill=colour, font=font)
    return np.asarray(image)


def _label(run: Run, t: int, steps: int, success_now: bool, final: bool):
    top = f"{run.label}  ep {run.index}  step {t}/{steps}"
    if final:
        verdict = "SUCCESS" if run.success else "FAILURE"
        return top, f"return {run.ret:.2f}  {verdict}", GREEN if run.success else RED
    return top, f"return {run.ret:.2f}  success {'yes' if success_now else 'no'}", GREEN if success_now else WHITE


# ---- episodes ----------------------------------------------------------------------------------


def run_episode(policies: Sequence[Policy], labels: Sequence[str], index: int, seed: int,
                renderer: Optional[Renderer] = None, every: int = 1, hold_frames: int = 0,
                task: Optional[str] = None) -> Episode:
    """Episode ``index`` (start seed ``seed``) of each policy, each in its own environment; frames
    (side by side for two policies) when a ``renderer`` is given, else none (and no state copied)."""
    task = task or policies[0].task
    envs = [JacoEnv(task=task) for _ in policies]
    runs = [Run(label, index, seed) for label in labels]
    obs = [env.reset(options={"episode_seed": seed})[0] for env in envs]
    success_now = [False] * len(envs)
    steps = envs[0].episode_steps
    ep = Episode(index, seed, runs)
    keep = set(kept_steps(steps, every)) if renderer is not None else set()

    def draw(t: int) -> None:
        final = t == steps
        panels = []
        for env, run, ok in zip(envs, runs, success_now):
            top, bottom, colour = _label(run, t, steps, ok, final)
            panels.append(annotate(renderer.draw(env._core.render_state()), top, bottom, colour))
        if len(panels) > 1:
            divider = np.full((panels[0].shape[0], 2, 3), 255, np.uint8)
            frame = np.concatenate([panels[0], divider, *panels[1:]], axis=1)
        else:
            frame = panels[0]
        ep.frames.append(frame)

    if 0 in keep:
        draw(0)
    truncated = False
    t = 0
    while not truncated:
        t += 1
        for k, (env, policy, run) in enumerate(zip(envs, policies, runs)):
            obs[k], reward, _, truncated, info = env.step(policy.act(obs[k]))
            run.ret += float(reward)
            run.steps = t
            success_now[k] = info["success"]
            run.success = info["success"]  # the predicate at the last step is the episode's
        if t in keep:
            draw(t)
    if ep.frames:
        ep.frames.extend([ep.frames[-1]] * hold_frames)
    return ep


# ---- writers -----------------------------------------------------------------------------------


def _even(frame: np.ndarray) -> np.ndarray:
    h, w = frame.shape[:2]
    if h % 2 or w % 2:
        frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
    return np.ascontiguousarray(frame)


def write_mp4(path: Path, frames: Sequence[np.ndarray], fps: float) -> None:
    """H.264 MP4 (yuv420p, so any player takes it; an odd width or height gets one edge pixel)."""
    try:
        import imageio_ffmpeg  # noqa: PLC0415
    except ImportError as e:
        raise RendererUnavailable("writing MP4 needs imageio-ffmpeg (its ffmpeg binary): pip install "
                                  "imageio-ffmpeg (tests/requirements.txt pins it), or --formats gif") from e
    first = _even(frames[0])
    h, w = first.shape[:2]
    writer = imageio_ffmpeg.write_frames(str(path), (w, h), fps=fps, codec="libx264", pix_fmt_in="rgb24",
                                         pix_fmt_out="yuv420p", macro_block_size=1, quality=None,
                                         output_params=["-crf", "23"], ffmpeg_log_level="error")
    writer.send(None)
    try:
        for f in frames:
            writer.send(_even(f).tobytes())
    finally:
        writer.close()


def write_gif(path: Path, frames: Sequence[np.ndarray], fps: float) -> None:
    """An endlessly looping GIF with one palette for every frame (no flicker; small deltas)."""
    Image, _, _ = _pillow()
    sample = frames[:: max(1, len(frames) // 8)][:8]
    palette = Image.fromarray(np.concatenate(sample, axis=0)).quantize(colors=128, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=max(20, round(1000 / fps)),
                   loop=0, optimize=False)


# ---- the command -------------------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m dexstack.render",
        description="Video (MP4 and GIF) of a policy file's episodes, from trainer eval's starts; "
                    "two files side by side.",
    )
    p.add_argument("policies", nargs="+", metavar="POLICY.dxpl", help="one policy file, or two side by side")
    p.add_argument("--task", help="the task (default: the policy's own; another is refused, as by trainer eval)")
    p.add_argument("--episodes", type=int, default=1, help="episodes to draw (default 1)")
    p.add_argument("--seed", type=int, default=EVAL_SEED,
                   help=f"start seed, as trainer eval --seed (default {EVAL_SEED})")
    p.add_argument("--first", type=int, default=0, help="index of the first episode (default 0)")
    p.add_argument("--failures", type=int, metavar="N",
                   help="draw the first N failing episodes among --search episodes from --first instead")
    p.add_argument("--search", type=int, default=100, help="episodes searched for --failures (default 100)")
    p.add_argument("--out", help="output path; its suffix is replaced by each format (default: POLICY's stem)")
    p.add_argument("--formats", default="mp4,gif", help="comma-separated: mp4, gif (default mp4,gif)")
    p.add_argument("--camera", default=DEFAULT_CAMERA,
                   help=f"one of {', '.join(camera_names())} (default {DEFAULT_CAMERA})")
    p.add_argument("--size", type=int, help=f"width and height in pixels (default {DEFAULT_SIZE})")
    p.add_argument("--width", type=int, help="image width (default --size)")
    p.add_argument("--height", type=int, help="image height (default --size)")
    p.add_argument("--every", type=int, default=1, help="draw every K-th step (default 1: all 20 per second)")
    p.add_argument("--hold", type=float, default=0.0, help="seconds the last frame of an episode stays (default 0)")
    p.add_argument("--labels", help="comma-separated names written on the frames (default: the file names)")
    p.add_argument("--no-can-quantisation", action="store_true",
                   help="skip the CAN quantisation of observations and commands (trainer eval --no-can-quantisation)")
    return p


def _fail(parser: argparse.ArgumentParser, message: str) -> None:
    parser.error(message)


def main(argv: Optional[Sequence[str]] = None) -> int:
    """The command line; returns the exit status (0, or 1 after an error it explains)."""
    parser = _parser()
    a = parser.parse_args(argv)
    if len(a.policies) > 2:
        _fail(parser, "one policy file, or two side by side")
    formats = [f.strip().lower() for f in a.formats.split(",") if f.strip()]
    if not formats or any(f not in FORMATS for f in formats):
        _fail(parser, f"--formats takes mp4 and/or gif, not {a.formats!r}")
    for name in ("episodes", "every", "search"):
        if getattr(a, name) < 1:
            _fail(parser, f"--{name} must be at least 1")
    if a.failures is not None and a.failures < 1:
        _fail(parser, "--failures must be at least 1")
    if a.first < 0 or not 0 <= a.seed < 2**64:
        _fail(parser, "--first must be >= 0 and --seed in [0, 2**64)")
    if a.hold < 0 or not math.isfinite(a.hold):
        _fail(parser, "--hold must be a non-negative number of seconds")
    size = DEFAULT_SIZE if a.size is None else a.size
    try:
        options = check_options(a.camera, size if a.width is None else a.width, size if a.height is None else a.height)
    except ValueError as e:
        _fail(parser, str(e))
    labels = [s.strip() for s in a.labels.split(",")] if a.labels else [Path(p).name for p in a.policies]
    if len(labels) != len(a.policies):
        _fail(parser, f"--labels names {len(labels)} files for {len(a.policies)}")
    out = Path(a.out) if a.out else Path(Path(a.policies[0]).stem)
    try:
        return _run(a, options, labels, formats, out)
    except (RenderError, ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1


def _run(a, options: dict, labels: List[str], formats: List[str], out: Path) -> int:
    policies = [Policy(p, can_quantisation=not a.no_can_quantisation, task=a.task) for p in a.policies]
    task = policies[0].task
    if any(p.task != task for p in policies):
        raise ValueError(f"the files are for different tasks ({', '.join(p.task for p in policies)})")
    fps = RENDER_FPS / a.every
    hold_frames = round(a.hold * fps)

    def describe(ep: Episode) -> None:
        for run in ep.runs:
            who = f" [{run.label}]" if len(ep.runs) > 1 else ""
            print(f"episode {run.index}{who} return {run.ret:.4f} success {str(run.success).lower()} "
                  f"seed {run.seed} steps {run.steps}")

    if a.failures is not None:
        indices = []
        for i in range(a.first, a.first + a.search):
            ep = run_episode(policies, labels, i, _core.episode_seed(a.seed, i), task=task)
            if not ep.success:
                indices.append(i)
                if len(indices) == a.failures:
                    break
        searched = (indices[-1] - a.first + 1) if len(indices) == a.failures else a.search
        print(f"{len(indices)} failing episode(s) among {searched} searched from episode {a.first}: {indices}")
        if not indices:
            print("nothing to draw")
            return 0
    else:
        indices = list(range(a.first, a.first + a.episodes))

    renderer = Renderer(**options)
    frames: List[np.ndarray] = []
    try:
        for i in indices:
            ep = run_episode(policies, labels, i, _core.episode_seed(a.seed, i), renderer=renderer,
                             every=a.every, hold_frames=hold_frames, task=task)
            describe(ep)
            frames.extend(ep.frames)
    finally:
        renderer.close()
    out.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    for fmt in formats:
        path = out.with_suffix("." + fmt)
        (write_mp4 if fmt == "mp4" else write_gif)(path, frames, fps)
        print(f"wrote {path} ({len(frames)} frames, {w}x{h}, {fps:g} frames/s, {os.path.getsize(path)} bytes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
