"""``python -m train.td3``: DDPG's trainer with the TD3 settings, its own run directory and resume."""

import glob
import json
import os

import pytest

from train import ddpg as ddpg_cli
from train import td3 as td3_cli

TINY = ["--batch-size", "16", "--actor-hidden", "16", "--critic-hidden", "16"]
RUN = ["--env", "brax:fast", "--episode-length", "16", "--total-steps", "256", "--num-envs", "4",
       "--unroll-length", "4", "--updates-per-iteration", "2", "--learning-starts", "32", "--buffer-size", "300",
       "--chunks", "2", "--checkpoint-every", "1", "--eval-episodes", "2", *TINY]  # fmt: skip


def test_td3_preset_is_ddpgs_with_the_td3_settings():
    args = td3_cli.parse(["--env", "unicycle", "--preset", "thesis"])
    expected = ddpg_cli.parse(["--env", "unicycle", "--preset", "thesis"]).ddpg
    cfg = args.td3
    assert (cfg.twin_critics, cfg.policy_delay, cfg.target_noise, cfg.target_noise_clip) == (True, 2, 0.2, 0.5)
    assert not expected.twin_critics and expected.target_noise == 0.0  # the thesis's DDPG row
    assert cfg.replace(**{k: getattr(expected, k) for k in td3_cli.TD3_SETTINGS}) == expected
    # a flag still overrides a TD3 setting
    assert td3_cli.parse(["--env", "unicycle", "--policy-delay", "3"]).td3.policy_delay == 3


def test_td3_run_writes_its_directory_and_resumes(tmp_path):
    assert td3_cli.main([*RUN, "--out", str(tmp_path), "--stop-after-steps", "128"]) == 0
    (run_dir,) = glob.glob(str(tmp_path / "td3-brax_fast-*"))
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["algo"] == "td3" and "ddpg" not in config
    assert config["td3"]["twin_critics"] is True and config["td3"]["target_noise"] == 0.2
    assert not os.path.exists(os.path.join(run_dir, "eval.json"))
    assert td3_cli.main(["--resume", run_dir]) == 0
    result = json.load(open(os.path.join(run_dir, "eval.json")))
    assert result["env_steps"] == 256 and result["finished"] is True
    rows = open(os.path.join(run_dir, "metrics.csv")).read().strip().splitlines()
    assert len(rows) == 3 and "critic_loss" in rows[0]  # header + 2 chunks, the first kept on resume
    # a TD3 run is not a DDPG run
    with pytest.raises(ValueError, match="a 'td3' run, not 'ddpg'"):
        ddpg_cli.CLI.args_from_saved(run_dir, ddpg_cli.parse(["--env", "brax:fast"]))


@pytest.mark.parametrize("cli", [ddpg_cli, td3_cli], ids=["ddpg", "td3"])
def test_tracking_presets_sharpen_the_reward_and_env_config_wins(cli):
    """cpu/fast build the unicycle with a_p = 100 and the SCARA with Eq. 3.22's coefficient 50 (the
    measured presets); thesis keeps Eq. 3.22-3.23; ``--env-config`` overrides the preset."""
    env_of = lambda *argv: cli.CLI.build(cli.parse(list(argv)))[0]  # noqa: E731
    assert env_of("--env", "unicycle", "--preset", "cpu").config.a_p == 100.0
    assert env_of("--env", "unicycle", "--preset", "thesis").config.a_p == 1.0
    assert env_of("--env", "unicycle", "--preset", "cpu", "--env-config", "a_p=5").config.a_p == 5.0
    assert env_of("--env", "scara", "--preset", "cpu").config.reward_coef == 50.0
    assert env_of("--env", "scara", "--preset", "thesis").config.reward_coef == 2.0
