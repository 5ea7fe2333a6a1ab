"""``jaxrl_robot.video`` without running episodes: the goal marker is drawn, an env without a MuJoCo model and
a bad suffix are refused, and the OpenGL errors name the library and its package.  (Episodes of arm7 rendered
to a GIF: ``tests/cli/test_eval_cli.py``.)"""

import importlib

import numpy as np
import pytest
from brax import envs as brax_envs

import envs_mjx
from jaxrl_robot import video


def test_the_goal_marker_is_drawn(tmp_path):
    env = envs_mjx.make("arm7", mode="kinematic")
    try:
        video.check_rendering(env)
    except video.RenderError as e:  # only this test needs OpenGL
        pytest.skip(f"no OpenGL for MuJoCo's offscreen renderer here: {e}")
    pose = {"qpos": np.zeros(env.mj_model.nq)}
    bare, marked = video.render_frames(env.mj_model, [pose, {**pose, "goal": np.array([0.4, 0.0, 0.8])}], 64, 48, 0.05)
    assert bare.shape == (48, 64, 3) and bare.dtype == np.uint8 and bare.std() > 10.0
    assert (np.abs(bare.astype(int) - marked).sum(axis=-1) > 30).sum() >= 4  # the same pose with a goal in view
    with pytest.raises(video.RenderError, match=r"the env's state has qpos \(3,\), its model 7 values"):
        video.render_frames(env.mj_model, [{"qpos": np.zeros(3)}], 64, 48)


def test_what_cannot_be_a_video_is_a_one_line_error(tmp_path):
    with pytest.raises(video.RenderError, match=r"^cannot render Fast: it has no MuJoCo model \(mj_model\)$"):
        video.check_rendering(brax_envs.get_environment("fast"))
    with pytest.raises(ValueError, match=r"unknown format '\.avi'; valid: \.gif, \.mp4$"):
        video.check_video_path(str(tmp_path / "a.avi"))
    with pytest.raises(ValueError, match=r"unknown format '\(none\)'"):
        video.check_video_path(str(tmp_path / "a"))


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


def test_a_renderer_mujoco_cannot_load_ends_a_command_in_one_line():
    """``MUJOCO_GL`` set to a value MuJoCo refuses stops ``python -m train.<x>`` before anything else runs:
    exit status 2 and one line naming the variable and the valid back ends (``import mujoco`` would raise)."""
    import subprocess
    import sys

    from tests.subproc import ROOT, cpu_env

    proc = subprocess.run([sys.executable, "-m", "train.eval", "no-such-run"], cwd=ROOT, capture_output=True,
                          text=True, timeout=120, env=cpu_env(MUJOCO_GL="nogl"))  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: MUJOCO_GL='nogl': MuJoCo cannot load that renderer")
    assert "valid: egl (libEGL, package libegl1)" in lines[0] and "osmesa" in lines[0] and "glfw" in lines[0]
