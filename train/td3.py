"""Train TD3 (thesis §6.2, Eq. 6.2–6.3): ``python -m train.td3 --env unicycle``.

TD3 (``jaxrl_robot.agents.td3``) is DDPG's trainer with three of its options set: two critics
regressed on the clipped double-Q target ``y = r + γ (1 − d) min(Q1'(s', a'), Q2'(s', a'))``
(Eq. 6.2), the target action smoothed as ``a' = clip(μ'(s') + clip(ξ, −0.5, 0.5), −1, 1)`` with
``ξ ~ N(0, 0.2²)`` (Eq. 6.3), and the actor (which maximises Q1) and all target networks updated
once every 2 critic updates. Everything else — presets per env (``train/presets/``, DDPG's),
PER, HER, the run directory, evaluation, figures and ``--resume`` — is ``python -m train.ddpg``'s;
every flag of that command works here, so ``--policy-delay 3`` or ``--target-noise 0.1`` change
the TD3 settings.

Examples::

    python -m train.td3 --env unicycle --trajectory sine
    python -m train.td3 --env scara --preset thesis
    python -m train.td3 --env arm7 --reward sparse --her future --her-k 4
    python -m train.td3 --resume runs/td3-unicycle-20260101-120000
    python -m train.td3 --env scara --preset thesis --distributed   # distributed TD3 (§4.2 workers)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any

import tyro

from jaxrl_robot.agents.ddpg import DDPGConfig
from jaxrl_robot.agents.td3 import TD3_SETTINGS, td3_config
from train import ddpg

__all__ = ["CLI", "TD3_SETTINGS", "Args", "build", "main", "parse", "preset"]


@dataclass
class Args(ddpg.OffPolicyOptions):
    """TD3 (thesis §6.2): DDPG with twin critics, target smoothing and delayed policy updates.
    --distributed: with the synchronous and collecting workers of distributed DDPG (thesis §4.2)
    on the preset's distributed variant (thesis: 4 + 4 workers, 4 x 32 transitions per update,
    memory 200 000)."""

    td3: Annotated[DDPGConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=td3_config)
    """TD3 hyper-parameters (defaults: DDPG's preset for the env with the TD3 settings)."""


def preset(args: ddpg.OffPolicyOptions, env: Any, distributed: bool = False) -> DDPGConfig:
    """DDPG's preset for ``env`` (:func:`train.ddpg.preset`, distributed or not) with the TD3 settings
    (``jaxrl_robot.agents.td3.TD3_SETTINGS``)."""
    return td3_config(ddpg.preset(args, env, distributed=distributed))


CLI = ddpg.OffPolicyCLI(
    name="td3", args_type=Args, config_type=DDPGConfig, preset=preset, make_trainer=ddpg.make_trainer,
    env_settings=ddpg.env_settings, env_fields=("trajectory",), preset_fields=("her",),
)  # fmt: skip


# parse(argv=None) -> Args (the preset's defaults for --env, then every flag); build(args) -> (env, trainer,
# config dict) of a fresh or resumed run; main(argv=None) -> exit code
parse, build, main = CLI.parse, CLI.build, CLI.main

if __name__ == "__main__":
    ddpg.exit_process(main())
