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

* :func:`evaluate` — a policy's evaluation as ``python -m train.<algo>`` reports it, chosen by the env
  (:func:`evaluation_kind`): test episodes (reaching), the test episode from ``t = 0`` (tracking) or laps on
  every road (racing); :func:`evaluation_program` and :func:`summarize_evaluation` are the same as a pure
  ``(key, train state) -> arrays`` function and its summary; :func:`evaluation_key` the key of a seed's.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env

from envs_mjx import backend
from jaxrl_robot.networks import gaussian_sample
from jaxrl_robot.types import Policy, RecurrentPolicy, as_recurrent

__all__ = [
    "EVALUATION_KINDS",
    "EVAL_KEY_OFFSET",
    "PRECISION_THRESHOLDS",
    "evaluate",
    "evaluation_key",
    "evaluation_kind",
    "evaluation_program",
    "final_episodes",
    "freeze",
    "precision_summary",
    "race_evaluation",
    "race_summary",
    "run_test_episodes",
    "sampling_policy",
    "strict_env",
    "summarize_episodes",
    "summarize_evaluation",
    "tracking_episode",
    "tracking_error_sums",
    "tracking_summary",
    "two_policies",
]

PRECISION_THRESHOLDS = (0.05, 0.02, 0.01)
"""Goal thresholds (m) at which :func:`precision_summary` reports success."""

EVAL_KEY_OFFSET = 1_000_003
"""Folded into the seed's key for test episodes, so their starts and goals are not training's."""

EVALUATION_KINDS = ("episodes", "tracking", "racing")
"""How an env's policies are evaluated (:func:`evaluation_kind`)."""


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


def evaluation_key(seed: int) -> jax.Array:
    """The key of the final evaluation of the run of ``--seed seed`` (a stream apart from training's: ``fold_in``
    of :data:`EVAL_KEY_OFFSET`)."""
    return jax.random.fold_in(jax.random.PRNGKey(seed), EVAL_KEY_OFFSET)


def evaluation_kind(env: Env) -> str:
    """How ``env``'s policies are evaluated, as the env says (its ``evaluation_kind``: ``envs_mjx``'s tracking
    envs ``"tracking"``, ``racecar`` ``"racing"``), else ``"episodes"``; one of :data:`EVALUATION_KINDS`.

    Raises:
      ValueError: the env names a kind that is not one of them.
    """
    kind = getattr(env, "evaluation_kind", "episodes")
    if kind not in EVALUATION_KINDS:
        raise ValueError(f"{type(env).__name__}.evaluation_kind {kind!r}; valid: {', '.join(EVALUATION_KINDS)}")
    return kind


def strict_env(env: Env, precision: bool) -> Env | None:
    """With ``precision``, ``env`` (a reaching env with ``config.goal_threshold``) at the smallest of
    ``PRECISION_THRESHOLDS`` and its own threshold (``env`` itself where that is its own), else None."""
    own = getattr(getattr(env, "config", None), "goal_threshold", None)
    if not precision or own is None:
        return None
    strict = min(PRECISION_THRESHOLDS + (own,))
    return env if strict == own else type(env)(env.config, goal_threshold=strict)


def final_episodes(
    key: jax.Array, env: Env, strict: Env | None, policy: Callable, episodes: int, episode_length: int = 0
) -> dict[str, Any]:
    """The final evaluation's episodes in one program: ``{"episodes": …}`` of ``env`` and, with a
    ``strict`` env (:func:`strict_env`), ``{"strict": …}``: the same starts and goals to its threshold
    (:func:`run_test_episodes` outputs, ``[episodes]`` each; the same episodes where ``strict`` is ``env``)."""
    limit = episode_length or None
    out = {"episodes": run_test_episodes(key, env, policy, episodes, limit)}
    if strict is not None:
        out["strict"] = out["episodes"] if strict is env else run_test_episodes(key, strict, policy, episodes, limit)
    return out


def tracking_episode(env: Env, policy: Policy | RecurrentPolicy) -> dict[str, Any]:
    """A tracking env's test episode from ``t = 0`` with ``policy`` (``envs_mjx.tracking.test_episode``: host
    values, ``abs_error [N, 3]``, ``steps``, ``episode_return``, ``ref_path`` / ``real_path [N+1, 3]``,
    ``axis_names``)."""
    from envs_mjx import tracking

    policy = as_recurrent(policy)
    return tracking.test_episode(env, policy.step, carry=policy.carry)


def tracking_summary(result: Mapping[str, Any], axes: tuple[str, ...]) -> dict[str, Any]:
    """:func:`evaluate`'s summary of a tracking env's test episode: ``result`` holds host values of
    ``envs_mjx.tracking.rollout`` (``abs_error [N, len(axes)]``, ``steps``, ``episode_return``)."""
    steps = int(result["steps"])
    summary = tracking_error_sums(np.asarray(result["abs_error"])[:steps], axes)
    summary["episode_return"] = float(result["episode_return"])
    return {"kind": "tracking", **summary}


def race_evaluation(key: jax.Array, env: Env, policy: Callable, laps: int) -> dict[str, Any]:
    """``laps`` one-lap test episodes on each road (thesis Tables 6.2-6.3) with the deterministic ``policy``:
    ``<road>/<outcome>`` counts (success, collision, out_of_track, stalled), ``<road>/overtakes`` (mean),
    ``<road>/speed_kmh``, ``<road>/rank`` and ``success_rate`` over every lap
    (:func:`envs_mjx.racecar.make_lap_test`)."""
    from envs_mjx.racecar import make_lap_test

    test = make_lap_test(env, laps)
    return race_summary(jax.device_get(jax.jit(lambda k: test(lambda e, s: policy(s.obs), k))(key)), laps)


def race_summary(result: Mapping[str, Any], laps: int) -> dict[str, Any]:
    """:func:`race_evaluation`'s summary of the host arrays of a lap test (``envs_mjx.racecar.make_lap_test``)."""
    from envs_mjx.racecar import lap_summary

    roads = lap_summary(result)
    flat: dict[str, Any] = {"kind": "racing", "laps_per_road": laps}
    flat["success_rate"] = sum(r["success"] for r in roads.values()) / (laps * len(roads))
    for road, row in roads.items():
        flat.update({f"{road}/{k}": v for k, v in row.items() if k != "laps"})
    return flat


def evaluation_program(
    env: Env, policy_of: Callable[[Any], Callable], episodes: int, episode_length: int = 0, precision: bool = False
) -> Callable[[jax.Array, Any], dict[str, Any]]:
    """``(key, state) -> arrays`` of one evaluation of ``policy_of(state)`` on ``env``, pure (jit it), whose
    host values :func:`summarize_evaluation` summarises as :func:`evaluate` would: :func:`final_episodes`
    (``episodes`` test episodes, ``precision`` as :func:`strict_env`), a tracking env's test episode from
    ``t = 0`` (``envs_mjx.tracking.rollout``; no key taken) or ``episodes`` laps on each road."""
    kind = evaluation_kind(env)
    if kind == "tracking":
        from envs_mjx import tracking

        def episode(k: jax.Array, s: Any) -> dict[str, jax.Array]:
            policy = as_recurrent(policy_of(s))
            return tracking.rollout(env, policy.step, carry=policy.carry)

        return episode
    if kind == "racing":
        from envs_mjx.racecar import make_lap_test

        test = make_lap_test(env, episodes)
        return lambda k, s: test(lambda e, st: policy_of(s)(st.obs), k)
    strict = strict_env(env, precision)

    def evaluation(k: jax.Array, s: Any) -> dict[str, Any]:  # the name of the compiled program
        return final_episodes(k, env, strict, policy_of(s), episodes, episode_length)

    return evaluation


def summarize_evaluation(env: Env, out: Mapping[str, Any], episodes: int) -> dict[str, Any]:
    """:func:`evaluate`'s summary of the host values ``out`` of :func:`evaluation_program` (``episodes``: its
    count of test episodes, racecar's laps per road)."""
    kind = evaluation_kind(env)
    if kind == "tracking":
        return tracking_summary(out, tuple(env.axis_names))
    if kind == "racing":
        return race_summary(out, episodes)
    summary = summarize_episodes(out["episodes"])
    if "strict" in out:
        summary.update(precision_summary(out["strict"], PRECISION_THRESHOLDS))
    return {"kind": "episodes", **summary}


def evaluate(
    key: jax.Array, env: Env, policy: Callable, episodes: int, episode_length: int = 0, *,
    episodes_fn: Callable[[jax.Array], dict[str, Any]] | None = None, precision: bool = False,
) -> dict[str, Any]:  # fmt: skip
    """The summary of a deterministic ``policy`` on ``env`` (its ``"kind"``: :func:`evaluation_kind`).

    Reaching envs: ``episodes`` test episodes from fresh starts and goals of ``key`` (step limit
    ``episode_length``, 0: the env's) → :func:`summarize_episodes`; with ``precision`` and a config with
    ``goal_threshold`` (arm7) also :func:`precision_summary` of the same episodes on :func:`strict_env`.
    ``episodes_fn(key)``, if given, is an already compiled :func:`final_episodes` of ``policy`` (with the same
    ``precision``). Tracking envs: the test episode from ``t = 0`` → :func:`tracking_summary`. ``racecar``:
    ``episodes`` laps on every road (:func:`race_evaluation`).
    """
    kind = evaluation_kind(env)
    if kind == "tracking":
        result = tracking_episode(env, policy)
        return tracking_summary(result, tuple(result["axis_names"]))
    if kind == "racing":
        return race_evaluation(key, env, policy, episodes)
    if episodes_fn is None:
        strict = strict_env(env, precision)
        episodes_fn = jax.jit(functools.partial(
            final_episodes, env=env, strict=strict, policy=policy, episodes=episodes, episode_length=episode_length
        ))  # fmt: skip
    return summarize_evaluation(env, jax.device_get(episodes_fn(key)), episodes)
