"""``python -m train.ddpg``: a tiny HER run, resume = uninterrupted (replay and sum-tree
included), bad input."""

import glob
import json
import os

import jax
import numpy as np

from jaxrl_robot.checkpoint import Checkpointer
from train import ddpg as ddpg_cli

TINY = ["--batch-size", "16", "--actor-hidden", "16", "--critic-hidden", "16"]


def test_cli_tiny_her_run_writes_the_run_directory(tmp_path, capsys):
    argv = ["--env", "arm7", "--reward", "sparse", "--her", "future", "--her-k", "2", "--per", "--env-config",
            "mode=kinematic", "max_steps=10", "--epochs", "2", "--cycles-per-epoch", "2", "--num-envs", "2",
            "--updates-per-cycle", "2", "--buffer-size", "2000", "--eval-episodes", "5", "--preset", "cpu",
            "--out", str(tmp_path), *TINY]  # fmt: skip
    assert ddpg_cli.main(argv) == 0
    (run_dir,) = glob.glob(str(tmp_path / "ddpg-arm7-*"))
    for name in ("config.json", "metrics.csv", "eval.json", "episode_reward.png"):
        assert os.path.isfile(os.path.join(run_dir, name)), name
    assert Checkpointer(os.path.join(run_dir, "checkpoints")).latest_step() == 2  # one chunk per epoch
    rows = open(os.path.join(run_dir, "metrics.csv")).read().strip().splitlines()
    assert len(rows) == 3 and "success" in rows[0] and "critic_loss" in rows[0]
    result = json.load(open(os.path.join(run_dir, "eval.json")))
    assert result["episodes"] == 5 and 0.0 <= result["success_rate"] <= 1.0
    assert result["env_steps"] == 2 * 2 * 2 * 10  # epochs × cycles × lanes × steps
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["ddpg"]["her"] == "future" and config["ddpg"]["her_k"] == 2 and config["ddpg"]["per"] is True
    assert config["ddpg"]["failure_value"] == -10.0  # the sparse preset
    assert "success_rate" in capsys.readouterr().out  # the printed table


def _final_state(run_dir):
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    args = ddpg_cli._args_from_saved(run_dir, ddpg_cli.Args(ddpg=None))
    _, trainer, _ = ddpg_cli.build(args)
    return ckpt.restore(ckpt.latest_step(), jax.jit(trainer.init)(jax.random.PRNGKey(0)))


def test_resume_equals_uninterrupted(tmp_path):
    common_args = ["--env", "brax:fast", "--episode-length", "16", "--total-steps", "512", "--num-envs", "4",
                   "--unroll-length", "4", "--updates-per-iteration", "2", "--learning-starts", "32",
                   "--buffer-size", "300", "--per", "--chunks", "4", "--checkpoint-every", "1",
                   "--eval-episodes", "2", "--seed", "3", *TINY]  # fmt: skip
    assert ddpg_cli.main([*common_args, "--out", str(tmp_path / "a")]) == 0
    assert ddpg_cli.main([*common_args, "--out", str(tmp_path / "b"), "--stop-after-steps", "256"]) == 0
    (run_b,) = glob.glob(str(tmp_path / "b" / "*"))
    assert not os.path.exists(os.path.join(run_b, "eval.json"))  # stopped half-way
    assert ddpg_cli.main(["--resume", run_b]) == 0
    (run_a,) = glob.glob(str(tmp_path / "a" / "*"))
    (sa, ra), (sb, rb) = _final_state(run_a), _final_state(run_b)
    assert ra["chunk"] == rb["chunk"] == 4
    assert int(sa.replay.size) == 300  # the ring wrapped, so its position and the tree matter
    same = jax.tree.map(lambda x, y: bool(np.array_equal(np.asarray(x), np.asarray(y))), sa, sb)
    assert all(jax.tree.leaves(same))  # params, targets, optimisers, replay, sum-tree, β, noise, envs, key
    assert len(open(os.path.join(run_b, "metrics.csv")).read().strip().splitlines()) == 5


def test_bad_input_names_the_valid_choices(capsys):
    assert ddpg_cli.main(["--env", "arm7", "--her", "best"]) == 2
    assert "her='best' is not valid; choose one of 'none', 'final', 'future', 'random'" in capsys.readouterr().err
    assert ddpg_cli.main(["--env", "unicycle", "--her", "final"]) == 2
    assert "needs whole episodes" in capsys.readouterr().err
