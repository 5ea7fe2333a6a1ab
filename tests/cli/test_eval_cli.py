"""``python -m train.eval``: the final evaluation again, to the same figures and table, without writing
into the run directory; other episodes and seeds; one-line errors with exit code 2."""

import json
import os
import re
import sys

import jax
import numpy as np
import pytest

from jaxrl_robot.evaluation import run_test_episodes, summarize_episodes
from tests.run_dirs import make_run, state_after
from train import common
from train import eval as eval_cli
from train import ppo as ppo_cli

RUN = ["--env", "brax:fast", "--episode-length", "8", "--total-steps", "256", "--chunks", "2", "--eval-episodes", "6",
       "--seed", "5", "--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16", "--actor-hidden", "8",
       "--critic-hidden", "8", "--no-batch-norm"]  # fmt: skip


@pytest.fixture(scope="module")
def finished(tmp_path_factory):
    """A finished PPO run (its final evaluation in ``eval.json``): ``(run dir, env, trainer)``."""
    run_dir, _, env, trainer = make_run(str(tmp_path_factory.mktemp("runs")), ppo_cli.CLI, RUN)
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
    assert "ppo on brax:fast: evaluation" in printed and "mean_return" in printed and "checkpoint" in printed
    again = json.loads(out.read_text())
    assert again["episodes"] == trained["episodes"] == 6 and again["seed"] == again["eval_seed"] == 5
    for key in ("kind", "episodes", "mean_return", "mean_length"):  # the same program on the same episodes
        assert again[key] == trained[key], key
    assert f"{trained['mean_return']:.4g}" in printed
    assert listing(run_dir) == before


def test_eval_other_episodes_and_seed_are_those_a_run_of_that_seed_would_test(finished, tmp_path, capsys):
    run_dir, env, trainer = finished
    out = tmp_path / "e.json"
    assert eval_cli.main([run_dir, "--episodes", "3", "--seed", "11", "--out", str(out)]) == 0
    got = json.loads(out.read_text())
    policy = trainer.policy(state_after(trainer, 5, 2))
    episodes = jax.jit(lambda k: run_test_episodes(k, env, policy, 3, 8))(common.evaluation_key(11))
    want = summarize_episodes(episodes)
    assert got["episodes"] == 3 and got["eval_seed"] == 11 and got["seed"] == 5
    np.testing.assert_allclose([got["mean_return"], got["mean_length"]], [want["mean_return"], want["mean_length"]],
                               rtol=1e-6)  # fmt: skip
    capsys.readouterr()


def test_user_mistakes_end_in_one_line_and_exit_2(finished, tmp_path, capsys, monkeypatch):
    run_dir, _, _ = finished
    cases = [
        ([str(tmp_path / "none")], r"none: no such directory"),
        ([str(tmp_path)], r"not a run directory \(no config.json\)"),
        ([run_dir, "--step", "9"], r"no checkpoint 9; saved: 2$"),
        ([run_dir, "--video", str(tmp_path / "v.avi")], r"unknown format '.avi'; valid: .gif, .mp4"),
        ([run_dir, "--video", str(tmp_path / "v.gif"), "--video-size", "15x10"], r"--video-size 15x10: each side"),
        ([run_dir, "--video", str(tmp_path / "v.gif")], r"cannot render Fast: it has no MuJoCo model"),
    ]
    for argv, message in cases:
        assert eval_cli.main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err
        assert re.search(message, err), (message, err)
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
