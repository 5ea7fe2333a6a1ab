"""Videos of test episodes: ``episode_video(path, env, policy, keys)`` writes a GIF or an MP4.

MuJoCo-based envs (``envs_mjx``'s arm7, scara and unicycle, brax's MJX envs, Playground's) are drawn by
MuJoCo's offscreen OpenGL renderer from each step's physics state: the ``qpos`` (and mocap poses) of the
state's ``pipeline_state`` (``data`` for a Playground state) are put into a ``mujoco.MjData`` of the env's
``mj_model`` and rendered from a free camera on the model's centre (25° above it); a reaching env's goal
(``info["goal"]``, ``[3]``) is drawn as a blue sphere of the env's goal threshold (``config.goal_threshold``,
else 3 cm).
``racecar``, which has no MuJoCo model, is drawn with its chase view (:func:`envs_mjx.demo.chase_view`).

OpenGL: ``$MUJOCO_GL`` picks the backend (``egl``: EGL, GPUs and Mesa's software EGL; ``osmesa``: OSMesa,
CPUs; ``glfw``: a window system); unset, EGL when ``libEGL`` is found, else OSMesa.  A backend that cannot
start is a :class:`RenderError` naming the library and its Debian package (``libegl1``, ``libosmesa6``).
The drawing is :mod:`jaxrl_robot.rendering`'s (re-exported here).
GIFs are written with Pillow (installed with matplotlib), MP4s with ``imageio`` and ``imageio-ffmpeg`` (the
``video`` extra: ``pip install 'jaxrl-robot[video]'``).
"""

from __future__ import annotations

import importlib
import math
import os
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env

from jaxrl_robot.evaluation import freeze
from jaxrl_robot.rendering import GL_LIBRARIES, RenderError, gl_backend, gl_context, mujoco_model, render_frames
from jaxrl_robot.types import Policy, RecurrentPolicy, as_recurrent

__all__ = [
    "GL_LIBRARIES",
    "VIDEO_FORMATS",
    "RenderError",
    "check_rendering",
    "check_video_path",
    "episode_snapshots",
    "episode_video",
    "gl_backend",
    "mujoco_model",
    "record_episodes",
    "render_frames",
    "write_video",
]

VIDEO_FORMATS = (".gif", ".mp4")
"""File suffixes :func:`write_video` writes."""

MAX_FPS = 50.0
"""Frames per second a video plays at most by default (GIF's frame times are whole hundredths of a second)."""


def check_video_path(path: str) -> str:
    """``path``'s format, ``".gif"`` or ``".mp4"``, once it can be written here.

    Raises:
      ValueError: another suffix (the message names the valid ones).
      RenderError: ``.mp4`` without ``imageio`` / ``imageio-ffmpeg`` (the message names the extra).
    """
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in VIDEO_FORMATS:
        valid = ", ".join(VIDEO_FORMATS)
        raise ValueError(f"video file {path!r}: unknown format {suffix or '(none)'!r}; valid: {valid}")
    if suffix == ".mp4":
        try:
            importlib.import_module("imageio")
            importlib.import_module("imageio_ffmpeg")
        except ImportError:
            raise RenderError(
                f"video file {path!r}: MP4 needs imageio and imageio-ffmpeg, the 'video' extra "
                "(pip install 'jaxrl-robot[video]'); or write a .gif"
            ) from None
    return suffix


# ---- recording the episodes -------------------------------------------------------------------------------


def _physics(state: Any) -> Any:
    """The physics state of an env state: brax's ``pipeline_state``, or a Playground state's ``data``."""
    physics = getattr(state, "pipeline_state", None)
    return getattr(state, "data", None) if physics is None else physics


def _snapshot(state: Any, nmocap: int) -> dict[str, jax.Array]:
    """What a frame is drawn from: ``qpos``, the mocap poses (if the model has mocap bodies) and the goal."""
    physics = _physics(state)
    qpos = getattr(physics, "qpos", None)
    out = {"qpos": getattr(physics, "q", None) if qpos is None else qpos}
    if nmocap:
        out.update(mocap_pos=physics.mocap_pos, mocap_quat=physics.mocap_quat)
    goal = state.info.get("goal") if isinstance(state.info, dict) else None
    if goal is not None and jnp.shape(goal) == (3,):
        out["goal"] = goal
    return out


def _is_tracking(env: Env) -> bool:
    """Tracking envs (``scara``, ``unicycle``) expose ``axis_names`` and ``wrap_axes``: their test episode starts
    at ``t = 0`` of the reference (``envs_mjx.tracking.eval_params``)."""
    return hasattr(env, "axis_names") and hasattr(env, "wrap_axes")


def record_episodes(
    env: Env,
    policy: Policy | RecurrentPolicy,
    keys: jax.Array,
    snapshot: Callable[[Any], dict[str, jax.Array]],
    episode_length: int = 0,
) -> tuple[dict[str, jax.Array], dict[str, jax.Array], jax.Array]:
    """``E`` episodes of an unbatched env with a deterministic policy, keeping ``snapshot(state)`` of each step.

    Pure and jittable (``env``, ``policy``, ``snapshot`` and the length static).  Episode ``i`` resets with
    ``keys[i]`` (a tracking env's test episode starts at ``t = 0`` of its reference whatever the key) and
    runs until its first ``done`` or the step limit; finished episodes keep their last state.

    Args:
      keys: ``[E, 2]`` reset keys.
      snapshot: ``state -> dict`` of arrays, applied to every (unbatched) state.
      episode_length: step limit (0: ``env.max_steps`` of a tracking env, else ``env.episode_length``).
    Returns:
      ``(first, steps, live)``: ``snapshot`` of the start ``[E, ...]``, of every step ``[T, E, ...]``, and
      ``live [T, E]`` (1 for the steps of the episode, the one that ends it included).
    """
    reset = env.reset
    limit = episode_length
    if _is_tracking(env):
        from envs_mjx import tracking

        reset = lambda k: env.reset(k, tracking.eval_params())  # noqa: E731
        limit = limit or env.max_steps
    limit = int(limit or env.episode_length)
    n = keys.shape[0]
    state = jax.vmap(reset)(keys)
    policy = as_recurrent(policy)
    memory = jax.tree.map(lambda c: jnp.broadcast_to(c, (n,) + jnp.shape(c)), policy.carry)

    def body(carry: tuple, _: None) -> tuple[tuple, tuple]:
        s, memory, finished = carry
        memory, action = policy.step(memory, s.obs)
        live = 1.0 - finished
        ns = freeze(live, s, jax.vmap(env.step)(s, action))
        finished = jnp.maximum(finished, live * ns.done.astype(jnp.float32))
        return (ns, memory, finished), (jax.vmap(snapshot)(ns), live)

    _, (steps, live) = jax.lax.scan(body, (state, memory, jnp.zeros((n,), jnp.float32)), None, length=limit)
    return jax.vmap(snapshot)(state), steps, live


def episode_snapshots(first: dict[str, Any], steps: dict[str, Any], live: Any) -> list[list[dict[str, Any]]]:
    """Per episode, the snapshots of its frames in order (host arrays): its start, then its live steps."""
    live = np.asarray(live)
    out = []
    for i in range(live.shape[1]):
        out.append([{k: np.asarray(v[i]) for k, v in first.items()}])
        out[-1] += [{k: np.asarray(v[t, i]) for k, v in steps.items()} for t in np.flatnonzero(live[:, i] > 0)]
    return out


def _every(items: list, stride: int) -> list:
    """Every ``stride``-th item, the last one always included."""
    picked = items[::stride]
    return picked + items[-1:] if (len(items) - 1) % stride else picked


def check_rendering(env: Env) -> None:
    """Check that :func:`episode_video` can draw ``env`` here (before any episode is run).

    Raises:
      RenderError: ``env`` has no MuJoCo model (and is not ``racecar``), or no OpenGL context starts
        (naming the library and its package).
    """
    from envs_mjx.racecar import RaceCar

    if isinstance(env, RaceCar):
        return
    if mujoco_model(env) is None:
        raise RenderError(f"cannot render {type(env).__name__}: it has no MuJoCo model (mj_model)")
    with gl_context(16, 16):
        pass


# ---- racecar: the chase view ---------------------------------------------------------------------------------


def _race_frames(env: Env, policy: Policy, keys: jax.Array, width: int, stride: int) -> list[list[np.ndarray]]:
    """Per key, the ``[width, width, 3]`` chase views (:func:`envs_mjx.demo.chase_view`) of a lap on the env's road."""
    import matplotlib.pyplot as plt

    from envs_mjx import demo

    rollout = jax.jit(demo.make_race_rollout(env, 1, act=lambda e, s: policy(s.obs)))
    out = []
    for key in keys:
        _, rec = rollout(jnp.asarray(key))  # one lane: the lap of this key
        r = {k: np.asarray(v)[:, 0] for k, v in rec.items()}
        steps = max(int(r["live"].sum()), 1)
        fig, draw = demo.chase_view(env, r, steps, size=width / 100)
        out.append([])
        try:
            for k in _every(list(range(steps)), stride):
                draw(k)
                fig.canvas.draw()
                out[-1].append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
        finally:
            plt.close(fig)
    return out


# ---- writing ---------------------------------------------------------------------------------------------------


def write_video(path: str, frames: Sequence[np.ndarray], fps: float, colors: int = 128) -> None:
    """Write ``frames`` (``[H, W, 3]`` uint8 each) as a GIF (Pillow; one palette of ``colors`` for every frame,
    so that Pillow stores only what changes) or an MP4 (imageio-ffmpeg, H.264) at ``fps`` frames per second.

    Raises:
      ValueError, RenderError: as :func:`check_video_path`; no frames.
      OSError: the file cannot be written.
    """
    suffix = check_video_path(path)
    if not frames:
        raise ValueError(f"video file {path!r}: no frames to write")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if suffix == ".gif":
        from PIL import Image

        pictures = [Image.fromarray(f) for f in frames]
        sample = frames[:: max(len(frames) // 16, 1)]  # the palette of frames from the whole video
        palette = Image.fromarray(np.concatenate(sample, axis=0)).quantize(colors=colors, dither=Image.Dither.NONE)
        pictures = [p.quantize(palette=palette, dither=Image.Dither.NONE) for p in pictures]
        duration = max(int(round(1000 / fps)), 20)  # ms; GIF viewers slow down anything shorter than 20
        pictures[0].save(path, save_all=True, append_images=pictures[1:], duration=duration, loop=0)
        return
    import imageio.v2 as imageio

    with warnings.catch_warnings():  # JAX warns of any fork; ffmpeg's process runs no JAX
        warnings.filterwarnings("ignore", message=r"os\.fork\(\) was called", category=RuntimeWarning)
        with imageio.get_writer(path, format="FFMPEG", mode="I", fps=fps, codec="libx264", macro_block_size=2) as w:
            for f in frames:
                w.append_data(f)


def episode_video(
    path: str,
    env: Env,
    policy: Policy | RecurrentPolicy,
    keys: jax.Array,
    width: int = 320,
    height: int = 240,
    stride: int | None = None,
    episode_length: int = 0,
    hold_s: float = 0.5,
) -> int:
    """Write a video (GIF or MP4 by ``path``'s suffix) of one episode per key, played at the env's speed.

    Args:
      path: ``*.gif`` or ``*.mp4``.
      env: the unbatched env (MuJoCo-based, or ``racecar``).
      policy: the deterministic policy, ``obs [E, D] -> action [E, A]`` or a recurrent one.
      keys: ``[E, 2]`` reset keys, one episode each (racecar: one lap each on the env's road).
      width, height: pixels (racecar: square frames of ``width``).
      stride: draw every ``stride``-th step (the video plays ``stride`` times fewer frames per second); None:
        the smallest that plays at most :data:`MAX_FPS` frames per second (1 for arm7's 20 control steps a second).
      episode_length: step limit (0: the env's).
      hold_s: seconds the last frame of each episode is held.
    Returns:
      The number of frames written.
    Raises:
      ValueError: a bad suffix or size; RenderError: no OpenGL, no MP4 writer or nothing to draw the env with.
    """
    check_video_path(path)
    dt = float(getattr(env, "dt", None) or getattr(getattr(env, "config", None), "dt", None) or 0.05)
    stride = max(1, math.ceil(1.0 / dt / MAX_FPS - 1e-9)) if stride is None else stride
    if width < 16 or height < 16 or stride < 1:
        raise ValueError(f"video size {width}x{height} and stride {stride}: allowed >= 16 pixels, stride >= 1")
    fps = 1.0 / dt / stride
    from envs_mjx.racecar import RaceCar

    if isinstance(env, RaceCar):
        if isinstance(policy, RecurrentPolicy):
            raise RenderError("racecar videos take a memoryless policy; this one is recurrent")
        episodes = _race_frames(env, policy, keys, width, stride)
    else:
        check_rendering(env)
        model = mujoco_model(env)
        snapshot = lambda s: _snapshot(s, model.nmocap)  # noqa: E731
        first, steps, live = jax.device_get(jax.jit(
            lambda k: record_episodes(env, policy, k, snapshot, episode_length)
        )(keys))  # fmt: skip
        chosen = [_every(snaps, stride) for snaps in episode_snapshots(first, steps, live)]
        radius = float(getattr(getattr(env, "config", None), "goal_threshold", 0.03))
        pictures = iter(render_frames(model, [s for snaps in chosen for s in snaps], width, height, radius))
        episodes = [[next(pictures) for _ in snaps] for snaps in chosen]
    hold = int(round(hold_s * fps))
    frames = [f for pictures in episodes for f in pictures + pictures[-1:] * hold]
    write_video(path, frames, fps)
    return len(frames)
