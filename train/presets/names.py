"""The preset names of each algorithm and how ``auto`` resolves; the env families presets are kept by."""

from __future__ import annotations

from jaxrl_robot import parallel
from train.presets.peers import BRAX_PPO, BRAX_SAC, _brax_task_of, playground_task

PPO_PRESETS = ("auto", "thesis", "cpu", "fast", "brax", "playground")
PRESETS = ("auto", "thesis", "cpu", "fast")
"""The presets of every algorithm; ``brax`` and ``playground`` are PPO's, DDPG's and TD3's (:data:`DDPG_PRESETS`)."""


def resolve_preset(name: str, env_name: str | None = None, algo: str = "ppo") -> str:
    """``auto`` → ``brax`` for a PPO run on a task of :data:`BRAX_PPO` or a DDPG / TD3 run on one of
    :data:`BRAX_SAC`, ``playground`` for such a run on a ``playground:<Name>`` env with MuJoCo Playground's
    settings (:func:`playground_task`), else ``fast`` on an accelerator backend, else ``cpu``; other names
    unchanged (validated: ``brax`` and ``playground`` are PPO's, DDPG's and TD3's)."""
    valid, table = {"ppo": (PPO_PRESETS, BRAX_PPO), "ddpg": (DDPG_PRESETS, BRAX_SAC), "td3": (DDPG_PRESETS, BRAX_SAC),
                    "sac": (DDPG_PRESETS, BRAX_SAC)}.get(algo, (PRESETS, {}))  # fmt: skip
    if name not in valid:
        raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(valid)}")
    if name == "auto":
        if env_name is not None and _brax_task_of(env_name, table):
            return "brax"
        if playground_task(env_name, algo):
            return "playground"
        return "fast" if parallel.on_accelerator() else "cpu"
    return name


def _family(env_name: str) -> str:
    """``arm``, ``tracking``, ``racing`` or ``other``: the family of ``env_name`` whose presets it takes."""
    base = env_name.split(":")[-1]
    if base in ("arm7", "arm7_precise"):
        return "arm"
    if base in ("unicycle", "scara"):
        return "tracking"
    if base == "racecar":
        return "racing"
    return "other"


def _precise_arm(env_name: str) -> bool:
    """Whether ``env_name`` is ``arm7_precise`` (1 cm goal threshold): PPO and A2C/A3C learn σ there
    (why: ``benchmarks/results/why-presets.md`` § PPO arm7_precise)."""
    return env_name.split(":")[-1] == "arm7_precise"


DDPG_PRESETS = ("auto", "thesis", "cpu", "fast", "brax", "playground")
"""DDPG's and TD3's presets: ``brax`` is :func:`brax_sac_ddpg_config` of the env's :data:`BRAX_SAC` task
(hopper's row for other envs, with the env's own episode length); ``playground`` is
:func:`playground_sac_ddpg_config` of a ``playground:<Name>`` env."""
