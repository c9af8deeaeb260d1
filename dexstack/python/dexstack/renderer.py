"""Drawing the Rust environments with MuJoCo's own renderer (the ``mujoco`` wheel).

The frames show the simulation the policy sees, not a re-simulation: the renderer loads the scene's
compiled model as Rust saved it (``_core.scene_mjb()``, MuJoCo's binary model file: the same
``MjModel``, every number included), copies an environment's MuJoCo state into its own ``MjData``
(``mj_setState`` with everything ``mj_step`` reads: time, positions, velocities, controls, mocap
poses, ...), calls ``mj_forward`` and draws. The only changes to the model are visual: brick 1 is
drawn red and brick 2 blue (the Duplo meshes are grey), and the shadow map is 1024 texels a side
(:data:`SHADOW_SIZE`; MuJoCo's 4096 costs a software rasteriser more than the rest of the frame).

Backends: ``MUJOCO_GL`` as MuJoCo reads it. Where it is not set and there is no display, this module
sets ``MUJOCO_GL=egl`` before importing ``mujoco`` (headless EGL; Mesa's llvmpipe software
rasteriser where there is no GPU: Debian ``libegl1 libegl-mesa0 libgl1-mesa-dri``);
``MUJOCO_GL=osmesa`` (``libosmesa6``) and ``glfw`` (a display) work too. A missing piece (the wheel,
its version, an OpenGL backend, a display for ``human``) raises :class:`RendererUnavailable` with
what to install; nothing is imported or created until the first frame is asked for.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading
import time
import weakref
from typing import Any, Optional

import gymnasium
import numpy as np

from . import _core

#: The MuJoCo version the environments link (``scripts/setup-mujoco.sh``); the ``mujoco`` wheel
#: must be the same (``tests/requirements.txt`` pins it).
MUJOCO_VERSION: str = _core.MUJOCO_VERSION
#: Frames per second of one frame per control step: 1 / 50 ms.
RENDER_FPS: int = round(1_000_000 / _core.CONTROL_PERIOD_US)
#: The default image size (pixels, square).
DEFAULT_SIZE = 480
#: The largest width or height accepted (an OpenGL framebuffer of 4096 x 4096 is 64 MiB).
MAX_IMAGE_SIZE = 4096
#: The default camera: the scene's own ``front`` camera (close on the bricks).
DEFAULT_CAMERA = "front"
#: Free cameras besides the scene's own: (look-at point, distance, azimuth, elevation) in the table
#: frame (metres, degrees); the arm base stands at (0, 0.4, 0).
FREE_CAMERAS = {
    "overview": ((0.0, 0.12, 0.12), 1.0, 135.0, -25.0),
    "side": ((0.0, 0.05, 0.1), 0.8, 180.0, -20.0),
    "top": ((0.0, 0.05, 0.0), 0.9, 90.0, -89.0),
}
#: The shadow map's size (texels a side) in the renderer's model (MuJoCo's default is 4096).
SHADOW_SIZE = 1024
#: Brick colours of the renderer's model (RGBA): brick 1 (the one picked up) red, brick 2 blue.
BRICK_COLOURS = {"brick1": (0.85, 0.15, 0.15, 1.0), "brick2": (0.15, 0.3, 0.85, 1.0)}

_EGL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri"
_INSTALL_WHEEL = (f"pip install mujoco=={MUJOCO_VERSION} (tests/requirements.txt pins it; "
                  "scripts/setup-python.sh installs it)")


class RenderError(gymnasium.error.Error, RuntimeError):
    """Rendering failed: a ``RuntimeError`` (and a Gymnasium error). The environment is unchanged."""


class RendererUnavailable(RenderError, gymnasium.error.DependencyNotInstalled):
    """A piece rendering needs is missing: the ``mujoco`` wheel (or another version of it), an
    OpenGL backend (EGL, OSMesa, GLFW), a video encoder, or a display for ``render_mode="human"``.
    The message says what to install."""


def display_available() -> bool:
    """Whether a display is there for a window (``DISPLAY`` or ``WAYLAND_DISPLAY`` set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def render_modes() -> list:
    """The render modes of this process: ``rgb_array``, and ``human`` where a display exists."""
    return ["rgb_array", "human"] if display_available() else ["rgb_array"]


def camera_names() -> list:
    """The cameras a renderer takes: the scene's own (``front``), then :data:`FREE_CAMERAS`."""
    return [n for n in _core.camera_names() if n] + list(FREE_CAMERAS)


def _check_size(name: str, value: Any) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer number of pixels, not {value!r}")
    if not 1 <= int(value) <= MAX_IMAGE_SIZE:
        raise ValueError(
            f"{name} = {int(value)} is out of range: images are 1 to {MAX_IMAGE_SIZE} pixels wide and high")
    return int(value)


def check_options(camera: Any = DEFAULT_CAMERA, width: Any = DEFAULT_SIZE, height: Any = DEFAULT_SIZE) -> dict:
    """Checks a camera name and an image size (``ValueError`` naming what is wrong); imports and
    creates nothing. Returns them as :class:`Renderer`'s keyword arguments."""
    names = camera_names()
    if not isinstance(camera, str) or camera not in names:
        raise ValueError(f"unknown camera {camera!r} (expected one of: {', '.join(names)})")
    return {"camera": camera, "width": _check_size("width", width), "height": _check_size("height", height)}


def check_render_mode(render_mode: Optional[str], vector: bool = False) -> Optional[str]:
    """``None`` or ``rgb_array``, or ``human`` where a display exists (single environments only);
    ``ValueError`` for anything else, :class:`RendererUnavailable` for ``human`` without a display."""
    if render_mode is None or render_mode == "rgb_array":
        return render_mode
    if render_mode == "human":
        if vector:
            raise ValueError(
                "the vector environment renders render_mode='rgb_array' only (render() gives one frame per "
                "environment); render one JacoEnv with render_mode='human' to watch it"
            )
        if not display_available():
            raise RendererUnavailable(
                "render_mode='human' needs a display, and neither DISPLAY nor WAYLAND_DISPLAY is set; use "
                "render_mode='rgb_array' (headless: EGL or OSMesa) or write a video with "
                "`python -m dexstack.render POLICY.dxpl --out video.mp4`"
            )
        return render_mode
    raise ValueError(f"render_mode {render_mode!r} is not supported (expected None, 'rgb_array' or 'human')")


# ---- the mujoco wheel, imported on the first frame --------------------------------------------

_MUJOCO: Any = None
_MUJOCO_ERROR: Optional[RenderError] = None
_MODEL: Any = None
_CONTEXT_ERROR: Optional[str] = None


def _backend() -> str:
    # What MuJoCo read when it was imported: MUJOCO_GL (set to egl by load_mujoco() where it was
    # unset and there is no display), else its default, GLFW.
    return os.environ.get("MUJOCO_GL", "").strip().lower() or "glfw"


def _backend_hint(backend: str) -> str:
    if backend == "egl":
        return (f"headless EGL needs Mesa's EGL and DRI drivers (Debian: apt-get install {_EGL_PACKAGES}; "
                "scripts/test.sh installs them), or set MUJOCO_GL=osmesa (libosmesa6), or MUJOCO_GL=glfw on a display")
    if backend == "osmesa":
        return "OSMesa needs Mesa's off-screen library (Debian: apt-get install libosmesa6), or set MUJOCO_GL=egl"
    if backend in ("glfw", "glx"):
        return ("GLFW needs a display (DISPLAY or WAYLAND_DISPLAY); headless, set MUJOCO_GL=egl before "
                f"`mujoco` is first imported (Debian: apt-get install {_EGL_PACKAGES})")
    return "MUJOCO_GL must be egl, osmesa or glfw"


def _import_failure(backend: str, e: BaseException) -> str:
    return (f"the `mujoco` package does not import with MUJOCO_GL={backend} ({type(e).__name__}: {e}); "
            f"{_backend_hint(backend)}")


def load_mujoco():
    """The ``mujoco`` module (version :data:`MUJOCO_VERSION`), imported once with the backend chosen
    (``MUJOCO_GL``, default ``egl`` without a display); :class:`RendererUnavailable` if it cannot be."""
    global _MUJOCO, _MUJOCO_ERROR
    if _MUJOCO is not None:
        return _MUJOCO
    if _MUJOCO_ERROR is not None:
        # The first failure again (a second import of a half-imported module fails differently),
        # as a new exception so tracebacks do not pile up.
        raise type(_MUJOCO_ERROR)(str(_MUJOCO_ERROR))
    if "mujoco" not in sys.modules and not os.environ.get("MUJOCO_GL") and not display_available():
        os.environ["MUJOCO_GL"] = "egl"
    backend = _backend()
    try:
        import mujoco  # noqa: PLC0415 - imported on the first frame only
    except ImportError as e:
        if isinstance(e, ModuleNotFoundError) and e.name == "mujoco":
            _MUJOCO_ERROR = RendererUnavailable(
                f"rendering needs the `mujoco` package, which is not installed: {_INSTALL_WHEEL}")
        else:
            _MUJOCO_ERROR = RendererUnavailable(_import_failure(backend, e))
        raise _MUJOCO_ERROR from e
    except Exception as e:  # noqa: BLE001 - MuJoCo's GL set-up raises RuntimeError, AttributeError, ...
        _MUJOCO_ERROR = RendererUnavailable(_import_failure(backend, e))
        raise _MUJOCO_ERROR from e
    found = getattr(mujoco, "__version__", "unknown")
    if found != MUJOCO_VERSION:
        _MUJOCO_ERROR = RendererUnavailable(
            f"rendering needs the `mujoco` package {MUJOCO_VERSION}, the version the environments link; "
            f"found {found}: {_INSTALL_WHEEL}")
        raise _MUJOCO_ERROR
    _MUJOCO = mujoco
    return mujoco


def scene_model():
    """The scene's ``MjModel`` in the ``mujoco`` wheel: Rust's compiled model, loaded from its MJB
    bytes (once per process), bricks coloured."""
    global _MODEL
    mujoco = load_mujoco()
    if _MODEL is None:
        name = "dexstack-scene.mjb"
        try:
            model = mujoco.MjModel.from_binary_path(name, {name: _core.scene_mjb()})
        except Exception as e:  # noqa: BLE001 - mujoco raises ValueError for a bad or foreign MJB
            raise RenderError(f"the `mujoco` package cannot load the scene's binary model: {e}") from e
        if mujoco.mj_stateSize(model, _core.STATE_SPEC) <= 0:
            raise RenderError("the scene's binary model has no state to copy")
        # Software rasterisers pay for every texel of the shadow map: MuJoCo's default 4096 x 4096
        # costs ~80 ms a frame on llvmpipe (dev-2c), 1024 x 1024 looks the same at these sizes.
        model.vis.quality.shadowsize = min(int(model.vis.quality.shadowsize), SHADOW_SIZE)
        for body, rgba in BRICK_COLOURS.items():
            bid = model.body(body).id
            for g in range(model.ngeom):
                if model.geom_bodyid[g] == bid and model.geom_group[g] == 0:
                    model.geom_rgba[g] = rgba
                    model.geom_matid[g] = -1
        _MODEL = model
    return _MODEL


def _close_at_exit(obj) -> Any:
    """Registers ``obj.close()`` to run at interpreter exit, through a weak reference (``obj`` may
    be collected before). Registered after the OpenGL set-up registered its own exit hooks (EGL's
    ``eglTerminate``, GLFW's), it runs before them: a context left open is freed while it still
    can be, instead of printing tracebacks from the garbage collector. Returns the hook, for
    ``atexit.unregister``."""
    ref = weakref.ref(obj)

    def hook() -> None:
        o = ref()
        if o is not None:
            try:
                o.close()
            except Exception:  # noqa: BLE001 - the process is ending
                pass

    atexit.register(hook)
    return hook


class Renderer:
    """MuJoCo's offscreen renderer over the scene: one OpenGL context, one ``MjData``; draws the
    state of any environment of this process.

    Args:
        camera: a name of :func:`camera_names` (``front``, ``overview``, ``side``, ``top``).
        width, height: image size in pixels, 1 to :data:`MAX_IMAGE_SIZE`.

    Raises :class:`RendererUnavailable` when the ``mujoco`` wheel or an OpenGL backend is missing,
    ``ValueError`` for a bad camera or size. Use from the thread that made it.
    """

    def __init__(self, camera: str = DEFAULT_CAMERA, width: int = DEFAULT_SIZE, height: int = DEFAULT_SIZE):
        options = check_options(camera, width, height)
        self.camera, self.width, self.height = options["camera"], options["width"], options["height"]
        self._renderer = None
        mujoco = load_mujoco()
        model = scene_model()
        self._mujoco, self._model = mujoco, model
        self._state_size = int(mujoco.mj_stateSize(model, _core.STATE_SPEC))
        # The offscreen buffer is made with the OpenGL context below, from these two numbers: the
        # image's size exactly (the scene asks for 640 x 480; a software rasteriser pays for every
        # pixel of the buffer, drawn or not). Visual only; the physics is untouched.
        model.vis.global_.offwidth = self.width
        model.vis.global_.offheight = self.height
        self._data = mujoco.MjData(model)
        global _CONTEXT_ERROR
        if _CONTEXT_ERROR is not None:
            # A failed EGL/OSMesa/GLFW set-up leaves MuJoCo's GL module half initialised: a second
            # try fails differently. Say the first reason again.
            raise RendererUnavailable(_CONTEXT_ERROR)
        backend = _backend()
        try:
            self._renderer = mujoco.Renderer(model, height=self.height, width=self.width)
        except Exception as e:  # noqa: BLE001 - ImportError (EGL), FatalError (GLFW), GLError, ...
            _CONTEXT_ERROR = (f"cannot create an OpenGL context with MUJOCO_GL={backend} ({type(e).__name__}: "
                              f"{e}); {_backend_hint(backend)}")
            raise RendererUnavailable(_CONTEXT_ERROR) from e
        if self.camera in FREE_CAMERAS:
            lookat, distance, azimuth, elevation = FREE_CAMERAS[self.camera]
            cam = mujoco.MjvCamera()
            cam.type = mujoco.mjtCamera.mjCAMERA_FREE
            cam.lookat[:] = lookat
            cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
            self._camera: Any = cam
        else:
            self._camera = self.camera
        self._exit_hook = _close_at_exit(self)

    def set_state(self, state: bytes) -> None:
        """Copies an environment's MuJoCo state (``_core`` ``render_state()`` bytes) into the
        renderer's ``MjData`` and runs ``mj_forward``."""
        values = np.frombuffer(state, dtype=np.float64)
        if values.size != self._state_size:
            raise RenderError(f"a state of {values.size} values for a model whose state has {self._state_size}")
        mujoco = self._mujoco
        mujoco.mj_setState(self._model, self._data, values, _core.STATE_SPEC)
        mujoco.mj_forward(self._model, self._data)

    @property
    def data(self):
        """The renderer's ``MjData`` (the state last copied in)."""
        return self._data

    def draw(self, state: bytes) -> np.ndarray:
        """The frame of a state: ``(height, width, 3)`` uint8, a new array."""
        if self._renderer is None:
            raise RenderError("the renderer is closed")
        self.set_state(state)
        self._renderer.update_scene(self._data, camera=self._camera)
        return self._renderer.render()

    def close(self) -> None:
        """Frees the OpenGL context (idempotent)."""
        r, self._renderer = getattr(self, "_renderer", None), None
        if r is not None:
            r.close()
        hook, self._exit_hook = getattr(self, "_exit_hook", None), None
        if hook is not None:
            atexit.unregister(hook)

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - nothing to report to at collection time
            pass


class Viewer:
    """``render_mode="human"``: MuJoCo's passive viewer window over the scene, showing each state
    given to :meth:`show`, paced at :data:`RENDER_FPS` (real time)."""

    def __init__(self):
        if not display_available():
            raise RendererUnavailable("render_mode='human' needs a display (DISPLAY or WAYLAND_DISPLAY)")
        mujoco = load_mujoco()
        model = scene_model()
        try:
            import mujoco.viewer  # noqa: PLC0415
        except Exception as e:  # noqa: BLE001
            raise RendererUnavailable(
                f"MuJoCo's viewer does not import ({type(e).__name__}: {e}); it needs glfw and a display") from e
        self._mujoco, self._model = mujoco, model
        self._data = mujoco.MjData(model)
        before = set(threading.enumerate())
        try:
            self._handle = mujoco.viewer.launch_passive(model, self._data, show_left_ui=False, show_right_ui=False)
        except Exception as e:  # noqa: BLE001
            raise RendererUnavailable(f"cannot open MuJoCo's viewer window ({type(e).__name__}: {e})") from e
        # The viewer draws on a thread of its own; close() waits for it (a window still swapping
        # buffers while the process exits makes X errors).
        self._threads = [t for t in threading.enumerate() if t not in before]
        # After the viewer's own exit hooks, so before them: an open window at interpreter exit is
        # closed and its thread joined before GLFW goes.
        self._exit_hook = _close_at_exit(self)
        self._last = 0.0

    def show(self, state: bytes) -> None:
        """Shows a state (``render_state()`` bytes); waits so that frames come at most at the
        control rate."""
        handle = self._handle
        if handle is None or not handle.is_running():
            return
        values = np.frombuffer(state, dtype=np.float64)
        with handle.lock():
            self._mujoco.mj_setState(self._model, self._data, values, _core.STATE_SPEC)
            self._mujoco.mj_forward(self._model, self._data)
        handle.sync()
        wait = self._last + 1.0 / RENDER_FPS - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        self._last = time.monotonic()

    def close(self) -> None:
        """Closes the window (idempotent)."""
        h, self._handle = getattr(self, "_handle", None), None
        if h is not None:
            h.close()
            for t in self._threads:
                t.join(timeout=5)
        hook, self._exit_hook = getattr(self, "_exit_hook", None), None
        if hook is not None:
            atexit.unregister(hook)


__all__ = [
    "MUJOCO_VERSION", "RENDER_FPS", "DEFAULT_SIZE", "MAX_IMAGE_SIZE", "DEFAULT_CAMERA", "FREE_CAMERAS",
    "RenderError", "RendererUnavailable", "Renderer", "Viewer", "camera_names", "check_options",
    "check_render_mode", "display_available", "load_mujoco", "render_modes", "scene_model",
]
