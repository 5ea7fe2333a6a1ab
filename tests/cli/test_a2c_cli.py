"""``python -m train.a3c`` / ``train.a2c``: a tiny run on arm7, bad input."""

import glob
import json
import os

from jaxrl_robot.checkpoint import Checkpointer
from jaxrl_robot.logging import read_csv
from train import a2c as a2c_cli
from train import a3c as a3c_cli

TINY = ["--num-envs", "4", "--unroll-length", "8", "--actor-hidden", "16", "--critic-hidden", "16"]


def test_a3c_cli_tiny_run_writes_the_run_directory(tmp_path, capsys):
    argv = ["--env", "arm7", "--reward", "path", "--total-steps", "256", "--chunks", "2", "--eval-episodes", "5",
            "--push-order", "fixed", "--lanes-per-worker", "1", "--preset", "cpu", "--out", str(tmp_path),
            *TINY]  # fmt: skip
    assert a3c_cli.main(argv) == 0
    printed = capsys.readouterr().out
    (run_dir,) = glob.glob(str(tmp_path / "a3c-arm7-*"))
    for name in ("config.json", "metrics.csv", "eval.json", "episode_reward.png", "success_rate.png",
                 "worker_rewards.png", "staleness.png"):  # fmt: skip
        assert os.path.isfile(os.path.join(run_dir, name)), name
    assert Checkpointer(os.path.join(run_dir, "checkpoints")).latest_step() == 2
    rows = read_csv(os.path.join(run_dir, "metrics.csv"))
    assert [int(r["env_steps"]) for r in rows] == [128, 256]  # 4 rounds of 4 lanes x 8 slots, 2 chunks
    # fixed push order, 4 workers: staleness 0, 1, 2, 3 in round one, then 3 for every push
    assert float(rows[0]["staleness_mean"]) == (0 + 1 + 2 + 3 + 3 * 12) / 16
    assert float(rows[1]["staleness_mean"]) == 3.0 and float(rows[1]["staleness_hist_3"]) == 1.0
    assert 0 < float(rows[0]["steps_taken"]) <= 128
    result = json.load(open(os.path.join(run_dir, "eval.json")))
    assert result["episodes"] == 5 and 0.0 <= result["success_rate"] <= 1.0
    assert "success_rate" in printed and "mean_extra_distance" in printed  # the printed table
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["algo"] == "a3c" and config["a3c"]["push_order"] == "fixed"
    assert config["args"]["reward"] == "path"


def test_presets_give_the_thesis_table_4_2():
    args = a2c_cli.parse(["--env", "arm7", "--preset", "thesis"], "a2c")
    cfg = args.a2c
    assert (cfg.num_envs, cfg.unroll_length, cfg.actor_lr, cfg.critic_lr) == (4, 8, 1e-4, 2e-4)
    assert (cfg.entropy_coef, cfg.gamma, cfg.sigma, cfg.batch_norm) == (0.01, 0.9, (0.8, 0.8, 0.1), True)
    args = a2c_cli.parse(["--env", "arm7", "--preset", "thesis", "--push-order", "fixed"], "a3c")
    assert args.a3c.num_workers == 4 and args.a3c.push_order == "fixed"


def test_bad_input_names_the_valid_choices(capsys):
    assert a3c_cli.main(["--env", "nope"]) == 2
    assert "unknown environment 'nope'; valid names: arm7" in capsys.readouterr().err
    assert a2c_cli.main(["--env", "arm7", "--preset", "huge"]) == 2
    assert "unknown preset 'huge'; valid presets" in capsys.readouterr().err
    assert a3c_cli.main(["--env", "arm7", "--lanes-per-worker", "3", "--num-envs", "4"]) == 2
    assert "lanes_per_worker=3 must divide num_envs=4" in capsys.readouterr().err
    assert a2c_cli.main(["--env", "arm7", "--reward", "fancy"]) == 2
    assert "reward='fancy'" in capsys.readouterr().err
