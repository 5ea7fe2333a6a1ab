"""The pieces every on-policy actor-critic trainer (PPO, A2C / A3C) shares.

* :class:`ActorCriticConfig` — the hyper-parameters such an agent always has (run size, lanes,
  Gaussian actor and critic, Adam, γ, episode length) with their validation; an algorithm's
  config subclasses it, adds its own fields and extends ``validate``.
* :func:`make_actor_critic` — the Gaussian actor (σ broadcast to the action size) and critic.
* :func:`make_optimizer`, :func:`apply_gradients` — Adam (clipped, optionally annealed) and one step
  (every algorithm's optimiser, DDPG's included); :func:`lr_end_factor` of ``lr_schedule``.
* :func:`setup` → :class:`Setup` — the shell of ``make_trainer``: the config validated, lanes per
  device, the env wrapped for training, iteration and chunk counts, the initial env states
  (:meth:`Setup.reset`) and the :class:`~jaxrl_robot.types.Trainer` (:meth:`Setup.trainer`).
* :class:`RunState` — the fields every such train state has (lanes' env states, key, iteration
  count); an algorithm's state subclasses it and adds its networks and optimisers.
* :func:`init_actor_critic`, :func:`sample_lanes`, :func:`cast_like`, :func:`state_specs`.
* Episode-parameter schedules: :func:`schedule_tables`, :func:`schedule_values`,
  :func:`initial_env_params`, :func:`apply_schedule`.
* Metrics of a chunk: :func:`episode_sums` per iteration, :func:`chunk_metrics` over the chunk.
* :func:`make_train_for` — an algorithm's ``make_train(config, env) -> train(key)`` from its
  ``make_trainer``: the whole run under ``lax.scan``.

A trainer built from these runs its lanes inside ``parallel.shard_lanes``: functions that use
``parallel.pmean`` / ``psum`` are called there.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple, Self

import jax
import jax.numpy as jnp
import numpy as np
import optax
from brax.envs.base import Env, State
from flax import struct

from envs_mjx.base import default_episode_length, wrap_for_training
from envs_mjx.config import ConfigError, check_choice, check_range
from jaxrl_robot import parallel
from jaxrl_robot.acting import per_lane_keys
from jaxrl_robot.networks import ACTIVATIONS, BN_MODES, Critic, GaussianActor, gaussian_sample
from jaxrl_robot.types import Metrics, Policy, Trainer, Transition

__all__ = [
    "LR_SCHEDULES",
    "ActorCriticConfig",
    "RunState",
    "action_sigma",
    "Setup",
    "apply_gradients",
    "apply_schedule",
    "cast_like",
    "check_counts",
    "chunk_metrics",
    "episode_sums",
    "init_actor_critic",
    "initial_env_params",
    "make_actor_critic",
    "lr_end_factor",
    "make_optimizer",
    "make_train_for",
    "sample_lanes",
    "schedule_tables",
    "schedule_values",
    "setup",
    "state_specs",
]

LR_SCHEDULES = ("constant", "linear")
"""The learning-rate schedules of :attr:`ActorCriticConfig.lr_schedule`."""


# ---- configuration ----------------------------------------------------------------------------
def check_counts(config: Any, *names: str) -> None:
    """Raise ``ConfigError`` unless each field in ``names`` is an integer ``>= 1``."""
    for name in names:
        value = getattr(config, name)
        check_range(name, value, 1)
        if int(value) != value:
            raise ConfigError(f"{name}={value!r} must be an integer")


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


# ---- networks and optimiser -------------------------------------------------------------------
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


def make_optimizer(
    lr: float, max_grad_norm: float, end_factor: float = 1.0, decay_steps: int = 1
) -> optax.GradientTransformation:
    """Adam with step size ``lr`` falling linearly to ``end_factor · lr`` over ``decay_steps`` of its own
    steps and then held (constant when ``end_factor`` is 1), after clipping the gradient to the
    global norm ``max_grad_norm`` when it is positive."""
    if end_factor < 1.0:
        lr = optax.linear_schedule(lr, lr * end_factor, max(int(decay_steps), 1))
    adam = optax.adam(lr)
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), adam) if max_grad_norm > 0 else adam


def apply_gradients(tx: optax.GradientTransformation, grads: Any, opt_state: Any, params: Any) -> tuple[Any, Any]:
    """One optimiser step: ``(new params, new opt_state)``."""
    updates, opt_state = tx.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state


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


# ---- the shell of make_trainer ----------------------------------------------------------------
class Setup(NamedTuple):
    """What a trainer derives from its config, env and mesh before it builds its functions.

    Attributes:
      mesh: device mesh the lanes are split over (mesh axis ``parallel.LANES``).
      env: the env wrapped by ``envs_mjx.wrap_for_training`` (lanes, time limit, true auto-reset).
      obs_size, action_size: of the unwrapped env.
      num_envs: K, lanes of all devices; local_lanes: lanes of one device.
      steps_per_iteration: env step slots of one iteration, ``K · N``.
      iterations_per_update: iterations per ``update`` call (one chunk).
      num_updates: chunks of the whole run, ``ceil(total_iterations / iterations_per_update)``.
    """

    mesh: jax.sharding.Mesh
    env: Env
    obs_size: int
    action_size: int
    num_envs: int
    local_lanes: int
    steps_per_iteration: int
    iterations_per_update: int
    num_updates: int

    def reset(self, key: jax.Array, params: Callable[[], Any] | None = None) -> State:
        """Env states ``[K]`` of ``split(key, K)``, lanes split over the mesh; ``params`` builds the
        episode parameters (called inside the lanes' ``shard_map``; None: the env's defaults)."""

        def reset_lanes(keys: jax.Array) -> State:
            return self.env.reset(keys, None if params is None else params())

        lanes = parallel.P(parallel.LANES)
        return parallel.shard_lanes(reset_lanes, self.mesh, lanes, lanes)(jax.random.split(key, self.num_envs))

    def trainer(
        self, init: Callable, update: Callable, policy: Callable[[Any], Policy], sample_policy: Callable | None = None
    ) -> Trainer:
        """The :class:`~jaxrl_robot.types.Trainer` of these functions with this run's counts."""
        steps = self.steps_per_iteration * self.iterations_per_update
        return Trainer(init, update, policy, self.num_updates, steps, sample_policy)


def setup(
    config: ActorCriticConfig,
    env: Env,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int = 1,
    **wrap_options: Any,
) -> Setup:
    """Validate ``config`` and derive the :class:`Setup` of a run (raises ``ConfigError``).

    Args:
      config: the trainer's hyper-parameters (validated here).
      env: an *unbatched* ``brax.envs.base.Env``; wrapped with ``envs_mjx.wrap_for_training``
        with the time limit ``config.episode_length`` (0: ``envs_mjx.base.default_episode_length(env)``:
        ``env.episode_length``, else 1000).
      mesh: device mesh from ``parallel.lane_mesh`` (default: all devices).
      iterations_per_update: iterations per ``update`` call (one chunk), ``>= 1``.
      wrap_options: further keywords of ``wrap_for_training`` (``reset_refresh``, ``reset_group``,
        ``lane_group``; a ``lane_group`` must divide the lanes per device).
    """
    config.validate()
    if iterations_per_update < 1:
        raise ConfigError(f"iterations_per_update={iterations_per_update} must be >= 1")
    mesh = parallel.lane_mesh() if mesh is None else mesh
    local_lanes = parallel.local_lane_count(config.num_envs, mesh)
    episode_length = config.episode_length or default_episode_length(env)
    lane_group = wrap_options.get("lane_group", 0)
    if lane_group and local_lanes % lane_group:
        raise ConfigError(f"lane_group={lane_group} must divide the lanes per device ({local_lanes})")
    return Setup(
        mesh=mesh,
        env=wrap_for_training(env, episode_length=int(episode_length), **wrap_options),
        obs_size=int(env.observation_size),
        action_size=int(env.action_size),
        num_envs=config.num_envs,
        local_lanes=local_lanes,
        steps_per_iteration=config.num_envs * config.unroll_length,
        iterations_per_update=iterations_per_update,
        num_updates=math.ceil(config.total_iterations / iterations_per_update),
    )


@struct.dataclass(kw_only=True)
class RunState:
    """The part of a train state that every trainer built on :func:`setup` has; an algorithm's state
    (``PPOState``, ``A2CState``, ``A3CState``) subclasses it and adds its own fields, which come
    first in the constructor's positional order (these three are keyword-only).

    Attributes:
      env_state: ``State [K]`` of the wrapped env (lanes split over devices).
      key: PRNG key of the run.
      iteration: ``[]`` int32 iterations (A2C / A3C: rounds) done.
    """

    env_state: State
    key: jax.Array
    iteration: jax.Array


def state_specs(cls: type, **specs: Any) -> Any:
    """A ``cls`` (a ``flax.struct.dataclass``) of partition specs: ``specs`` by field, every
    other field replicated (``parallel.P()``), as ``shard_lanes`` takes them."""
    return cls(**{f.name: specs.get(f.name, parallel.P()) for f in dataclasses.fields(cls)})


def cast_like(tree: Any, reference: Any) -> Any:
    """``tree`` with every leaf cast to the dtype of ``reference``'s leaf (drops weak types, so a
    jitted chunk whose state passes through an env never retraces)."""
    return jax.tree.map(lambda x, r: jnp.asarray(x).astype(r.dtype), tree, reference)


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


def chunk_metrics(metrics: Metrics, sums: dict[str, jax.Array]) -> Metrics:
    """Scalar metrics of a chunk from per-iteration values ``[I]`` (inside ``shard_lanes``).

    ``metrics``: averaged over the chunk's iterations.  ``sums``: :func:`episode_sums` of each
    iteration, totalled over the chunk and the devices; every episode metric becomes its mean
    over the finished episodes (NaN where none finished), ``episodes`` their number.
    """
    out = {k: jnp.mean(v) for k, v in metrics.items()}
    sums = parallel.psum(jax.tree.map(lambda x: jnp.sum(x, axis=0), sums))
    episodes = sums.pop("episodes")
    out["episodes"] = episodes
    for k, v in sums.items():
        out[k] = jnp.where(episodes > 0, v / jnp.maximum(episodes, 1.0), jnp.nan)
    return out


def make_train_for(make_trainer: Callable[..., Trainer]) -> Callable[..., Callable[[jax.Array], tuple[Any, Metrics]]]:
    """The ``make_train`` of a trainer factory: ``make_train(config, env, **options) -> train``.

    ``train(key) -> (final state, metrics [num_updates])`` runs ``init`` and then every ``update``
    of ``make_trainer(config, env, **options)`` (keywords such as ``mesh`` and
    ``iterations_per_update``) under ``lax.scan``: the whole run, pure and jittable;
    ``jax.jit(jax.vmap(train))(keys)`` trains one agent per key.
    """

    def make_train(config: Any, env: Env, **options: Any) -> Callable[[jax.Array], tuple[Any, Metrics]]:
        trainer = make_trainer(config, env, **options)

        def train(key: jax.Array) -> tuple[Any, Metrics]:
            state = trainer.init(key)
            return jax.lax.scan(lambda s, _: trainer.update(s), state, None, length=trainer.num_updates)

        return train

    make_train.__module__, make_train.__qualname__ = make_trainer.__module__, "make_train"
    make_train.__doc__ = make_train_for.__doc__
    return make_train
