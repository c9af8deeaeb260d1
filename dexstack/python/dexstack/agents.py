"""The scripted demonstrator and policy files, from Python."""

from __future__ import annotations

import os
from typing import Optional, Union

import numpy as np

from . import _core
from .envs import ACT_DIM, OBS_DIM, JacoEnv, _task_name


def _core_env(env) -> "_core.Env":
    inner = getattr(env, "unwrapped", env)
    if not isinstance(inner, JacoEnv):
        raise TypeError(f"expected a dexstack JacoEnv (or a wrapper of one), not {type(inner).__name__}")
    return inner._core


class Demonstrator:
    """The scripted demonstrator of a task: ``act(env)`` gives the normalised action for the
    environment's current state (the Rust ``Demonstrator``, bit for bit).

    Args:
        task: ``reach``, ``grasp``, ``stack-in-hand`` or ``stack`` (or ``Reach``, ...).
        kind: ``scripted`` (a phase machine; restarts by itself at each new episode of the
            environment it acts on, taking over mid-task starts from their state) or ``markov``
            (the demonstrator whose action is a function of the state alone).
    """

    def __init__(self, task: str, kind: str = "scripted"):
        self._core = _core.Demonstrator(_task_name(task), kind)

    @property
    def task(self) -> str:
        """The task."""
        return self._core.task

    def act(self, env) -> np.ndarray:
        """The action (9 float32 in [-1, 1]) for ``env``'s current state (a ``JacoEnv`` or a wrapper)."""
        return np.frombuffer(self._core.act(_core_env(env)), dtype=np.float32).copy()

    def restart(self) -> None:
        """Back to the start of the script (happens by itself at each new episode)."""
        self._core.restart()


class Policy:
    """A ``.dxpl`` policy file run through the runtime's evaluator, as a controller runs it.

    Args:
        file: a path, or the file's bytes.
        can_quantisation: pass observations and commands through the CAN bus's quantisation, as
            ``trainer eval`` does by default.
        task: if given, the task the file must have been trained for (else ``ValueError``).

    The file is checked (format, CRC, the Jaco cell's observation and action layout) when loaded;
    an invalid one raises ``ValueError``. A loaded file stays in memory for the rest of the process
    (the evaluator borrows its weights): load a policy once.
    """

    def __init__(self, file: Union[str, os.PathLike, bytes], can_quantisation: bool = True,
                 task: Optional[str] = None):
        if isinstance(file, (bytes, bytearray, memoryview)):
            data = bytes(file)
            self.path = None
        else:
            self.path = os.fspath(file)
            with open(self.path, "rb") as f:
                data = f.read()
        self._core = _core.Policy(data)
        self._bytes = data
        self.can_quantisation = bool(can_quantisation)
        if task is not None and _task_name(task) != self._core.task:
            raise ValueError(f"the policy is a {self._core.task} policy, not a {_task_name(task)} one")

    @property
    def task(self) -> str:
        """The task the file was trained for."""
        return self._core.task

    def act(self, obs) -> np.ndarray:
        """The environment action (9 float32 in [-1, 1]) for one observation (44 values)."""
        try:
            o = np.asarray(obs)
        except (TypeError, ValueError) as e:
            raise ValueError(f"observation cannot be read as an array: {e}") from None
        if o.dtype.kind not in "fiu":
            raise ValueError(f"observation has dtype {o.dtype}; expected real numbers (float32)")
        if o.shape != (OBS_DIM,):
            raise ValueError(f"observation has shape {o.shape}, expected ({OBS_DIM},)")
        with np.errstate(over="ignore", invalid="ignore"):
            o32 = np.ascontiguousarray(o, dtype=np.float32)
        a = self._core.act(o32.tobytes(), self.can_quantisation)
        return np.frombuffer(a, dtype=np.float32).copy()

    def info(self) -> dict:
        """Header (version, flags, layout hash, CRC), layout (observation fields, action joints,
        layers), task and provenance of the file."""
        return self._core.info()

    @classmethod
    def from_onnx(cls, model: Union[str, os.PathLike, bytes], task: Optional[str] = None,
                  layout: Union[str, os.PathLike, bytes, None] = None,
                  can_quantisation: bool = True) -> "Policy":
        """A policy from an ONNX model of an MLP actor (what ``torch.onnx.export`` writes), as
        ``policy import`` makes it: Gemm/MatMul + Add layers with Relu or Tanh, input normalisation
        and output scaling folded in, anything else refused with a ``ValueError`` naming the node.

        Args:
            model: a path to a ``.onnx`` file, or its bytes.
            task: the task (``"grasp"``, ...); default: the layout file's, else the model's
                ``dexstack.task`` metadata.
            layout: a ``.dxpl`` file (path or bytes) whose layout to take instead of the cell's.
            can_quantisation: as for ``Policy``.

        A graph without output scaling gives actions in ``[-1, 1]``, the environments' action
        space (a Stable-Baselines3 actor's ``tanh`` output): the cell's joint scales apply.
        ``save`` writes the converted ``.dxpl`` for ``trainer eval`` and flashing.
        """
        data = _read_bytes(model)
        layout_data = None if layout is None else _read_bytes(layout)
        dxpl = _core.onnx_to_policy(data, None if task is None else _task_name(task), layout_data)
        return cls(dxpl, can_quantisation=can_quantisation, task=task)

    def to_onnx(self, path: Union[str, os.PathLike, None] = None) -> bytes:
        """The ONNX model of this policy (``policy export-onnx``): normalisation, layers, joint
        scaling and limits, opset 17; written to ``path`` when given. Its output is the joint
        command (``act`` times each joint's scale)."""
        onnx = _core.policy_to_onnx(self._bytes)
        if path is not None:
            with open(os.fspath(path), "wb") as f:
                f.write(onnx)
        return onnx

    def save(self, path: Union[str, os.PathLike]) -> None:
        """Writes the policy file (``.dxpl``) to ``path``."""
        with open(os.fspath(path), "wb") as f:
            f.write(self._bytes)

    def to_bytes(self) -> bytes:
        """The policy file's bytes."""
        return self._bytes


def _read_bytes(source) -> bytes:
    if isinstance(source, (bytes, bytearray, memoryview)):
        return bytes(source)
    with open(os.fspath(source), "rb") as f:
        return f.read()


__all__ = ["Demonstrator", "Policy", "ACT_DIM"]
