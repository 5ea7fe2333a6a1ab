"""``python -m train.eval``: the final evaluation again, to the same figures and table, without writing
into the run directory; another evaluation seed; a video of arm7's test episodes; one-line errors, exit 2."""

import json
import os
import re
import sys

import jax
import numpy as np
import pytest
from PIL import Image, ImageSequence

from jaxrl_robot import video
from jaxrl_robot.evaluation import evaluation_key, run_test_episodes, summarize_episodes
from tests.run_dirs import make_run, state_after
from train import eval as eval_cli
from train import ppo as ppo_cli

RUN = ["--env", "arm7", "--episode-length", "4", "--total-steps", "256", "--chunks", "2", "--eval-episodes", "4",
       "--no-precision", "--seed", "5", "--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16",
       "--actor-hidden", "8", "--critic-hidden", "8", "--no-batch-norm"]  # fmt: skip
OFFSET = 0.3  # each chunk moves the parameters this far: the policy pushes the arm hard in one direction
FIGURES = ("episodes", "mean_return", "mean_length", "successes", "mean_final_distance")


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished PPO run on arm7 (its final evaluation in ``eval.json``) whose policy moves the arm visibly:
    ``(run dir, env, trainer)``."""
    run_dir, _, env, trainer = make_run(str(tmp_path_factory.mktemp("runs")), ppo_cli.CLI, RUN, offset=OFFSET)
    return run_dir, env, trainer


def listing(folder):
    """Every file under ``folder`` with its size and modification time."""
    return {os.path.join(r, n): (os.stat(os.path.join(r, n)).st_size, os.stat(os.path.join(r, n)).st_mtime_ns)
            for r, _, names in os.walk(folder) for n in names}  # fmt: skip


def test_eval_prints_the_final_evaluation_again_and_writes_nothing_into_the_run(finished, tmp_path, capsys):
    run_dir, _, _ = finished
    with open(os.path.join(run_dir, "eval.json")) as f:
        trained = json.load(f)
    before = listing(run_dir)
    out = tmp_path / "again" / "eval.json"
    assert eval_cli.main([run_dir, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"{run_dir}: checkpoint 2 (256 env steps)" in printed
    assert "ppo on arm7: evaluation" in printed and "success_rate" in printed and "checkpoint" in printed
    again = json.loads(out.read_text())
    assert again["episodes"] == 4 and again["seed"] == again["eval_seed"] == 5
    for key in FIGURES:  # the same program on the same episodes
        assert again[key] == trained[key], key
    assert f"{trained['mean_final_distance']:.4g}" in printed
    assert listing(run_dir) == before


def test_eval_seed_gives_the_episodes_a_run_of_that_seed_tests(finished, tmp_path, capsys):
    run_dir, env, trainer = finished
    out = tmp_path / "e.json"
    assert eval_cli.main([run_dir, "--seed", "11", "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    policy = trainer.policy(state_after(trainer, 5, 2, OFFSET))
    episodes = jax.jit(lambda k: run_test_episodes(k, env, policy, 4, 4))(evaluation_key(11))
    want = summarize_episodes(episodes)
    assert got["episodes"] == 4 and got["eval_seed"] == 11 and got["seed"] == 5
    np.testing.assert_allclose([got[k] for k in FIGURES], [want[k] for k in FIGURES], rtol=1e-5)
    with open(os.path.join(run_dir, "eval.json")) as f:
        assert json.load(f)["mean_final_distance"] != got["mean_final_distance"]  # other starts and goals
    capsys.readouterr()


def test_eval_video_shows_the_test_episodes_moving(finished, tmp_path, capsys):
    run_dir, env, _ = finished
    try:
        video.check_rendering(env)
    except video.RenderError as e:  # only this test needs OpenGL
        pytest.skip(f"no OpenGL for MuJoCo's offscreen renderer here: {e}")
    path = tmp_path / "arm7.gif"
    argv = [run_dir, "--video", str(path), "--video-episodes", "2", "--video-size", "48x32"]
    assert eval_cli.main(argv) == 0
    assert f"wrote {path} (" in capsys.readouterr().out
    gif = Image.open(path)
    assert gif.size == (48, 32) and gif.info["duration"] == 50  # arm7's control period, 0.05 s
    frames = [np.asarray(f.convert("RGB"), np.float32) for f in ImageSequence.Iterator(gif)]
    assert len(frames) >= 4  # two episodes of up to 4 steps and their starts (held last frames merge)
    for f in frames:  # a scene, not a blank or uniform picture
        assert f.std() > 10.0
    changes = [np.abs(a - b).mean() for a, b in zip(frames, frames[1:], strict=False)]
    assert min(changes) > 0.5, changes  # the arm moves from frame to frame (held frames are merged), episodes differ


def test_user_mistakes_end_in_one_line_and_exit_2(finished, tmp_path, capsys, monkeypatch):
    run_dir, _, _ = finished
    cases = [
        ([str(tmp_path / "none")], r"none: no such directory"),
        ([str(tmp_path)], r"not a run directory \(no config.json\)"),
        ([run_dir, "--step", "9"], r"no checkpoint 9; saved: 2$"),
        ([run_dir, "--video", str(tmp_path / "v.avi")], r"unknown format '.avi'; valid: .gif, .mp4"),
        ([run_dir, "--video", str(tmp_path / "v.gif"), "--video-size", "15x10"], r"--video-size 15x10: each side"),
        ([run_dir, "--out", str(tmp_path / "blocker" / "e.json")], r"--out .*: cannot write it"),
    ]
    (tmp_path / "blocker").write_text("a file, not a folder")
    for argv, message in cases:
        assert eval_cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err
        assert re.search(message, err.strip()), (message, err)
    monkeypatch.setitem(sys.modules, "imageio", None)  # the 'video' extra is not installed
    assert eval_cli.main([run_dir, "--video", str(tmp_path / "v.mp4")]) == 2
    assert "MP4 needs imageio and imageio-ffmpeg, the 'video' extra (pip install 'jaxrl-robot[video]')" in (
        capsys.readouterr().err
    )
    for argv in (["--episodes", "0"], ["--seed", "-1"], ["--video-episodes", "x"]):
        with pytest.raises(SystemExit) as e:
            eval_cli.main([run_dir, *argv])
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: argument {argv[0]}: ") and err.count("\n") == 1, err
    assert not os.path.exists(tmp_path / "v.gif") and not os.path.exists(tmp_path / "v.mp4")
