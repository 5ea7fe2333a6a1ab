"""The on-policy actor-critic family (PPO, A2C / A3C): what its trainers share beyond
:mod:`~jaxrl_robot.agents.core`.

* :class:`ActorCriticConfig` — the hyper-parameters such an agent always has (run size, lanes,
  Gaussian actor and critic, Adam, γ, episode length) with their validation; an algorithm's
  config subclasses it, adds its own fields and extends ``validate``.
* :func:`make_actor_critic` — the Gaussian actor (σ broadcast to the action size) and critic;
  :func:`init_actor_critic`, :func:`sample_lanes`; :func:`lr_end_factor` of ``lr_schedule``.
* Episode-parameter schedules: :func:`schedule_tables`, :func:`schedule_values`,
  :func:`initial_env_params`, :func:`apply_schedule`.
* :func:`episode_sums` per iteration, for :func:`~jaxrl_robot.agents.core.chunk_metrics` at the end of a chunk.

The shell of a trainer (``core.setup``, ``core.RunState``, ``core.state_specs``, the optimiser,
``core.make_train_for``) is :mod:`~jaxrl_robot.agents.core`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Self

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State

from envs_mjx.config import ConfigError, check_choice, check_range
from jaxrl_robot.acting import per_lane_keys
from jaxrl_robot.agents.core import check_counts
from jaxrl_robot.networks import ACTIVATIONS, BN_MODES, Critic, GaussianActor, gaussian_sample
from jaxrl_robot.types import Transition

__all__ = [
    "LR_SCHEDULES",
    "ActorCriticConfig",
    "action_sigma",
    "apply_schedule",
    "episode_sums",
    "init_actor_critic",
    "initial_env_params",
    "lr_end_factor",
    "make_actor_critic",
    "sample_lanes",
    "schedule_tables",
    "schedule_values",
]

LR_SCHEDULES = ("constant", "linear")
"""The learning-rate schedules of :attr:`ActorCriticConfig.lr_schedule`."""


# ---- configuration ----------------------------------------------------------------------------
@dataclass(frozen=True)
class ActorCriticConfig:
    """Hyper-parameters shared by the actor-critic agents (defaults: the thesis's arm settings, except
    that a per-action field such as ``sigma`` defaults to one value, broadcast to any env's action size;
    the arm's per-action values are set by its presets, ``train/presets.py``).

    ``num_envs`` lanes (the K workers) each collect ``unroll_length`` (N) steps per iteration;
    the actor is Gaussian (fixed or learned σ, optional batch-norm), the critic a plain MLP,
    both trained with Adam.  Subclasses add the algorithm's fields, re-declare a field to change
    its default, and extend :meth:`validate`.
    """

    total_steps: int = 400_000
    """Environment step slots of the whole run, num_envs * unroll_length per iteration (rounded up
    to whole chunks of iterations). Where lanes idle after an early episode end (A2C), the steps
    taken (metric ``steps_taken``) can be fewer."""
    num_envs: int = 4
    """K: parallel lanes (workers); a multiple of the device count."""
    unroll_length: int = 8
    """N: steps (buffer slots) each lane collects per iteration."""
    actor_lr: float = 1e-4
    """Adam learning rate of the actor (α_π)."""
    critic_lr: float = 5e-4
    """Adam learning rate of the critic (α_v)."""
    gamma: float = 0.9
    """Discount factor γ."""
    sigma: tuple[float, ...] = (0.5,)
    """Policy standard deviation in action units: one value (broadcast to the env's action size) or one
    per action dimension. The default 0.5 suits any env with actions in [−1, 1]: it is fixed for the whole
    run unless ``learn_std``, so it sits below the initial σ of policies that learn theirs (brax's PPO
    ≈ 0.69 = softplus(0) + 0.001, Stable-Baselines3's 1) and within the thesis's fixed values (arm
    (0.8, 0.8, 0.1), Table 5.2; unicycle (0.1, 0.01), Table 5.3), which the presets set per env."""
    learn_std: bool = False
    """Learn a state-independent log-std starting at log(sigma) instead of a fixed σ."""
    state_std: bool = False
    """With learn_std: a state-dependent σ(s) = softplus(·) + 0.001 from a second output layer of
    the actor, starting at sigma (brax's PPO parametrisation)."""
    activation: str = "relu"
    """Hidden-layer activation of actor and critic: relu, swish (brax's PPO networks), tanh or elu."""
    actor_hidden: tuple[int, ...] = (200, 200)
    """Hidden layer widths of the actor."""
    critic_hidden: tuple[int, ...] = (200, 200)
    """Hidden layer widths of the critic."""
    batch_norm: bool = True
    """Batch-normalise the actor (batch statistics in training, moving averages when acting)."""
    bn_momentum: float = 0.999
    """Decay of the batch-norm moving averages, applied at every actor gradient step. Slow: with
    K = 4 lanes a batch holds 4 goals, and its statistics would drag the acting policy around
    (arm7 thesis preset: 2 % test success at 0.99; at 0.999 PPO 79 %, A2C 65 / 27 %, seeds 0 / 1)."""
    bn_mode: str = "renorm"
    """Actor batch-norm in training: 'renorm' — batch renormalisation (Ioffe, 2017): outputs equal
    the acting ones (moving averages) while gradients flow through the batch statistics;
    'batch' — plain batch-norm, whose trained policy (each few-lane mini-batch normalised by its
    own statistics) is not the acting one."""
    normalize_advantages: bool = True
    """Standardise advantages over each iteration's K·N transitions."""
    entropy_coef: float = 0.0
    """Entropy bonus coefficient in the actor objective."""
    max_grad_norm: float = 0.0
    """Clip gradients to this global norm (0: no clipping)."""
    lr_schedule: str = "constant"
    """Learning rates 'constant' (the thesis) or 'linear': annealed to 0 over the run's optimiser steps
    (purejaxrl's and CleanRL's ``anneal_lr``, Stable-Baselines3's linear schedule)."""
    reward_scale: float = 1.0
    """Multiply rewards by this before computing returns."""
    episode_length: int = 0
    """Time limit in steps (0: the environment's own ``episode_length``, else brax's default of 1000)."""

    @property
    def total_iterations(self) -> int:
        """Iterations of the whole run: ``ceil(total_steps / (K · N))``, at least 1."""
        return max(1, math.ceil(self.total_steps / (self.num_envs * self.unroll_length)))

    def validate(self) -> Self:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        check_counts(self, "total_steps", "num_envs", "unroll_length")
        check_range("actor_lr", self.actor_lr, 0.0, lo_open=True)
        check_range("critic_lr", self.critic_lr, 0.0, lo_open=True)
        check_range("gamma", self.gamma, 0.0, 1.0)
        check_range("bn_momentum", self.bn_momentum, 0.0, 1.0, hi_open=True)
        check_choice("bn_mode", self.bn_mode, BN_MODES)
        check_choice("activation", self.activation, tuple(ACTIVATIONS))
        if self.state_std and not self.learn_std:
            raise ConfigError("state_std=True needs learn_std=True (a state-dependent σ is learned)")
        check_range("entropy_coef", self.entropy_coef, 0.0)
        check_range("max_grad_norm", self.max_grad_norm, 0.0)
        check_choice("lr_schedule", self.lr_schedule, LR_SCHEDULES)
        check_range("reward_scale", self.reward_scale, 0.0, lo_open=True)
        check_range("episode_length", self.episode_length, 0)
        if not self.sigma:
            raise ConfigError("sigma=() must have at least one value")
        for i, s in enumerate(self.sigma):
            check_range(f"sigma[{i}]", s, 0.0, lo_open=True)
        for name in ("actor_hidden", "critic_hidden"):
            for i, w in enumerate(getattr(self, name)):
                check_range(f"{name}[{i}]", w, 1)
        return self

    def replace(self, **changes: Any) -> Self:
        """A copy with ``changes`` applied (the original is not modified)."""
        return dataclasses.replace(self, **changes)


# ---- networks -------------------------------------------------------------------------------------
def make_actor_critic(
    config: ActorCriticConfig, action_size: int, bn_axis_name: str | None = None, squash: bool = True
) -> tuple[GaussianActor, Critic]:
    """The Gaussian actor and the critic of ``config``; σ is broadcast to ``action_size``.

    ``bn_axis_name``: the mapped axis the actor's batch statistics are averaged over (the lanes'
    mesh axis when one batch spans every device's lanes), or None. ``squash``: ``tanh`` on the
    actor's mean (False: a linear mean, for actions squashed on the env's side).
    """
    actor = GaussianActor(
        action_size=action_size,
        hidden=tuple(config.actor_hidden),
        sigma=action_sigma(config, action_size),
        learn_std=config.learn_std,
        batch_norm=config.batch_norm,
        bn_momentum=config.bn_momentum,
        bn_mode=config.bn_mode,
        bn_axis_name=bn_axis_name,
        state_std=config.state_std,
        squash=squash,
        activation=config.activation,
    )
    return actor, Critic(hidden=tuple(config.critic_hidden), activation=config.activation)


def action_sigma(config: ActorCriticConfig, action_size: int) -> tuple[float, ...]:
    """``config.sigma`` with one value per action dimension (a single value is broadcast)."""
    sigma = tuple(config.sigma)
    if len(sigma) == 1:
        sigma = sigma * action_size
    if len(sigma) != action_size:
        raise ConfigError(f"sigma={config.sigma!r} must have 1 or action_size={action_size} values")
    return sigma


def lr_end_factor(config: ActorCriticConfig) -> float:
    """The learning rates' factor at the end of the run: 0 for ``lr_schedule='linear'``, else 1."""
    return 0.0 if config.lr_schedule == "linear" else 1.0


def init_actor_critic(
    key_actor: jax.Array, key_critic: jax.Array, actor: GaussianActor, critic: Critic, obs_size: int
) -> tuple[Any, Any, Any]:
    """``(actor params, actor batch_stats ({} without batch-norm), critic params)``."""
    dummy = jnp.zeros((1, obs_size), jnp.float32)
    actor_vars = actor.init(key_actor, dummy)
    return actor_vars["params"], actor_vars.get("batch_stats", {}), critic.init(key_critic, dummy)["params"]


def sample_lanes(key: jax.Array, lane_ids: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Gaussian actions ``[B, A]``, lane ``i`` drawing with ``fold_in(key, lane_ids[i])``."""
    return jax.vmap(gaussian_sample)(per_lane_keys(key, lane_ids), mean, log_std)


# ---- episode-parameter schedules --------------------------------------------------------------
def schedule_tables(
    schedule: tuple[tuple[float, str, float], ...], env: Env
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``name -> (starts [S], values [S, ...])`` sorted by start; validated against the env's params.

    ``schedule``: entries ``(start fraction of training, name in state.info["params"], value)``;
    every named parameter needs an entry starting at 0.0; values are broadcast to its shape.
    """
    if not schedule:
        return {}
    defaults = env.default_params() if hasattr(env, "default_params") else {}
    tables: dict[str, list] = {}
    for start, name, value in sorted(schedule, key=lambda e: e[0]):
        if name not in defaults:
            valid = ", ".join(sorted(defaults)) or "none"
            raise ConfigError(f"schedule: unknown episode parameter {name!r}; this env's parameters: {valid}")
        val = np.broadcast_to(np.asarray(value, np.float32), np.shape(defaults[name]))
        tables.setdefault(name, []).append((float(start), val))
    out = {}
    for name, entries in tables.items():
        if entries[0][0] != 0.0:
            raise ConfigError(f"schedule: parameter {name!r} needs an entry starting at 0.0")
        out[name] = (np.array([s for s, _ in entries], np.float32), np.stack([v for _, v in entries]))
    return out


def schedule_values(tables: dict, progress: jax.Array) -> dict[str, jax.Array]:
    """Piecewise-constant parameter values at ``progress`` in [0, 1]."""
    out = {}
    for name, (starts, values) in tables.items():
        idx = jnp.sum(jnp.asarray(starts) <= progress) - 1
        out[name] = jnp.asarray(values)[jnp.clip(idx, 0, len(starts) - 1)]
    return out


def initial_env_params(env: Env, tables: dict) -> dict[str, jax.Array] | None:
    """The env's default episode parameters with the schedule's values at progress 0 (None without a schedule)."""
    if not tables:
        return None
    params = dict(env.default_params())
    params.update(schedule_values(tables, jnp.asarray(0.0)))
    return params


def apply_schedule(env_state: State, tables: dict, progress: jax.Array) -> State:
    """``env_state`` ``[B]`` with the scheduled parameters at ``progress`` written into ``info["params"]``
    (same shapes and dtypes, so nothing recompiles)."""
    if not tables:
        return env_state
    params = dict(env_state.info["params"])
    for name, v in schedule_values(tables, progress).items():
        params[name] = jnp.broadcast_to(v, params[name].shape).astype(params[name].dtype)
    return env_state.replace(info={**env_state.info, "params": params})


# ---- metrics ----------------------------------------------------------------------------------
def episode_sums(traj: Transition) -> dict[str, jax.Array]:
    """Sums over the episodes that finished in ``traj`` ``[T, B]`` (this device's lanes):
    ``episodes`` and every episode metric (a metric shaped like ``done``, its final value)."""
    done = traj.done
    sums = {"episodes": jnp.sum(done)}
    for k, v in traj.metrics.items():
        if v.shape == done.shape:
            sums[k] = jnp.sum(jnp.where(done > 0, v, 0.0))
    return sums
