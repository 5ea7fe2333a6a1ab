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
    """cpu builds the unicycle with a_p = 100 and the SCARA with Eq. 3.22's coefficient 50, fast with
    a_p = 300 and the coefficient 1000 on the extended SCARA observation (the measured presets);
    thesis keeps Eq. 3.21-3.23; ``--env-config`` overrides the preset."""
    env_of = lambda *argv: cli.CLI.build(cli.parse(list(argv)))[0]  # noqa: E731
    assert env_of("--env", "unicycle", "--preset", "cpu").config.a_p == 100.0
    assert env_of("--env", "unicycle", "--preset", "thesis").config.a_p == 1.0
    assert env_of("--env", "unicycle", "--preset", "cpu", "--env-config", "a_p=5").config.a_p == 5.0
    assert env_of("--env", "scara", "--preset", "cpu").config.reward_coef == 50.0
    assert env_of("--env", "scara", "--preset", "thesis").config.reward_coef == 2.0
    assert env_of("--env", "unicycle", "--preset", "fast").config.a_p == 300.0
    # distributed DDPG on the sine under fast: a_p = 1000 (measured better there); its ellipse and TD3 keep 300
    distributed = ("--env", "unicycle", "--preset", "fast", "--distributed", "--total-steps", "64")
    assert env_of(*distributed).config.a_p == (1000.0 if cli is ddpg_cli else 300.0)
    assert env_of(*distributed, "--trajectory", "ellipse").config.a_p == 300.0
    fast = env_of("--env", "scara", "--preset", "fast")
    assert (fast.config.reward_coef, fast.config.observation, fast.observation_size) == (1000.0, "extended", 13)
    assert env_of("--env", "scara", "--preset", "thesis").config.observation == "thesis"


def test_racing_presets_imitate_first():
    """racecar: every preset imitates the expert first (thesis §6.1.2) with Table 6.1's OU noise; cpu and
    fast train on the bank of roads and add the opponents' closing speeds and offsets to the observation;
    ``--pretrain none`` trains from scratch."""
    for preset in ("thesis", "cpu", "fast"):
        cfg = td3_cli.parse(["--env", "racecar", "--preset", preset]).td3
        assert cfg.pretrain == "imitation" and cfg.twin_critics and cfg.noise == "ou"
        assert cfg.noise_mean == (0.0, 0.5, -0.1) and cfg.noise_reversion == (0.8, 1.0, 1.0)
        assert cfg.noise_scale == (0.2, 0.1, 0.05) and 0 < cfg.pretrain_steps < cfg.total_steps
    assert ddpg_cli.parse(["--env", "racecar", "--pretrain", "none"]).ddpg.pretrain == "none"
    env_of = lambda *argv: ddpg_cli.CLI.build(ddpg_cli.parse(list(argv)))[0]  # noqa: E731
    cpu = env_of("--env", "racecar", "--preset", "cpu")
    assert cpu.observation_size == 132 and cpu.n_roads == 64 and cpu.config.end_on_collision
    thesis = env_of("--env", "racecar", "--preset", "thesis")
    assert thesis.observation_size == 60 and thesis.n_roads == 1 and not thesis.config.end_on_collision
    assert env_of("--env", "racecar", "--preset", "cpu", "--env-config", "road=train").n_roads == 1


def test_racing_run_resumes_through_the_imitation_stage_and_drives_laps(tmp_path):
    run = ["--env", "racecar", "--preset", "cpu", "--total-steps", "512", "--pretrain-steps", "256", "--num-envs",
           "4", "--unroll-length", "4", "--updates-per-iteration", "1", "--learning-starts", "64", "--buffer-size",
           "1000", "--imitation-batch", "16", "--imitation-updates", "1", "--imitation-buffer", "500", "--chunks",
           "2", "--eval-episodes", "1", "--env-config", "n_opponents=2", "max_steps=200", *TINY]  # fmt: skip
    assert td3_cli.main([*run, "--out", str(tmp_path), "--stop-after-steps", "256"]) == 0
    (run_dir,) = glob.glob(str(tmp_path / "td3-racecar-*"))
    assert td3_cli.main(["--resume", run_dir]) == 0
    result = json.load(open(os.path.join(run_dir, "eval.json")))
    assert result["kind"] == "racing" and result["env_steps"] == 512 and result["laps_per_road"] == 1
    for road in ("train", "test1", "test2", "test3"):
        outcomes = sum(result[f"{road}/{k}"] for k in ("success", "collision", "out_of_track", "stalled"))
        assert outcomes == 1
    header = open(os.path.join(run_dir, "metrics.csv")).readline()
    assert "imitation_loss" in header


@pytest.mark.parametrize("cli", [ddpg_cli, td3_cli])
def test_arm7_precise_budget_follows_reward_and_relabelling(cli):
    """arm7_precise: every reward gets the sparse rows' epochs, random relabelling goals twice that;
    arm7 keeps the thesis's 200 / 100 (the cpu preset: random relabelling goals twice); --epochs still wins."""

    def epochs(*argv):
        args = cli.parse(["--preset", "fast", *argv])
        return getattr(args, cli.CLI.name).epochs

    assert epochs("--env", "arm7", "--reward", "sparse", "--her", "future") == 20
    assert epochs("--env", "arm7", "--reward", "shaped", "--her", "random") == 10
    assert epochs("--env", "arm7_precise", "--reward", "shaped", "--her", "future") == 20
    assert epochs("--env", "arm7_precise", "--reward", "shaped", "--her", "random") == 40
    assert epochs("--env", "arm7_precise", "--reward", "shaped", "--her", "random", "--epochs", "5") == 5
    assert epochs("--env", "arm7", "--reward", "shaped", "--her", "random", "--preset", "cpu") == 20
    assert epochs("--env", "arm7", "--reward", "shaped", "--her", "future", "--preset", "cpu") == 10
    assert epochs("--env", "arm7_precise", "--reward", "shaped", "--her", "random", "--preset", "cpu") == 40
    thesis = cli.parse(["--env", "arm7_precise", "--preset", "thesis", "--her", "random"])
    assert getattr(thesis, cli.CLI.name).epochs == 400  # the env's default reward (path): 200, twice


@pytest.mark.parametrize("cli", [ddpg_cli, td3_cli])
def test_arm7_precise_normalises_observations(cli):
    """Every preset normalises the networks' observations on arm7_precise and on no other env;
    --no-normalize-obs still wins."""

    def normalise(*argv):
        return getattr(cli.parse(list(argv)), cli.CLI.name).normalize_obs

    for preset in ("thesis", "cpu", "fast"):
        assert normalise("--env", "arm7_precise", "--preset", preset, "--her", "random")
        assert not normalise("--env", "arm7", "--preset", preset, "--her", "random")
    assert not normalise("--env", "arm7_precise", "--preset", "fast", "--no-normalize-obs")
