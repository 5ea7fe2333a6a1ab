"""Videos of test episodes (``jaxrl_robot.video``): arm7 rendered by MuJoCo's offscreen renderer to a GIF
whose frames move and are not blank; the OpenGL errors name the library and its package."""

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image, ImageSequence

import envs_mjx
from jaxrl_robot import video


def test_arm7_episodes_render_to_a_gif_that_moves(tmp_path):
    env = envs_mjx.make("arm7", mode="kinematic")
    try:
        video.check_rendering(env)
    except video.RenderError as e:  # only this test needs OpenGL
        pytest.skip(f"no OpenGL for MuJoCo's offscreen renderer here: {e}")
    path = str(tmp_path / "arm7.gif")

    def policy(obs):  # toward the goal: arm7 observes (end effector, goal) positions
        return jnp.clip(8.0 * (obs[..., 3:6] - obs[..., :3]), -1.0, 1.0)

    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    count = video.episode_video(path, env, policy, keys, width=48, height=32, episode_length=3, hold_s=0.1)
    assert count == 2 * (1 + 3 + 2)  # per episode: its start, 3 steps (none reaches its goal), held 2 frames
    gif = Image.open(path)
    assert gif.size == (48, 32) and gif.info["duration"] == 50  # arm7's control period, 0.05 s
    frames = [np.asarray(f.convert("RGB"), np.float32) for f in ImageSequence.Iterator(gif)]
    assert len(frames) >= 4  # Pillow merges the held frames into one
    for f in frames:  # a scene, not a blank or uniform picture
        assert f.std() > 10.0
    changes = [np.abs(a - b).mean() for a, b in zip(frames, frames[1:], strict=False)]
    assert sum(c > 0.5 for c in changes) >= 3  # the arm moves from frame to frame, and the episodes differ
    # the goal marker: the same pose drawn with and without a goal in view differs
    pose = {"qpos": np.zeros(env.mj_model.nq)}
    bare, marked = video.render_frames(env.mj_model, [pose, {**pose, "goal": np.array([0.4, 0.0, 0.8])}], 64, 48, 0.05)
    assert bare.shape == (48, 64, 3) and bare.dtype == np.uint8
    assert (np.abs(bare.astype(int) - marked).sum(axis=-1) > 30).sum() >= 4


def test_gl_backend_follows_mujoco_gl_and_failures_name_the_library(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "bogus")
    with pytest.raises(video.RenderError, match=r"^MUJOCO_GL='bogus' cannot render offscreen; valid: egl, osmesa"):
        video.gl_backend()
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    assert video.gl_backend() == "osmesa"
    real = importlib.import_module

    def missing(name, *args):
        if name == "mujoco.osmesa":
            raise ImportError("libOSMesa.so.8: cannot open shared object file: No such file or directory")
        return real(name, *args)

    monkeypatch.setattr(importlib, "import_module", missing)
    with pytest.raises(video.RenderError) as info:
        video.check_rendering(envs_mjx.make("arm7", mode="kinematic"))
    assert str(info.value) == (
        "cannot render with MUJOCO_GL=osmesa: libOSMesa is missing or unusable (libOSMesa.so.8: cannot open shared "
        "object file: No such file or directory); Debian/Ubuntu: apt-get install libosmesa6"
    )
    monkeypatch.delenv("MUJOCO_GL")
    monkeypatch.setattr("ctypes.util.find_library", lambda name: None)
    with pytest.raises(video.RenderError, match=r"install libEGL \(Debian/Ubuntu: apt-get install libegl1\) or "):
        video.gl_backend()
