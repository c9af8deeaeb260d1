"""Gymnasium environments over the Rust ``JacoEnv`` (``dexstack._core``)."""

from __future__ import annotations

from typing import Any, Optional, Sequence, Union

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from . import _core
from . import renderer as _renderer

#: The Gymnasium id stem of each task and the task name the Rust side takes.
TASKS = {
    "Reach": "reach",
    "Grasp": "grasp",
    "StackInHand": "stack-in-hand",
    "Stack": "stack",
}

OBS_DIM = _core.OBS_DIM
ACT_DIM = _core.ACT_DIM
_U64 = 2**64


class InvalidAction(gymnasium.error.InvalidAction, ValueError):
    """An action of the wrong shape or dtype, or with a NaN or infinite component.

    A ``ValueError`` and Gymnasium's ``InvalidAction``; the environment is left as it was.
    """


def _observation_space() -> spaces.Box:
    low, high = [], []
    for _name, size, lo, hi in _core.observation_fields():
        low += [lo] * size
        high += [hi] * size
    return spaces.Box(
        low=np.array(low, dtype=np.float32),
        high=np.array(high, dtype=np.float32),
        dtype=np.float32,
    )


def _action_space() -> spaces.Box:
    return spaces.Box(low=-1.0, high=1.0, shape=(ACT_DIM,), dtype=np.float32)


def _task_name(task: str) -> str:
    """Accepts the Rust name (``stack-in-hand``) or the id stem (``StackInHand``)."""
    if not isinstance(task, str):
        raise ValueError(f"task must be a string, not {type(task).__name__}")
    return TASKS.get(task, task)


def _as_actions(action: Any, shape: tuple) -> bytes:
    """float32 bytes of an action batch, or ``InvalidAction`` for a wrong shape, dtype or value."""
    try:
        a = np.asarray(action)
    except (TypeError, ValueError) as e:
        raise InvalidAction(f"action cannot be read as an array: {e}") from None
    if a.dtype.kind not in "fiu":
        raise InvalidAction(
            f"action has dtype {a.dtype}; expected real numbers (float32, or any float or integer type)"
        )
    if a.shape != shape:
        raise InvalidAction(f"action has shape {a.shape}, expected {shape}")
    with np.errstate(over="ignore", invalid="ignore"):
        a32 = np.ascontiguousarray(a, dtype=np.float32)
    bad = ~np.isfinite(a32)
    if bad.any():
        flat = int(np.flatnonzero(bad.reshape(-1))[0])
        index = np.unravel_index(flat, shape)
        value = a.reshape(-1)[flat]
        raise InvalidAction(
            f"action{list(int(i) for i in index)} = {value} is not finite (as float32); actions must "
            "be finite (values outside [-1, 1] are clipped)"
        )
    return a32.tobytes()


def _requested_seed(options: Optional[dict]) -> Optional[int]:
    """The ``episode_seed`` reset option, checked (``None`` when not given)."""
    if not options:
        return None
    unknown = set(options) - {"episode_seed"}
    if unknown:
        raise ValueError(f"unknown reset option(s) {sorted(unknown)}; the only one is 'episode_seed'")
    return _check_seed(options.get("episode_seed"))


def _check_seed(s: Any) -> Optional[int]:
    if s is None:
        return None
    if isinstance(s, (bool, np.bool_)) or not isinstance(s, (int, np.integer)) or not 0 <= int(s) < _U64:
        raise ValueError(f"episode_seed must be an integer in [0, 2**64), not {s!r}")
    return int(s)


def _draw_seed(rng: np.random.Generator) -> int:
    """An episode's 64-bit seed, drawn from the environment's generator."""
    return int(rng.integers(0, _U64, dtype=np.uint64))


_RENDER_BEFORE_RESET = "render() before reset(): there is no state to draw yet; call reset() first"


def _predicates(success: bool, reach: bool, grasp: bool, stack: bool) -> dict:
    return {"success": bool(success), "reach": bool(reach), "grasp": bool(grasp), "stack": bool(stack)}


class JacoEnv(gymnasium.Env):
    """One Jaco task: a Kinova Jaco arm, two Duplo bricks, MuJoCo 3.17.0 (the Rust ``JacoEnv``).

    Args:
        task: ``reach``, ``grasp``, ``stack-in-hand`` or ``stack`` (or ``Reach``, ``StackInHand``, ...).
        reward: a reward name (``dexstack.reward_names()``: ``full-composite``, ``sparse-stack``,
            ``reach-shaping``, ...); default the task's own sparse reward.
        start: ``original`` (the task's start states), ``mixture`` (the in-hand start with
            probability ``in_hand_probability``) or ``along-demonstrations`` (states along the
            scripted demonstrator's episodes, the paper's instructive starts).
        episode_steps: control steps (50 ms each) before ``truncated``; default 150 (Reach 50), 50
            under ``along-demonstrations``.
        in_hand_probability: the in-hand share under ``mixture``.
        render_mode: ``None`` (no rendering: no renderer is made, no state copied), ``rgb_array``
            (``render()`` returns the frame, ``(height, width, 3)`` uint8, drawn by MuJoCo's offscreen
            renderer from this environment's own MuJoCo state) or ``human`` (a MuJoCo viewer window
            paced at 20 frames/s; where a display exists, else ``RendererUnavailable``).
        camera: ``front`` (the scene's camera, close on the bricks), ``overview``, ``side`` or ``top``
            (``dexstack.renderer.camera_names()``).
        width, height: the image size in pixels (1 to 4096; default 480 x 480).

    Observations are 44 float32 (``dex_runtime::interface``), actions 9 float32 in [-1, 1]
    (clipped, then scaled to the joints' velocity commands). ``terminated`` is always False,
    ``truncated`` is True at the time limit; ``info`` holds ``success`` and the ``reach``,
    ``grasp`` and ``stack`` predicates (at reset also ``episode_seed`` and ``start``).

    Seeding: ``reset(seed=s)`` seeds ``self.np_random`` (Gymnasium's rules); each reset draws the
    episode's 64-bit seed from it, and the Rust start state comes from that seed alone
    (``reset(options={"episode_seed": k})`` gives the start of ``JacoEnv::reset(k)`` directly).

    Rendering (docs/python.md): ``render()`` before ``reset()`` raises ``gymnasium.error.ResetNeeded``;
    a missing ``mujoco`` wheel or OpenGL backend ``dexstack.RendererUnavailable`` (at the first
    ``render()``); the environment stays usable either way. ``close()`` frees the renderer.
    """

    metadata = {"render_modes": _renderer.render_modes(), "render_fps": _renderer.RENDER_FPS}

    def __init__(
        self,
        task: str = "reach",
        reward: Optional[str] = None,
        start: str = "original",
        episode_steps: Optional[int] = None,
        in_hand_probability: float = 0.5,
        render_mode: Optional[str] = None,
        camera: str = _renderer.DEFAULT_CAMERA,
        width: int = _renderer.DEFAULT_SIZE,
        height: int = _renderer.DEFAULT_SIZE,
    ):
        # Checked before anything is made; nothing of the renderer is imported or created here.
        self.render_mode = _renderer.check_render_mode(render_mode)
        self._render_options = _renderer.check_options(camera, width, height)
        self._renderer: Optional[_renderer.Renderer] = None
        self._viewer: Optional[_renderer.Viewer] = None
        if episode_steps is not None and (
            isinstance(episode_steps, bool) or not isinstance(episode_steps, (int, np.integer)) or episode_steps < 1
        ):
            raise ValueError(f"episode_steps must be a positive integer, not {episode_steps!r}")
        self._core = _core.Env(
            _task_name(task), reward, start, None if episode_steps is None else int(episode_steps),
            float(in_hand_probability),
        )
        self.observation_space = _observation_space()
        self.action_space = _action_space()
        self._running = False
        self._reset_once = False

    @property
    def task(self) -> str:
        """The task (``reach``, ``grasp``, ``stack-in-hand``, ``stack``)."""
        return self._core.task

    @property
    def reward_name(self) -> str:
        """The reward function's name."""
        return self._core.reward

    @property
    def episode_steps(self) -> int:
        """The time limit, in control steps."""
        return self._core.episode_steps

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        """Starts an episode; see the class documentation for the seeding."""
        requested = _requested_seed(options)  # checked before anything changes
        super().reset(seed=seed)
        episode_seed = _draw_seed(self.np_random) if requested is None else requested
        self._running = False
        obs, start, success, reach, grasp, stack = self._core.reset(episode_seed)
        self._running = True
        self._reset_once = True
        info = {"episode_seed": np.uint64(episode_seed), **start, **_predicates(success, reach, grasp, stack)}
        return np.frombuffer(obs, dtype=np.float32).copy(), info

    def step(self, action):
        """One 50 ms control step."""
        if not self._running:
            raise gymnasium.error.ResetNeeded(
                "the episode has ended (truncated at the time limit): call reset()"
                if self._reset_once
                else "step() before reset(): call reset() first"
            )
        data = _as_actions(action, (ACT_DIM,))
        try:
            obs, reward, truncated, success, reach, grasp, stack = self._core.step(data)
        except RuntimeError:
            self._running = False
            raise
        if truncated:
            self._running = False
        return (
            np.frombuffer(obs, dtype=np.float32).copy(),
            float(reward),
            False,
            bool(truncated),
            _predicates(success, reach, grasp, stack),
        )

    @property
    def steps_taken(self) -> int:
        """Control steps taken in the current episode."""
        return self._core.steps_taken

    def render(self):
        """The current state drawn by MuJoCo's renderer: an ``(height, width, 3)`` uint8 frame
        (``rgb_array``), or ``None`` after showing it in the viewer window (``human``). Without a
        render mode: a warning and ``None``. Works after the time limit too (the last state)."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() without a render mode: make the environment with render_mode='rgb_array', e.g. "
                'gymnasium.make("dexstack/Stack-v0", render_mode="rgb_array")'
            )
            return None
        if not self._reset_once:
            raise gymnasium.error.ResetNeeded(_RENDER_BEFORE_RESET)
        if self.render_mode == "human":
            if self._viewer is None:
                self._viewer = _renderer.Viewer()
            self._viewer.show(self._core.render_state())
            return None
        if self._renderer is None:
            self._renderer = _renderer.Renderer(**self._render_options)
        return self._renderer.draw(self._core.render_state())

    def close(self):
        """Frees the renderer or closes the viewer window, if any (the environment itself needs no
        closing)."""
        r, self._renderer = self._renderer, None
        v, self._viewer = self._viewer, None
        if r is not None:
            r.close()
        if v is not None:
            v.close()
        super().close()


def make_env(**kwargs) -> JacoEnv:
    """The registered ids' entry point: ``JacoEnv(**kwargs)``.

    A function rather than the class so that ``gymnasium.make(id, render_mode="human")`` reaches
    :class:`JacoEnv` (a clear error without a display) instead of Gymnasium swapping in its pygame
    ``HumanRendering`` wrapper for a mode the class's ``metadata`` does not list."""
    return JacoEnv(**kwargs)


class VectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` Jaco environments stepped on Rust threads with the GIL released.

    The options are :class:`JacoEnv`'s, plus ``threads`` (0: one per core, at most ``num_envs``).
    Semantics are Gymnasium 1.x's ``SyncVectorEnv`` over ``num_envs`` :class:`JacoEnv`\\ s, bit for
    bit: ``reset(seed=s)`` seeds environment ``i`` with ``s + i`` (or takes a list of seeds), and
    autoreset is ``AutoresetMode.NEXT_STEP`` (the step after an episode ends resets that
    environment, ignores its action and returns reward 0, ``truncated`` False and the reset info).
    Infos are batched the Gymnasium way (``info["success"]`` with the mask ``info["_success"]``).

    ``render_mode="rgb_array"`` (with ``camera``, ``width``, ``height`` as for :class:`JacoEnv`):
    ``render()`` returns a tuple of ``num_envs`` frames, environment ``i``'s state drawn by one
    shared renderer, Gymnasium's vector convention (``SyncVectorEnv.render``).
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": _renderer.RENDER_FPS,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        task: str = "reach",
        reward: Optional[str] = None,
        start: str = "original",
        episode_steps: Optional[int] = None,
        in_hand_probability: float = 0.5,
        threads: int = 0,
        render_mode: Optional[str] = None,
        camera: str = _renderer.DEFAULT_CAMERA,
        width: int = _renderer.DEFAULT_SIZE,
        height: int = _renderer.DEFAULT_SIZE,
    ):
        self.render_mode = _renderer.check_render_mode(render_mode, vector=True)
        self._render_options = _renderer.check_options(camera, width, height)
        self._renderer: Optional[_renderer.Renderer] = None
        self._reset_once = False
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, not {num_envs!r}")
        if episode_steps is not None and (
            isinstance(episode_steps, bool) or not isinstance(episode_steps, (int, np.integer)) or episode_steps < 1
        ):
            raise ValueError(f"episode_steps must be a positive integer, not {episode_steps!r}")
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 0:
            raise ValueError(f"threads must be a non-negative integer, not {threads!r}")
        self._core = _core.VecEnv(
            int(num_envs), _task_name(task), reward, start,
            None if episode_steps is None else int(episode_steps), float(in_hand_probability), int(threads),
        )
        self.num_envs = int(num_envs)
        self.single_observation_space = _observation_space()
        self.single_action_space = _action_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs: list = [None] * self.num_envs
        self._running = np.zeros(self.num_envs, dtype=bool)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._zeros = np.zeros((self.num_envs, ACT_DIM), dtype=np.float32).tobytes()

    @property
    def threads(self) -> int:
        """Threads a step uses."""
        return self._core.threads

    def _draw(self, i: int) -> int:
        if self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random(None)
        return _draw_seed(self._rngs[i])

    def reset(
        self,
        *,
        seed: Union[int, Sequence[Optional[int]], None] = None,
        options: Optional[dict] = None,
    ):
        """Resets every environment (seeds as ``SyncVectorEnv``: ``s + i`` or a list)."""
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
        episode = None
        if options:
            unknown = set(options) - {"episode_seed"}
            if unknown:
                raise ValueError(f"unknown reset option(s) {sorted(unknown)}; the only one is 'episode_seed'")
            if options.get("episode_seed") is not None:
                episode = [_check_seed(e) for e in options["episode_seed"]]
                if len(episode) != self.num_envs:
                    raise ValueError(f"{len(episode)} episode seeds for {self.num_envs} environments")
        new_rngs = list(self._rngs)
        for i, s in enumerate(seeds):
            if s is not None:
                new_rngs[i], _ = seeding.np_random(s)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
        self._rngs = new_rngs
        episode_seeds = [self._draw(i) if episode is None or episode[i] is None else episode[i]
                         for i in range(self.num_envs)]
        self._running[:] = False
        (obs, _, _, success, reach, grasp, stack), starts = self._core.step(self._zeros, episode_seeds)
        self._running[:] = True
        self._autoreset[:] = False
        self._reset_once = True
        infos: dict = {}
        for i in range(self.num_envs):
            info = {"episode_seed": np.uint64(episode_seeds[i]), **starts[i],
                    **_predicates(success[i], reach[i], grasp[i], stack[i])}
            infos = self._add_info(infos, info, i)
        return np.frombuffer(obs, dtype=np.float32).reshape(self.num_envs, OBS_DIM).copy(), infos

    def step(self, actions):
        """One control step of every environment (a reset for those whose episode just ended)."""
        if not (self._running | self._autoreset).all():
            raise gymnasium.error.ResetNeeded("step() before reset() (or after a failed step): call reset() first")
        data = _as_actions(actions, (self.num_envs, ACT_DIM))
        resets = np.flatnonzero(self._autoreset)
        seeds: list = [None] * self.num_envs
        for i in resets:
            seeds[i] = self._draw(int(i))
        try:
            (obs, rewards, truncated, success, reach, grasp, stack), starts = self._core.step(data, seeds)
        except RuntimeError:
            self._running[:] = False
            self._autoreset[:] = False
            raise
        truncated = np.array(truncated, dtype=bool)
        infos: dict = {}
        for i in range(self.num_envs):
            info = _predicates(success[i], reach[i], grasp[i], stack[i])
            if seeds[i] is not None:
                info = {"episode_seed": np.uint64(seeds[i]), **starts[i], **info}
            infos = self._add_info(infos, info, i)
        self._autoreset = truncated.copy()
        self._running = ~truncated
        return (
            np.frombuffer(obs, dtype=np.float32).reshape(self.num_envs, OBS_DIM).copy(),
            np.frombuffer(rewards, dtype=np.float32).astype(np.float64),
            np.zeros(self.num_envs, dtype=bool),
            truncated,
            infos,
        )

    def render(self):
        """One frame per environment (``rgb_array``): a tuple of ``num_envs`` ``(height, width, 3)``
        uint8 arrays. Without a render mode: a warning and ``None``."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() without a render mode: make the vector environment with render_mode='rgb_array'")
            return None
        if not self._reset_once:
            raise gymnasium.error.ResetNeeded(_RENDER_BEFORE_RESET)
        if self._renderer is None:
            self._renderer = _renderer.Renderer(**self._render_options)
        return tuple(self._renderer.draw(self._core.render_state(i)) for i in range(self.num_envs))

    def close_extras(self, **kwargs):
        """Frees the renderer, if any."""
        r, self._renderer = self._renderer, None
        if r is not None:
            r.close()
