"""Train SAC (soft actor-critic, ``jaxrl_robot.agents.sac``): ``python -m train.sac --env brax:hopper``.

SAC is a member of the off-policy family: its presets per env are DDPG's (``train/presets/``,
:func:`train.ddpg.preset`, converted field by field to a :class:`~jaxrl_robot.agents.sac.SACConfig`; the
exploration-noise fields go unused, since the policy explores by sampling itself), and PER, HER,
``--random-start``, ``--pretrain imitation``, ``--distributed``, the run directory, evaluation, figures and
``--resume`` are ``python -m train.ddpg``'s; every flag of that command works here, and ``--init-alpha``,
``--no-learn-alpha``, ``--alpha-lr``, ``--target-entropy`` and ``--min-std`` set SAC's temperature and policy.
On brax's hopper and walker2d the ``brax`` preset (``auto`` there) takes brax's SAC lanes and memory with the
update settings of the SAC and TD3 papers (``TD3_OWN``: one update per env step, two on these tasks, on
mini-batches of 256 at 3e-4, γ 0.99).

Examples::

    python -m train.sac --env brax:hopper
    python -m train.sac --env arm7 --reward sparse --her future --her-k 4
    python -m train.sac --env scara --preset thesis --distributed
    python -m train.sac --resume runs/sac-brax_hopper-20260101-120000
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Annotated, Any

import tyro

from jaxrl_robot.agents.off_policy import OffPolicyConfig
from jaxrl_robot.agents.sac import SACConfig, make_trainer
from train import ddpg

__all__ = ["CLI", "Args", "build", "main", "parse", "preset", "sac_config"]


@dataclass
class Args(ddpg.OffPolicyOptions):
    """SAC: twin critics, a learned temperature with a target entropy, a tanh-Gaussian policy, on the
    off-policy family's schedules, replay (PER, HER) and workers (--distributed: thesis §4.2)."""

    sac: Annotated[SACConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=SACConfig)
    """SAC hyper-parameters (defaults: DDPG's preset for the env, converted)."""


def sac_config(config: OffPolicyConfig, **changes: Any) -> SACConfig:
    """A :class:`SACConfig` with the family's fields of ``config`` (e.g. a DDPG preset), then ``changes``."""
    family = {f.name: getattr(config, f.name) for f in dataclasses.fields(OffPolicyConfig)}
    return SACConfig(**family).replace(**changes)


def preset(args: ddpg.OffPolicyOptions, env: Any, distributed: bool = False) -> SACConfig:
    """DDPG's preset for ``env`` (:func:`train.ddpg.preset`, distributed or not) as a :class:`SACConfig`."""
    return sac_config(ddpg.preset(args, env, distributed=distributed))


CLI = ddpg.OffPolicyCLI(
    name="sac", args_type=Args, config_type=SACConfig, preset=preset, make_trainer=ddpg.chunked(make_trainer),
    env_settings=ddpg.env_settings, env_fields=("trajectory",), preset_fields=("her",),
)  # fmt: skip

# parse(argv=None) -> Args (the preset's defaults for --env, then every flag); build(args) -> (env, trainer,
# config dict) of a fresh or resumed run; main(argv=None) -> exit code
parse, build, main = CLI.parse, CLI.build, CLI.main

if __name__ == "__main__":
    ddpg.exit_process(main())
