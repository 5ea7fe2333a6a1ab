"""The presets' settings by hand (train.presets): the thesis's tables where a preset keeps them, the measured
options elsewhere."""

import numpy as np

from train import ppo as ppo_cli
from train.presets import ddpg_preset


def test_tracking_presets_thesis_keeps_table_3_3_and_cpu_uses_the_measured_options():
    thesis = ddpg_preset("thesis", "unicycle", 314)
    table_3_3 = (thesis.gamma, thesis.batch_size, thesis.buffer_size, thesis.tau, thesis.noise, thesis.per)
    assert table_3_3 == (0.9, 32, 50_000, 0.01, "ou", True)
    assert not thesis.twin_critics and thesis.policy_delay == 1 and thesis.reward_shift == 0.0
    assert thesis.noise_end_factor == 1.0 and thesis.termination_metric == ""
    for env in ("unicycle", "scara"):
        for name in ("cpu", "fast"):
            cfg = ddpg_preset(name, env, 314).validate()
            assert cfg.twin_critics and cfg.policy_delay == 2 and cfg.termination_metric == "early_termination"
            # the cost form r − 1 needs early termination valued at the worst return −1/(1 − γ)
            np.testing.assert_allclose(cfg.failure_value, cfg.reward_shift / (1.0 - cfg.gamma))


def test_arm_presets_bound_the_critic_targets_of_both_rewards():
    """sparse: the fixed [−10, 0]; shaped: the env's return range (resolved when the trainer is built)."""
    for name in ("thesis", "cpu", "fast"):
        sparse, shaped = (ddpg_preset(name, "arm7", 100, reward) for reward in ("sparse", "shaped"))
        assert sparse.target_clip == (-10.0, 0.0) and not sparse.clip_targets_to_env
        assert shaped.target_clip == () and shaped.clip_targets_to_env


def test_unicycle_fast_preset_a_p_per_method_and_trajectory_and_the_users_on_top():
    """Under ``fast`` the unicycle trains at a_p = 300, but two-stage training and the LSTM at 1000 on
    the sine (``train.presets.UNICYCLE_A_P_FAST``); ``--env-config`` still wins."""
    import tyro

    def settings(*extra):
        return ppo_cli.env_settings(tyro.cli(ppo_cli.Args, args=["--env", "unicycle", "--preset", "fast", *extra]))

    ellipse = ("--env-config", "trajectory=ellipse")
    assert settings("--pretrain", "action-search") == settings("--policy", "lstm") == {"a_p": 1000.0}
    assert settings() == {"a_p": 300.0}
    assert settings("--policy", "lstm", *ellipse) == settings("--pretrain", "action-search", *ellipse)
    assert settings("--policy", "lstm", *ellipse) == {"a_p": 300.0, "trajectory": "ellipse"}
    assert settings("--pretrain", "action-search", "--env-config", "a_p=5") == {"a_p": 5}
