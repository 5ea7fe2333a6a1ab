"""``python -m train.<algo> --env playground:<Name>``: a few hundred steps of ``train.ppo`` on Playground's
``CartpoleBalance`` in-process (the ``playground`` preset, ``--env-config``, a run directory whose
``config.json`` rebuilds the env), and the one-line errors for an unknown name and a missing package."""

from __future__ import annotations

import csv
import glob
import json
import math
import os
import sys

from train import ppo as ppo_cli
from train import td3 as td3_cli
from train.envs import make_env

TINY = [
    "--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16", "--actor-updates", "2",
    "--critic-updates", "2", "--actor-hidden", "16", "--critic-hidden", "16", "--advantage-segment", "8",
]  # fmt: skip


def test_train_ppo_trains_cartpole_balance_with_playground_s_settings_and_resume_rebuilds_the_env(tmp_path, capsys):
    """``--preset auto`` picks ``playground`` (Playground's ``brax_ppo_config``, converted: γ 0.995, rewards
    x 10, Adam 1e-3, entropy 1e-2, brax's networks and update) with the env's own time limit (16 steps
    through ``--env-config``); the first of two chunks (4 lanes x 32 steps: 8 episodes) trains, is
    checkpointed, and ``--resume`` reads back the env and its Playground config from ``config.json``."""
    argv = ["--env", "playground:CartpoleBalance", "--env-config", "episode_length=16", *TINY, "--total-steps",
            "256", "--chunks", "2", "--stop-after-steps", "128", "--out", str(tmp_path)]  # fmt: skip
    assert ppo_cli.main(argv) == 0
    err = capsys.readouterr().err
    assert "preset: playground (MuJoCo Playground's brax_ppo_config for playground:CartpoleBalance" in err
    (run_dir,) = glob.glob(str(tmp_path / "ppo-playground_CartpoleBalance-*"))
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        (row,) = list(csv.DictReader(f))
    assert int(row["env_steps"]) == 128 and float(row["episodes"]) == 8 and float(row["episode_length"]) == 16
    assert all(math.isfinite(float(row[k])) for k in ("actor_loss", "critic_loss", "episode_return"))
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["args"]["preset"] == "playground" and config["args"]["env_config"] == ["episode_length=16"]
    cfg = config["ppo"]
    assert (cfg["gamma"], cfg["reward_scale"], cfg["actor_lr"], cfg["entropy_coef"]) == (0.995, 10.0, 1e-3, 1e-2)
    assert (cfg["episode_length"], cfg["tanh_actions"], cfg["normalize_obs"], cfg["num_envs"]) == (16, True, True, 4)

    resumed = ppo_cli.parse(["--resume", run_dir])
    env = make_env(resumed.env, ppo_cli.env_settings(resumed))
    assert env.name == "playground:CartpoleBalance" and env.episode_length == 16
    assert env.env.mjx_model.impl.value == "jax"


def test_an_unknown_name_and_a_missing_package_are_one_line_errors(capsys, monkeypatch):
    assert ppo_cli.main(["--env", "playground:CartpolBalance"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: unknown MuJoCo Playground environment 'CartpolBalance'; valid names")
    assert "CartpoleBalance" in line and "WalkerWalk" in line

    monkeypatch.setitem(sys.modules, "mujoco_playground", None)  # as if it were not installed
    for main in (ppo_cli.main, td3_cli.main):
        assert main(["--env", "playground:CartpoleBalance"]) == 2
        assert capsys.readouterr().err == (
            'error: --env playground:CartpoleBalance needs MuJoCo Playground: pip install -e ".[playground]"\n'
        )
