"""The core every trainer is built on, on-policy (PPO, A2C / A3C) and off-policy (DDPG, TD3, SAC) alike.

* :func:`setup` → :class:`Setup` — the shell of ``make_trainer``: the config validated, the mesh and
  the lanes per device, the time limit, the env wrapped for training, iteration and chunk counts, the
  initial env states (:meth:`Setup.reset`), the chunk split over the lanes (:meth:`Setup.shard`) and
  the :class:`~jaxrl_robot.types.Trainer` (:meth:`Setup.trainer`).
* :class:`RunState` — the fields every train state has (lanes' env states, key, iteration count);
  an algorithm's state subclasses it.  :func:`state_specs` — its partition specs; :func:`cast_like`.
* :func:`make_optimizer`, :func:`apply_gradients` — Adam (clipped, optionally annealed) and one step.
* Metrics of a chunk: :func:`episode_means` of every device's episode sums, :func:`chunk_metrics`.
* :func:`make_train_for` — an algorithm's ``make_train(config, env) -> train(key)`` from its
  ``make_trainer``: the whole run under ``lax.scan``.
* :func:`check_counts` — the integer-count check of every config (:mod:`jaxrl_robot.validation`'s).

The config a trainer passes to :func:`setup` has ``validate()``, ``num_envs``, ``unroll_length``,
``episode_length`` and ``total_iterations`` (``on_policy.ActorCriticConfig``,
``off_policy.OffPolicyConfig``).  Functions that use ``parallel.pmean`` / ``psum`` are called inside
``parallel.shard_lanes``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env, State
from flax import struct

from envs_mjx.base import default_episode_length, steps_mjx_physics, wrap_for_training
from jaxrl_robot import parallel
from jaxrl_robot.types import Metrics, Policy, Trainer
from jaxrl_robot.validation import ConfigError, check_counts

__all__ = [
    "RunState",
    "Setup",
    "apply_gradients",
    "cast_like",
    "check_counts",
    "chunk_metrics",
    "episode_means",
    "make_optimizer",
    "make_train_for",
    "setup",
    "state_specs",
]


# ---- the shell of make_trainer ----------------------------------------------------------------
class Setup(NamedTuple):
    """What a trainer derives from its config, env and mesh before it builds its functions.

    Attributes:
      mesh: device mesh the lanes are split over (mesh axis ``parallel.LANES``).
      env: the env wrapped by ``envs_mjx.wrap_for_training`` (lanes, time limit, true auto-reset).
      obs_size, action_size: of the unwrapped env.
      num_envs: K, lanes of all devices; local_lanes: lanes of one device.
      episode_length: T, the time limit.
      steps_per_iteration: env step slots of one iteration (``K · N`` unless the trainer says otherwise).
      iterations_per_update: iterations per ``update`` call (one chunk).
      num_updates: chunks of the whole run, ``ceil(total_iterations / iterations_per_update)``.
      lane_map: the lane map's implementation (``parallel.lane_map_impl`` of the mesh and of whether the env
        steps MJX physics, ``envs_mjx.base.steps_mjx_physics``); every ``shard_lanes`` of the run takes it.
    """

    mesh: jax.sharding.Mesh
    env: Env
    obs_size: int
    action_size: int
    num_envs: int
    local_lanes: int
    episode_length: int
    steps_per_iteration: int
    iterations_per_update: int
    num_updates: int
    lane_map: str

    def reset(self, key: jax.Array, params: Callable[[], Any] | None = None) -> State:
        """Env states ``[K]`` of ``split(key, K)``, lanes split over the mesh; ``params`` builds the
        episode parameters (called inside the lanes' ``shard_map``; None: the env's defaults)."""

        def reset_lanes(keys: jax.Array) -> State:
            state = self.env.reset(keys, None if params is None else params())
            # plain arrays where an env's reset gives weakly typed ones (brax's reward and done), as a chunk
            # returns them: a jitted chunk's second call then reuses its first program
            return cast_like(state, state)

        lanes = parallel.P(parallel.LANES)
        return self.map_lanes(reset_lanes, lanes, lanes)(jax.random.split(key, self.num_envs))

    def map_lanes(self, fn: Callable[..., Any], in_specs: Any, out_specs: Any) -> Callable[..., Any]:
        """``parallel.shard_lanes`` of ``fn`` over this run's mesh with its :attr:`lane_map`."""
        return parallel.shard_lanes(fn, self.mesh, in_specs, out_specs, impl=self.lane_map)

    def shard(self, chunk: Callable[[Any], tuple[Any, Metrics]], specs: Any) -> Callable[[Any], tuple[Any, Metrics]]:
        """``chunk`` (state -> (state, scalar metrics)) split over the lanes with the state's partition ``specs``."""
        return self.map_lanes(chunk, (specs,), (specs, parallel.P()))

    def trainer(
        self, init: Callable, update: Callable, policy: Callable[[Any], Policy], sample_policy: Callable | None = None
    ) -> Trainer:
        """The :class:`~jaxrl_robot.types.Trainer` of these functions with this run's counts."""
        steps = self.steps_per_iteration * self.iterations_per_update
        return Trainer(init, update, policy, self.num_updates, steps, sample_policy)


def setup(
    config: Any,
    env: Env,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int = 1,
    *,
    steps_per_iteration: Callable[[int], int] | None = None,
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
      steps_per_iteration: ``T -> env step slots of one iteration`` (default ``num_envs · unroll_length``).
      wrap_options: further keywords of ``wrap_for_training`` (``reset_refresh``, ``reset_group``,
        ``lane_group``; a ``lane_group`` must divide the lanes per device).
    """
    config.validate()
    if iterations_per_update < 1:
        raise ConfigError(f"iterations_per_update={iterations_per_update} must be >= 1")
    mesh = parallel.lane_mesh() if mesh is None else mesh
    local_lanes = parallel.local_lane_count(config.num_envs, mesh)
    episode_length = int(config.episode_length or default_episode_length(env))
    lane_group = wrap_options.get("lane_group", 0)
    if lane_group and local_lanes % lane_group:
        raise ConfigError(f"lane_group={lane_group} must divide the lanes per device ({local_lanes})")
    steps = config.num_envs * config.unroll_length
    if steps_per_iteration is not None:
        steps = steps_per_iteration(episode_length)
    return Setup(
        mesh=mesh,
        env=wrap_for_training(env, episode_length=episode_length, **wrap_options),
        obs_size=int(env.observation_size),
        action_size=int(env.action_size),
        num_envs=config.num_envs,
        local_lanes=local_lanes,
        episode_length=episode_length,
        steps_per_iteration=steps,
        iterations_per_update=iterations_per_update,
        num_updates=math.ceil(config.total_iterations / iterations_per_update),
        lane_map=lane_map_of(env, mesh),
    )


def lane_map_of(env: Any, mesh: jax.sharding.Mesh) -> str:
    """The lane map a run of ``env`` (unwrapped or wrapped) over ``mesh`` takes: ``parallel.lane_map_impl`` of the
    mesh and of whether the env steps MJX physics (``envs_mjx.base.steps_mjx_physics``)."""
    return parallel.lane_map_impl(mesh, mjx_physics=steps_mjx_physics(env))


@struct.dataclass(kw_only=True)
class RunState:
    """The part of a train state that every trainer built on :func:`setup` has; an algorithm's state
    (``PPOState``, ``A2CState``, ``A3CState``, ``off_policy.OffPolicyState``) subclasses it and adds its
    own fields, which come first in the constructor's positional order (these three are keyword-only).

    Attributes:
      env_state: ``State [K]`` of the wrapped env (lanes split over devices).
      key: PRNG key of the run.
      iteration: ``[]`` int32 iterations (A2C / A3C: rounds; DDPG: cycles or unroll phases) done.
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


# ---- optimiser --------------------------------------------------------------------------------
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


# ---- metrics ----------------------------------------------------------------------------------
def episode_means(sums: dict[str, jax.Array], prefix: str = "") -> Metrics:
    """Every device's episode ``sums`` (psum; ``episodes`` and per-episode totals) -> ``episodes`` and
    the per-episode means (NaN where no episode finished), names prefixed with ``prefix``."""
    sums = dict(parallel.psum(sums))
    episodes = sums.pop("episodes")
    out = {prefix + "episodes": episodes}
    for k, v in sums.items():
        out[prefix + k] = jnp.where(episodes > 0, v / jnp.maximum(episodes, 1.0), jnp.nan)
    return out


def chunk_metrics(metrics: Metrics, sums: dict[str, jax.Array]) -> Metrics:
    """Scalar metrics of a chunk from per-iteration values ``[I]`` (inside ``shard_lanes``).

    ``metrics``: averaged over the chunk's iterations.  ``sums``: the episode sums of each iteration
    (``on_policy.episode_sums``), totalled over the chunk and the devices; every episode metric
    becomes its mean over the finished episodes (:func:`episode_means`), ``episodes`` their number.
    """
    out = {k: jnp.mean(v) for k, v in metrics.items()}
    out.update(episode_means(jax.tree.map(lambda x: jnp.sum(x, axis=0), sums)))
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
