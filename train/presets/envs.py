"""Env settings that go with a preset: the tracking curriculum, the unicycle's a_p and the racing env."""

from __future__ import annotations

from envs_mjx.unicycle import UnicycleConfig
from train.presets.names import _family, resolve_preset


def tracking_schedule(rsi_end: float = 2 / 3, narrow_end: float = 5 / 6, origin_start: float | None = None) -> tuple:
    """Thesis §5.5 curriculum as a PPO ``schedule`` for the tracking envs' episode parameters.

    Until ``rsi_end`` of training: start anywhere on the reference, early-termination limit 20;
    then from ¼-½ of the reference, limit 15; from ``narrow_end`` on: from the first quarter,
    limit 10 (episodes 0-2000, 2000-2500, 2500-3000 of 3000); from ``origin_start`` on (if given):
    from ``t = 0`` (the LSTM run of §5.7: 2000 / 400 / 400 / 200 episodes).
    """
    stages = [(0.0, 0.0, 1.0, 20.0), (rsi_end, 0.25, 0.5, 15.0), (narrow_end, 0.0, 0.25, 10.0)]
    if origin_start is not None:
        stages.append((origin_start, 0.0, 0.0, 10.0))
    out = []
    for start, lo, hi, limit in stages:
        out += [(start, "start_lo", lo), (start, "start_hi", hi), (start, "et_limit", limit)]
    return tuple(out)


def ppo_env_overrides(
    name: str, env_name: str, pretrain: str = "none", policy: str = "mlp", trajectory: str | None = None
) -> dict:
    """Env settings a preset needs (the user's ``--env-config`` goes on top); ``pretrain``,
    ``policy``: PPO's ``--pretrain`` and ``--policy``; ``trajectory``: the unicycle's (None: the
    env's default), which with them picks the unicycle's ``a_p`` (:func:`unicycle_a_p`).

    ``arm7`` under ``thesis`` and ``cpu`` runs in ``kinematic`` mode — the thesis's setting, and
    the one that is fast on a CPU: MJX's ``pd`` physics of the 7-link chain compiles and runs
    slowly on CPUs (see the foundation benchmark). ``fast`` keeps the env's default (``pd``).

    ``unicycle`` trains with a sharper position term than Eq. 3.23's ``a_p = 1`` (:func:`unicycle_a_p`;
    why: ``benchmarks/results/why-presets.md`` § unicycle a_p); ``thesis`` keeps a_p = 1.
    """
    name = resolve_preset(name)
    if _family(env_name) == "arm" and name in ("thesis", "cpu"):
        return {"mode": "kinematic"}
    if env_name.split(":")[-1] == "unicycle" and name in UNICYCLE_A_P:
        method = "two-stage" if pretrain == "action-search" else policy
        return {"a_p": unicycle_a_p(name, method, trajectory)}
    return {}


UNICYCLE_A_P = {"cpu": 100.0, "fast": 300.0}
"""Eq. 3.23's ``a_p`` of the unicycle under the ``cpu`` and ``fast`` presets (every algorithm), except
:data:`UNICYCLE_A_P_FAST` (why: ``benchmarks/results/why-presets.md`` § unicycle a_p)."""

UNICYCLE_A_P_FAST = {("two-stage", "sine"): 1000.0, ("lstm", "sine"): 1000.0, ("distributed", "sine"): 1000.0}
"""``(method, trajectory) -> a_p`` under ``fast`` where 1000 tracked better than 300
(``benchmarks/results/why-presets.md`` § unicycle a_p)."""


def unicycle_a_p(name: str, method: str, trajectory: str | None = None) -> float:
    """The unicycle's ``a_p`` under preset ``name`` (``cpu`` or ``fast``) for ``method`` (PPO's
    ``mlp``, ``lstm``, ``two-stage``; ``ddpg``, ``distributed``, ``td3``, ``distributed-td3``) on
    ``trajectory`` (None: the env's default)."""
    trajectory = trajectory or UnicycleConfig.trajectory
    if name == "fast":
        return UNICYCLE_A_P_FAST.get((method, trajectory), UNICYCLE_A_P[name])
    return UNICYCLE_A_P[name]


RACING_ENV = {"road": "random", "opponent_speeds": True, "opponent_offsets": True, "distance_scale": "log",
              "end_on_collision": True}
"""``racecar`` under ``cpu`` and ``fast``: train on a bank of generated roads, see the opponents' closing
speeds and offsets across the road, log-scaled distances, and end an episode at a collision
(why: ``benchmarks/results/why-presets.md`` § racing env)."""


def ddpg_env_overrides(name: str, env_name: str, method: str = "ddpg", trajectory: str | None = None) -> dict:
    """Env settings a DDPG preset needs (the user's ``--env-config`` goes on top): a sharper reward.
    ``method`` (``ddpg``, ``distributed``, ``td3``, ``distributed-td3``) and ``trajectory`` pick the
    unicycle's ``a_p`` (:func:`unicycle_a_p`).

    ``unicycle``: the sharper position term of :func:`ppo_env_overrides` (:data:`UNICYCLE_A_P`).
    ``scara``: ``cpu`` Eq. 3.22's coefficient 50 instead of 2; ``fast`` 1000 and the ``extended``
    observation (the error to the next reference point).  ``racecar`` under ``cpu`` and ``fast``:
    :data:`RACING_ENV`.  ``thesis`` keeps Eq. 3.22-3.23.  Why: ``benchmarks/results/why-presets.md``
    § unicycle a_p, § scara reward.
    """
    name = resolve_preset(name)
    if name not in ("cpu", "fast"):
        return {}
    scara = {"cpu": {"reward_coef": 50.0}, "fast": {"reward_coef": 1000.0, "observation": "extended"}}[name]
    sharper = {"unicycle": {"a_p": unicycle_a_p(name, method, trajectory)}, "scara": scara, "racecar": RACING_ENV}
    return sharper.get(env_name.split(":")[-1], {})
