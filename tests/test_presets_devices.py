"""PPO's ``fast`` preset on ``arm7`` scales with the devices its lanes are spread over (``--devices``)."""

from __future__ import annotations

import jax
import tyro

import envs_mjx
from train import ppo as ppo_cli
from train.presets import ppo_preset


def test_arm7_fast_preset_scales_lanes_mini_batches_and_steps_with_the_devices():
    """4 096 lanes and mini-batches of 8 192 per device (4 mini-batches of an 8-step unroll per epoch); 3 M env
    steps on one device, 1 M more per doubling (``train.presets.ARM_FAST_STEPS``)."""
    expected = {1: (4096, 8192, 3_000_000), 2: (8192, 16384, 4_000_000), 4: (16384, 32768, 5_000_000),
                8: (32768, 65536, 6_000_000)}  # fmt: skip
    for devices, sizes in expected.items():
        c = ppo_preset("fast", "arm7", 100, 3, devices=devices)[0].validate()
        assert (c.num_envs, c.minibatch_size, c.total_steps) == sizes
        assert c.num_envs * c.unroll_length // c.minibatch_size == 4 and c.actor_lr == 1e-3
    # other envs, presets and variants keep their sizes on any device count
    for name, env, variant in [("fast", "arm7_precise", {}), ("fast", "unicycle", {}), ("cpu", "arm7", {}),
                               ("thesis", "arm7", {}), ("fast", "arm7", {"policy": "lstm"}),
                               ("fast", "arm7", {"pretrain": "action-search"})]:  # fmt: skip
        assert ppo_preset(name, env, 100, 3, devices=4, **variant) == ppo_preset(name, env, 100, 3, **variant)
    assert ppo_preset("fast", "arm7_precise", 100, 3)[0].total_steps == 12_000_000
    # 0: every device
    assert ppo_preset("fast", "arm7", 100, 3, devices=0)[0].num_envs == 4096 * jax.device_count()


def test_the_ppo_command_line_passes_devices_to_the_preset():
    env = envs_mjx.make("arm7")
    args = tyro.cli(ppo_cli.Args, args=["--env", "arm7", "--preset", "fast", "--devices", "2"])
    assert (ppo_cli.preset(args, env).num_envs, ppo_cli.preset(args, env).total_steps) == (8192, 4_000_000)


def test_without_devices_the_fast_main_job_takes_one_device_and_every_other_run_all():
    """``--devices`` not given: 1 for PPO ``fast`` on ``arm7`` (its 4 096 lanes train faster on one GPU than
    spread over two), 0 (every device) for other envs, presets and variants; a given ``--devices`` is kept."""
    from train.presets import ppo_default_devices

    assert ppo_default_devices("fast", "arm7") == 1
    for args in [("fast", "unicycle"), ("fast", "arm7_precise"), ("cpu", "arm7"), ("thesis", "arm7"),
                 ("fast", "arm7", "lstm"), ("fast", "arm7", "mlp", "action-search")]:  # fmt: skip
        assert ppo_default_devices(*args) == 0, args
    parsed = {flags: ppo_cli.parse(["--env", "arm7", "--preset", "fast", *flags]) for flags in [(), ("--devices", "0")]}
    assert parsed[()].devices == 1 and parsed[()].ppo.num_envs == 4096
    assert parsed[("--devices", "0")].devices == 0
    assert parsed[("--devices", "0")].ppo.num_envs == 4096 * jax.device_count()
    assert ppo_cli.parse(["--env", "unicycle", "--preset", "fast"]).devices == 0


def test_without_devices_the_single_off_policy_learner_takes_one_device_and_distributed_ddpg_every_one():
    """``--devices`` not given: 1 for DDPG's, TD3's and SAC's single learner (its replay and updates are
    replicated on every device: on two H200s a chunk ran 31-39 s against 0.9 s on one), 0 (every device) for
    distributed DDPG (a worker per device); a given ``--devices`` is kept."""
    import train.ddpg as ddpg_cli
    import train.sac as sac_cli
    import train.td3 as td3_cli
    from train.presets import off_policy_default_devices

    assert (off_policy_default_devices(False), off_policy_default_devices(True)) == (1, 0)
    for cli in (ddpg_cli, td3_cli, sac_cli):
        assert cli.parse(["--env", "arm7", "--preset", "cpu"]).devices == 1, cli.__name__
        assert cli.parse(["--env", "arm7", "--preset", "cpu", "--devices", "0"]).devices == 0, cli.__name__
    assert ddpg_cli.parse(["--env", "arm7", "--preset", "cpu", "--distributed"]).devices == 0
    assert ddpg_cli.parse(["--env", "arm7", "--preset", "cpu", "--distributed", "--devices", "2"]).devices == 2
