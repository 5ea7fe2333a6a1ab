"""Test episodes and their summaries.

* :func:`run_test_episodes` — ``E`` independent episodes (vmapped, one ``lax.scan``) of an
  *unbatched* env with a policy (the mean action, or :func:`sampling_policy`'s draws);
  returns every episode's final metrics.
* :func:`two_policies` — one batch of episodes, the first ``n`` acting with one policy and the rest
  with another (both evaluation modes in one rollout).
* :func:`summarize_episodes` — success rate, mean extra distance (arm7, thesis §4.1.3) and
  mean return.
* :func:`precision_summary` — success at tighter goal thresholds (5, 2, 1 cm) from the episodes'
  closest approach to the goal, and that distance's distribution.
* :func:`tracking_error_sums` — per-axis sums of absolute tracking errors over one test
  episode (Tables 4.3-4.5, 5.4-5.7), with the mean per step and the number of steps.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env

from envs_mjx import backend
from jaxrl_robot.networks import gaussian_sample
from jaxrl_robot.types import Policy, RecurrentPolicy, as_recurrent

__all__ = [
    "PRECISION_THRESHOLDS",
    "freeze",
    "precision_summary",
    "run_test_episodes",
    "sampling_policy",
    "summarize_episodes",
    "tracking_error_sums",
    "two_policies",
]

PRECISION_THRESHOLDS = (0.05, 0.02, 0.01)
"""Goal thresholds (m) at which :func:`precision_summary` reports success."""


def sampling_policy(
    dist: Callable[[Any, jax.Array], tuple[Any, tuple[jax.Array, jax.Array]]],
    carry: Any,
    key: jax.Array,
    to_env: Callable[[jax.Array], jax.Array] = lambda a: a,
) -> RecurrentPolicy:
    """A :class:`RecurrentPolicy` that draws its actions from a diagonal Gaussian.

    Args:
      dist: ``(memory, obs [E, D]) -> (memory, (mean, log_std) [E, A])`` (``memory`` ``()`` for a
        feed-forward policy).
      carry: the memory an episode starts from.
      key: a raw PRNG key (``[2]`` uint32); a batch of episodes shares one stream of keys and draws
        one normal per episode and action dimension at each step.
      to_env: applied to the sample before the env receives it (e.g. ``jnp.tanh`` or a clip).
    """

    def step(c: tuple[Any, jax.Array], obs: jax.Array) -> tuple[tuple[Any, jax.Array], jax.Array]:
        memory, keys = c
        nxt, sub = jax.random.split(keys.reshape(-1, keys.shape[-1])[0])
        memory, (mean, log_std) = dist(memory, obs)
        return (memory, jnp.broadcast_to(nxt, keys.shape)), to_env(gaussian_sample(sub, mean, log_std))

    return RecurrentPolicy((carry, key), step)


def two_policies(first: Policy | RecurrentPolicy, second: Policy | RecurrentPolicy, n: int) -> RecurrentPolicy:
    """A :class:`RecurrentPolicy` of ``2n`` episodes: episodes ``0 … n−1`` act with ``first``, ``n … 2n−1``
    with ``second``, each half keeping its own policy's memory, so one :func:`run_test_episodes` call of
    ``2n`` episodes evaluates both (half the sequential env steps of two calls).

    ``obs [2n, D] -> action [2n, A]``; the carry is the pair of both policies' carries over all ``2n``
    episodes (each policy reads and advances its own half).
    """
    a, b = as_recurrent(first), as_recurrent(second)
    head = lambda tree: jax.tree.map(lambda x: x[:n], tree)  # noqa: E731
    tail = lambda tree: jax.tree.map(lambda x: x[n:], tree)  # noqa: E731

    def step(carry: tuple[Any, Any], obs: jax.Array) -> tuple[tuple[Any, Any], jax.Array]:
        ca, cb = carry
        na, act_a = a.step(head(ca), obs[:n])
        nb, act_b = b.step(tail(cb), obs[n:])
        ca = jax.tree.map(lambda new, old: jnp.concatenate([new, old[n:]]), na, ca)
        cb = jax.tree.map(lambda new, old: jnp.concatenate([old[:n], new]), nb, cb)
        return (ca, cb), jnp.concatenate([act_a, act_b])

    return RecurrentPolicy((a.carry, b.carry), step)


def freeze(live: jax.Array, old: Any, new: Any) -> Any:
    """``new`` where ``live [E]`` > 0, else ``old``: a pytree of ``[E, ...]`` leaves, lane by lane (a MuJoCo Warp
    data's fields shared by all lanes, without a lane axis, are ``old``'s: ``envs_mjx.backend.select``)."""
    return backend.select(live > 0, new, old)


def run_test_episodes(
    key: jax.Array,
    env: Env,
    policy: Policy | RecurrentPolicy,
    num_episodes: int,
    episode_length: int | None = None,
    params: Any = None,
) -> dict[str, jax.Array]:
    """Run ``num_episodes`` episodes from fresh random starts (and goals) with ``policy``.

    Each episode runs until its first ``done`` or ``episode_length`` steps; its metrics are
    taken at that step. Pure and jittable (``env``, ``policy`` and sizes are static).

    Args:
      key: PRNG key; episode ``i`` resets with ``split(key, num_episodes)[i]``.
      env: an unbatched env (not wrapped for training).
      policy: ``obs [E, D] -> action [E, A]``, or a :class:`~jaxrl_robot.types.RecurrentPolicy`
        (every episode starts from its ``carry``).
      num_episodes: E.
      episode_length: step limit (default ``env.episode_length``).
      params: optional episode parameters passed to ``env.reset``.
    Returns:
      ``[E]`` arrays: every env metric at the episode's last step, plus ``return``,
      ``length`` and ``terminated`` (1.0 where the env ended the episode before the limit);
      with a ``distance`` metric also ``closest_distance``, its smallest value over the start and
      the episode's steps (not counting a step that left the region, ``out_of_region`` metric).
    """
    limit = int(episode_length or env.episode_length)
    keys = jax.random.split(key, num_episodes)
    if params is None:
        state = jax.vmap(env.reset)(keys)
    else:
        state = jax.vmap(lambda k: env.reset(k, params))(keys)
    zeros = jnp.zeros((num_episodes,), jnp.float32)
    policy = as_recurrent(policy)
    memory = jax.tree.map(lambda c: jnp.broadcast_to(c, (num_episodes,) + jnp.shape(c)), policy.carry)
    closest = state.metrics.get("distance", zeros)
    init = (state, memory, zeros, zeros, zeros, dict(state.metrics), closest)

    def body(carry, _):
        s, memory, finished, ret, length, final, closest = carry
        memory, action = policy.step(memory, s.obs)
        live = 1.0 - finished
        # a finished episode's lane keeps its last state: an env stepped past its end may drift to NaN
        ns = freeze(live, s, jax.vmap(env.step)(s, action))
        ret = ret + jnp.where(live > 0, ns.reward, 0.0)  # the live steps' rewards alone
        length = length + live
        ending = live * ns.done.astype(jnp.float32)
        final = jax.tree.map(lambda f, m: jnp.where(live > 0, m, f), final, dict(ns.metrics))
        inside = live * (1.0 - ns.metrics.get("out_of_region", zeros))  # arm7: success needs the region
        closest = jnp.where(inside > 0, jnp.minimum(closest, ns.metrics.get("distance", closest)), closest)
        return (ns, memory, jnp.maximum(finished, ending), ret, length, final, closest), None

    (_, _, finished, ret, length, final, closest), _ = jax.lax.scan(body, init, None, length=limit)
    out = {k: v for k, v in final.items() if v.shape == (num_episodes,)}
    out.update({"return": ret, "length": length, "terminated": finished})
    if "distance" in state.metrics:
        out["closest_distance"] = closest
    return out


def precision_summary(
    episodes: dict[str, Any], thresholds: tuple[float, ...] = PRECISION_THRESHOLDS
) -> dict[str, float]:
    """Success at each goal threshold ``t`` from episodes run on an env whose own threshold is the
    smallest ``t``: an episode succeeds at ``t`` when its closest approach to the goal
    (``closest_distance`` of :func:`run_test_episodes`) is below ``t``.  Up to the first step within
    ``t`` such an episode is the one the env with threshold ``t`` would run, which ends there.

    Returns ``success_<t in cm>cm`` per threshold (fractions) and the closest distance's median,
    90th percentile and maximum (m).
    """
    d = np.asarray(episodes["closest_distance"], np.float64)
    out = {f"success_{t * 100:g}cm": float((d < t).mean()) for t in thresholds}
    out.update(closest_distance_median=float(np.median(d)), closest_distance_p90=float(np.percentile(d, 90)),
               closest_distance_max=float(d.max()))  # fmt: skip
    return out


def summarize_episodes(episodes: dict[str, Any]) -> dict[str, float]:
    """Scalar summary of :func:`run_test_episodes` output.

    Always: ``episodes``, ``mean_return``, ``mean_length``. With a ``success`` metric:
    ``success_rate`` and ``successes``. With ``extra_distance``: ``mean_extra_distance`` over
    successful episodes (the path is only complete where the goal was reached; over all
    episodes when no ``success`` metric exists) and ``mean_extra_distance_all``.
    """
    ep = {k: np.asarray(v, np.float64) for k, v in episodes.items()}
    n = len(ep["return"])
    out = {"episodes": float(n), "mean_return": float(ep["return"].mean()), "mean_length": float(ep["length"].mean())}
    success = ep.get("success")
    if success is not None:
        out["successes"] = float((success > 0.5).sum())
        out["success_rate"] = float((success > 0.5).mean())
    if "extra_distance" in ep:
        extra = ep["extra_distance"]
        mask = success > 0.5 if success is not None else np.ones(n, bool)
        out["mean_extra_distance"] = float(extra[mask].mean()) if mask.any() else float("nan")
        out["mean_extra_distance_all"] = float(extra.mean())
    if "distance" in ep:
        out["mean_final_distance"] = float(ep["distance"].mean())
    return out


def tracking_error_sums(errors: Any, axes: tuple[str, ...] = ("x", "y", "orientation")) -> dict[str, float]:
    """Per-axis ``Σ_t |e_t|`` of one test episode, with mean per step and step count.

    Args:
      errors: ``[T, len(axes)]`` signed tracking errors of one episode.
      axes: column names.
    Returns:
      ``{"<axis>": sum, "<axis>_mean": mean per step, ..., "steps": T}``.
    """
    e = np.abs(np.asarray(errors, np.float64))
    if e.ndim != 2 or e.shape[1] != len(axes):
        raise ValueError(f"errors must have shape [T, {len(axes)}], got {e.shape}")
    out: dict[str, float] = {}
    for i, name in enumerate(axes):
        out[name] = float(e[:, i].sum())
        out[f"{name}_mean"] = float(e[:, i].mean()) if len(e) else float("nan")
    out["steps"] = float(len(e))
    return out
