"""The Jaco stacking tasks of dexterous-stack as Gymnasium environments.

Importing the package registers four Gymnasium 1.x ids::

    dexstack/Reach-v0  dexstack/Grasp-v0  dexstack/StackInHand-v0  dexstack/Stack-v0

``gymnasium.make(id, reward=..., start=..., episode_steps=..., in_hand_probability=...)`` gives a
:class:`JacoEnv`; ``gymnasium.make_vec(id, num_envs=N)`` a :class:`VectorEnv` (N environments
stepped on Rust threads with the GIL released). The simulation is the Rust ``JacoEnv`` itself
(MuJoCo 3.17.0), so the same seed and the same actions give the same bits as in Rust.
:class:`Demonstrator` is the scripted demonstrator, :class:`Policy` a ``.dxpl`` policy file run
through the runtime's evaluator. ``render_mode="rgb_array"`` (or ``"human"`` on a display) draws
the environment's own MuJoCo state with MuJoCo's renderer (:mod:`dexstack.renderer`);
``python -m dexstack.render POLICY.dxpl`` writes a video of a policy file. See docs/python.md.
"""

from __future__ import annotations

import gymnasium

import numpy as np

from . import _core
from ._core import episode_seed, reward_names
from ._core import task_features as _task_features
from .envs import TASKS, InvalidAction, JacoEnv, VectorEnv
from .agents import Demonstrator, Policy
from .renderer import RenderError, RendererUnavailable

__all__ = [
    "TASKS",
    "JacoEnv",
    "VectorEnv",
    "InvalidAction",
    "Demonstrator",
    "Policy",
    "RenderError",
    "RendererUnavailable",
    "episode_seed",
    "reward_names",
    "task_features",
    "TASK_FEATURE_FIELDS",
    "register_envs",
]

__version__ = "0.1.0"


#: The controller's task features, in order: (name, size).
TASK_FEATURE_FIELDS = tuple(_core.task_feature_fields())  # before `del _core` below


def task_features(obs) -> np.ndarray:
    """The controller's task features of one observation (44 values): 14 float32 values, the
    runtime's own computation (``runtime/src/features.rs``). A policy file that takes them
    (``trainer imitate --features``) sees them after the observation; its ONNX export takes the
    58 values ``np.concatenate([obs, task_features(obs)])``."""
    o = np.ascontiguousarray(obs, dtype=np.float32)
    if o.shape != (44,):
        raise ValueError(f"an observation is 44 values, got shape {o.shape}")
    return np.frombuffer(_task_features(o.tobytes()), dtype=np.float32).copy()


def register_envs() -> None:
    """Registers ``dexstack/<Task>-v0`` for the four tasks (done on import; idempotent)."""
    for name, task in TASKS.items():
        env_id = f"dexstack/{name}-v0"
        if env_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=env_id,
            # A function, not the class: see `envs.make_env` (render_mode="human" without a display).
            entry_point="dexstack.envs:make_env",
            vector_entry_point="dexstack.envs:VectorEnv",
            kwargs={"task": task},
            # The environment truncates at its own time limit (the `episode_steps` option), so no
            # TimeLimit wrapper is added, and it is deterministic given the seed.
            max_episode_steps=None,
            nondeterministic=False,
        )


register_envs()
del _core
