"""Pictures of MuJoCo models by MuJoCo's offscreen OpenGL renderer (what :mod:`jaxrl_robot.video` draws with).

:func:`render_frames` draws a model in each frame's ``qpos`` (and mocap poses) from a free camera on the
model's centre (25° above it), with a reaching env's goal as a blue sphere; :func:`mujoco_model` finds an env's
``MjModel``.  OpenGL: ``$MUJOCO_GL`` picks the backend (``egl``, ``osmesa`` or ``glfw``); unset, EGL when
``libEGL`` is found, else OSMesa (:func:`gl_backend`).  A backend that cannot start is a :class:`RenderError`
naming the library and its Debian package.
"""

from __future__ import annotations

import contextlib
import ctypes.util
import importlib
import os
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np
from brax.envs.base import Env

__all__ = ["GL_LIBRARIES", "RenderError", "gl_backend", "gl_context", "mujoco_model", "render_frames"]

GL_LIBRARIES = {"egl": ("libEGL", "libegl1"), "osmesa": ("libOSMesa", "libosmesa6"), "glfw": ("GLFW", "libglfw3")}
"""``MUJOCO_GL`` backend → (the library it needs, its Debian/Ubuntu package)."""

GOAL_RGBA = np.array([0.1, 0.35, 0.95, 0.45], np.float32)
"""Colour of the goal marker (blue, translucent: the end effector shows inside it)."""


class RenderError(RuntimeError):
    """A video cannot be made here (no OpenGL library, no MP4 writer, an env without a model to draw); one line."""


def mujoco_model(env: Env) -> Any:
    """The ``mujoco.MjModel`` of ``env`` or of an env it wraps (``mj_model``, brax's ``sys.mj_model``); None if none."""
    seen = set()
    while env is not None and id(env) not in seen:
        seen.add(id(env))
        for owner in (env, getattr(env, "sys", None)):
            model = getattr(owner, "mj_model", None)
            if model is not None:
                return model
        env = getattr(env, "env", None) or getattr(env, "_env", None)
    return None


def gl_backend() -> str:
    """The OpenGL backend to render with: ``$MUJOCO_GL`` (``egl``, ``osmesa`` or ``glfw``); unset, ``egl`` when
    ``libEGL`` is found, else ``osmesa`` when ``libOSMesa`` is.

    Raises:
      RenderError: ``$MUJOCO_GL`` names another backend, or unset and neither library is found.
    """
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if chosen:
        if chosen not in GL_LIBRARIES:
            raise RenderError(f"MUJOCO_GL={chosen!r} cannot render offscreen; valid: {', '.join(GL_LIBRARIES)}")
        return chosen
    if ctypes.util.find_library("EGL"):
        return "egl"
    if ctypes.util.find_library("OSMesa"):
        return "osmesa"
    raise RenderError(
        "cannot render: no OpenGL library for offscreen rendering found; install libEGL (Debian/Ubuntu: "
        "apt-get install libegl1) or libOSMesa (apt-get install libosmesa6, with MUJOCO_GL=osmesa)"
    )


@contextlib.contextmanager
def gl_context(width: int, height: int) -> Iterator[str]:
    """A current OpenGL context of :func:`gl_backend` while the block runs; yields the backend's name.

    Raises:
      RenderError: the backend cannot start (its library is missing or unusable), naming the library and package.
    """
    backend = gl_backend()
    try:
        context = importlib.import_module(f"mujoco.{backend}").GLContext(width, height)
        context.make_current()
    except Exception as e:  # ImportError, OSError, RuntimeError or PyOpenGL's errors: all mean no usable GL
        library, package = GL_LIBRARIES[backend]
        cause = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise RenderError(
            f"cannot render with MUJOCO_GL={backend}: {library} is missing or unusable ({cause}); "
            f"Debian/Ubuntu: apt-get install {package}"
        ) from None
    try:
        yield backend
    finally:
        context.free()


def render_frames(
    model: Any,
    frames: Sequence[dict[str, Any]] | Iterator[dict[str, Any]],
    width: int,
    height: int,
    goal_radius: float = 0.03,
) -> list[np.ndarray]:
    """``[height, width, 3]`` uint8 pictures of ``model`` in each frame's ``qpos`` (and mocap poses), with a
    sphere of ``goal_radius`` (m) at the frame's ``goal`` if it has one.

    Raises:
      RenderError: no OpenGL (:func:`gl_backend`), or a ``qpos`` that is not the model's.
    """
    import mujoco

    with gl_context(width, height):
        model = _with_offscreen_size(model, width, height)
        data = mujoco.MjData(model)
        context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        try:
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, context)
            scene, option, camera = mujoco.MjvScene(model, maxgeom=10_000), mujoco.MjvOption(), mujoco.MjvCamera()
            mujoco.mjv_defaultFreeCamera(model, camera)  # on the model's centre, 1.5 extents away
            camera.elevation = -25.0  # MuJoCo's -45 looks down so steeply that what is high leaves the frame
            rect = mujoco.MjrRect(0, 0, width, height)
            pixels = np.empty((height, width, 3), np.uint8)
            out = []
            for frame in frames:
                qpos = np.asarray(frame["qpos"]) if frame.get("qpos") is not None else None
                if qpos is None or qpos.shape != (model.nq,):
                    shape = None if qpos is None else qpos.shape
                    raise RenderError(f"cannot render: the env's state has qpos {shape}, its model {model.nq} values")
                data.qpos[:] = qpos
                if "mocap_pos" in frame:
                    data.mocap_pos[:], data.mocap_quat[:] = frame["mocap_pos"], frame["mocap_quat"]
                mujoco.mj_forward(model, data)
                mujoco.mjv_updateScene(model, data, option, None, camera, mujoco.mjtCatBit.mjCAT_ALL, scene)
                if "goal" in frame and scene.ngeom < scene.maxgeom:
                    goal = np.asarray(frame["goal"], np.float64)
                    size = np.array([goal_radius, 0.0, 0.0])
                    mujoco.mjv_initGeom(scene.geoms[scene.ngeom], mujoco.mjtGeom.mjGEOM_SPHERE, size, goal,
                                        np.eye(3).ravel(), GOAL_RGBA)  # fmt: skip
                    scene.ngeom += 1
                mujoco.mjr_render(rect, scene, context)
                mujoco.mjr_readPixels(pixels, None, rect, context)
                out.append(np.flipud(pixels).copy())
        finally:
            context.free()
    return out


def _with_offscreen_size(model: Any, width: int, height: int) -> Any:
    """``model``, or a copy whose offscreen buffer holds ``width × height`` (the model itself is not changed)."""
    import copy

    size = model.vis.global_
    if size.offwidth >= width and size.offheight >= height:
        return model
    model = copy.deepcopy(model)
    model.vis.global_.offwidth = max(size.offwidth, width)
    model.vis.global_.offheight = max(size.offheight, height)
    return model
