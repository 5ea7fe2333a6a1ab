"""``python -m train.sac``: DDPG's presets as a SACConfig, a distributed run with PER that writes its
directory, stops and resumes (the temperature in the checkpoint), in-process."""

import glob
import json
import os

import pytest

from jaxrl_robot.agents.off_policy import OffPolicyConfig
from jaxrl_robot.agents.sac import SACConfig
from train import ddpg as ddpg_cli
from train import sac as sac_cli

TINY = ["--batch-size", "16", "--actor-hidden", "16", "--critic-hidden", "16"]
RUN = ["--env", "brax:fast", "--episode-length", "16", "--total-steps", "256", "--num-envs", "4",
       "--unroll-length", "4", "--updates-per-iteration", "2", "--learning-starts", "32", "--buffer-size", "300",
       "--chunks", "2", "--checkpoint-every", "1", "--eval-episodes", "2", *TINY]  # fmt: skip


def test_sac_presets_are_ddpgs_converted():
    """Every family field of the preset is DDPG's; SAC's own fields keep their defaults; brax's tasks
    resolve ``auto`` to ``brax`` as for DDPG and TD3; flags set SAC's own fields."""
    for argv in (["--env", "unicycle", "--preset", "thesis"], ["--env", "brax:hopper"]):
        cfg, expected = sac_cli.parse(argv).sac, ddpg_cli.parse(argv).ddpg
        assert isinstance(cfg, SACConfig)
        for f in OffPolicyConfig.__dataclass_fields__:
            assert getattr(cfg, f) == getattr(expected, f), f
        assert (cfg.init_alpha, cfg.learn_alpha, cfg.target_entropy) == (1.0, True, None)
    assert sac_cli.parse(["--env", "brax:hopper"]).preset == "brax"
    args = sac_cli.parse(["--env", "unicycle", "--target-entropy", "-0.5", "--no-learn-alpha", "--init-alpha", "0.1"])
    assert (args.sac.target_entropy, args.sac.learn_alpha, args.sac.init_alpha) == (-0.5, False, 0.1)


def test_distributed_sac_with_per_writes_its_directory_and_resumes(tmp_path):
    argv = [*RUN, "--distributed", "--per", "--sync-workers", "2", "--collect-workers", "2", "--out", str(tmp_path)]
    assert sac_cli.main([*argv, "--stop-after-steps", "128"]) == 0
    (run_dir,) = glob.glob(str(tmp_path / "sac-brax_fast-*"))
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["algo"] == "sac" and config["sac"]["distributed"] and config["sac"]["target_entropy"] is None
    assert not os.path.exists(os.path.join(run_dir, "eval.json"))
    assert sac_cli.main(["--resume", run_dir]) == 0
    result = json.load(open(os.path.join(run_dir, "eval.json")))
    assert result["finished"] is True and result["env_steps"] == 2 * 6 * 24  # 2 chunks of 6 iterations, 6 lanes × 4
    rows = open(os.path.join(run_dir, "metrics.csv")).read().strip().splitlines()
    header = rows[0].split(",")
    assert len(rows) == 3 and {"alpha", "critic_loss", "beta", "collect_episodes"} <= set(header)
    alpha = [float(r.split(",")[header.index("alpha")]) for r in rows[1:]]
    assert all(0.0 < a < 1.0 for a in alpha)  # learned down from init_alpha = 1 by the second chunk
    with pytest.raises(ValueError, match="a 'sac' run, not 'ddpg'"):
        ddpg_cli.CLI.args_from_saved(run_dir, ddpg_cli.parse(["--env", "brax:fast"]))


def test_bad_sac_flag_is_one_line(capsys):
    assert sac_cli.main(["--env", "brax:fast", "--init-alpha", "0"]) == 2
    err = capsys.readouterr().err
    assert "init_alpha=0" in err and "Traceback" not in err
