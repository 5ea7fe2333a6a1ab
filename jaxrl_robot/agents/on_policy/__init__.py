"""The on-policy actor-critic family (PPO, A2C / A3C): what its trainers share beyond
:mod:`~jaxrl_robot.agents.core`.

* :class:`ActorCriticConfig` (:mod:`.config`) — the hyper-parameters such an agent always has (run
  size, lanes, Gaussian actor and critic, Adam, γ, episode length) with their validation; an
  algorithm's config subclasses it, adds its own fields and extends ``validate``; :func:`lr_end_factor`
  of ``lr_schedule``.
* :mod:`.actor_critic` — :func:`make_actor_critic` (the Gaussian actor, σ broadcast to the action size
  by :func:`action_sigma`, and the critic), :func:`init_actor_critic`, :func:`sample_lanes`.
* :mod:`.rollout` — :func:`collect` (every lane acting with a per-lane memory, new episodes starting
  from :class:`StartStates`: zeros or the LSTM start-state table), :func:`sequence_resets`,
  :func:`update_start_table`; :func:`collect_until_done` (A2C's local buffers); :func:`episode_sums`
  per iteration, for :func:`~jaxrl_robot.agents.core.chunk_metrics` at the end of a chunk.
* :mod:`.update` — the update steps: mini-batches of whole sequences or segments, GAE and λ-returns per
  lane, standardised advantages, mini-batch epochs (:func:`sgd_steps`), :func:`gradient_step`,
  :func:`policy_kl`.
* :mod:`.schedule` — episode-parameter schedules: :func:`schedule_tables`, :func:`schedule_values`,
  :func:`initial_env_params`, :func:`apply_schedule`.

The shell of a trainer (``core.setup``, ``core.RunState``, ``core.state_specs``, the optimiser,
``core.make_train_for``) is :mod:`~jaxrl_robot.agents.core`.
"""

from jaxrl_robot.agents.on_policy.actor_critic import action_sigma, init_actor_critic, make_actor_critic, sample_lanes
from jaxrl_robot.agents.on_policy.config import LR_SCHEDULES, ActorCriticConfig, lr_end_factor
from jaxrl_robot.agents.on_policy.rollout import (
    Rollout,
    StartStates,
    collect,
    collect_until_done,
    episode_sums,
    sequence_resets,
    update_start_table,
)
from jaxrl_robot.agents.on_policy.schedule import apply_schedule, initial_env_params, schedule_tables, schedule_values
from jaxrl_robot.agents.on_policy.update import (
    draw_segments,
    draw_sequences,
    flat,
    gradient_step,
    lane_gae,
    lane_lambda_returns,
    policy_kl,
    sgd_steps,
    standardize,
)

__all__ = [
    "LR_SCHEDULES",
    "ActorCriticConfig",
    "Rollout",
    "StartStates",
    "action_sigma",
    "apply_schedule",
    "collect",
    "collect_until_done",
    "draw_segments",
    "draw_sequences",
    "episode_sums",
    "flat",
    "gradient_step",
    "init_actor_critic",
    "initial_env_params",
    "lane_gae",
    "lane_lambda_returns",
    "lr_end_factor",
    "make_actor_critic",
    "policy_kl",
    "sample_lanes",
    "schedule_tables",
    "schedule_values",
    "sequence_resets",
    "sgd_steps",
    "standardize",
    "update_start_table",
]
