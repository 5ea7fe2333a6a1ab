"""``python -m train.ddpg --distributed`` and ``python -m train.td3 --distributed``: the distributed preset,
``--help``, and a tiny run writing its run directory with the workers' metrics."""

import csv
import glob
import json
import os

import pytest

from train import ddpg as ddpg_cli
from train import td3 as td3_cli

TINY = ["--batch-size", "8", "--actor-hidden", "16", "--critic-hidden", "16"]


def test_distributed_flag_selects_the_distributed_preset_for_ddpg_and_td3():
    args = ddpg_cli.parse(["--env", "unicycle", "--preset", "thesis", "--distributed"])
    cfg = args.ddpg
    assert cfg.distributed and (cfg.sync_workers, cfg.collect_workers, cfg.fetch_every) == (4, 4, 5)
    assert (cfg.batch_size, cfg.buffer_size) == (32, 200_000)
    assert not ddpg_cli.parse(["--env", "unicycle", "--preset", "thesis"]).ddpg.distributed
    assert not ddpg_cli.parse(["--env", "unicycle", "--distributed", "--no-distributed"]).ddpg.distributed
    assert ddpg_cli.parse(["--env", "unicycle", "--distributed", "--fetch-every", "3"]).ddpg.fetch_every == 3
    td3 = td3_cli.parse(["--env", "unicycle", "--preset", "thesis", "--distributed"]).td3
    assert td3 == cfg.replace(**td3_cli.TD3_SETTINGS)


def test_help_says_distributed(capsys):
    with pytest.raises(SystemExit):
        ddpg_cli.main(["--env", "brax:fast", "--distributed", "--help"])
    out = capsys.readouterr().out
    assert "distributed DDPG (thesis §4.2)" in out and "--sync-workers" in out and "--fetch-every" in out
    with pytest.raises(SystemExit):
        td3_cli.main(["--env", "brax:fast", "--help"])
    assert "--distributed" in capsys.readouterr().out


def test_distributed_run_writes_its_directory(tmp_path):
    """2 + 2 workers of 2 lanes on brax's ``fast``: 8 iterations of 8 lanes × 4 steps, two chunks."""
    argv = ["--env", "brax:fast", "--distributed", "--episode-length", "16", "--total-steps", "256", "--num-envs", "4",
            "--sync-workers", "2", "--collect-workers", "2", "--collect-lanes", "2", "--unroll-length", "4",
            "--updates-per-iteration", "2", "--learning-starts", "64", "--buffer-size", "300", "--chunks", "2",
            "--eval-episodes", "2", "--out", str(tmp_path), *TINY]  # fmt: skip
    assert ddpg_cli.main(argv) == 0
    (run_dir,) = glob.glob(str(tmp_path / "ddpg-brax_fast-*"))
    config = json.load(open(os.path.join(run_dir, "config.json")))["ddpg"]
    assert config["distributed"] is True and (config["sync_workers"], config["collect_lanes"]) == (2, 2)
    rows = list(csv.DictReader(open(os.path.join(run_dir, "metrics.csv"))))
    assert len(rows) == 2 and float(rows[-1]["updates"]) == 2 * 7  # 32 rows per iteration: learning from the 2nd
    assert float(rows[-1]["staleness_max"]) <= 4 and "collect_episodes" in rows[-1]
    assert json.load(open(os.path.join(run_dir, "eval.json")))["env_steps"] == 256
