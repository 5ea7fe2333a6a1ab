"""Advantage and return estimators on one stream of ``T`` transitions.

Every function here works on a single stream (arrays of shape ``[T]``); :func:`over_lanes` maps one
over the lanes of time-major ``[T, B]`` batches (``over_lanes(gae, 5)``: ``jax.vmap(gae, in_axes=(1, 1,
1, 1, 1, None, None), out_axes=1)``).

Episode ends are given as two separate flags per step, because they must be treated
differently when bootstrapping:

* ``terminations[t] = 1``: the episode *failed or succeeded* at step ``t`` (a true terminal
  state). Nothing is bootstrapped after it: the successor's value counts as 0.
* ``truncations[t] = 1``: the episode was *cut by the time limit* at step ``t``. The
  successor state is an ordinary state, so the return bootstraps from its value
  ``V(s'_t)``; only the recursion across the episode boundary is cut.

``next_values[t]`` is ``V(s'_t)``, the value of the true successor of step ``t`` — with an
auto-resetting environment that is the value of ``info["final_obs"]``, not of the next
observation in the stream (which already belongs to a fresh episode). Where an episode
continues, ``next_values[t] == values[t + 1]``.

The last step of the stream (``t = T - 1``) always bootstraps from ``next_values[T - 1]``
(unless terminated): the stream is a fixed-length segment of a longer episode.
"""

from __future__ import annotations

from collections.abc import Callable

import chex
import jax
import jax.numpy as jnp

__all__ = ["gae", "lambda_returns", "n_step_returns", "over_lanes", "td_errors"]


def _check_stream(*arrays: jax.Array) -> None:
    chex.assert_rank(arrays, 1)
    chex.assert_equal_shape(arrays)
    chex.assert_type(arrays, float)


def _flags(terminations: jax.Array, truncations: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(not_terminal [T], continues [T])`` as floats.

    ``continues[t]`` is 1 where the recursion may look at step ``t + 1`` of the same episode:
    the episode did not end at ``t`` and ``t`` is not the last step of the stream.
    """
    not_terminal = 1.0 - terminations
    ended = jnp.maximum(terminations, truncations)
    continues = (1.0 - ended).at[-1].set(0.0)
    return not_terminal, continues


def td_errors(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminations: jax.Array,
    gamma: float,
) -> jax.Array:
    """One-step TD errors ``δ_t = r_t + γ (1 - term_t) V(s'_t) - V(s_t)`` (Eq. 5.7).

    Args:
      rewards, values, next_values, terminations: ``[T]``.
      gamma: discount factor γ.
    Returns:
      ``[T]`` TD errors.
    """
    _check_stream(rewards, values, next_values, terminations)
    return rewards + gamma * (1.0 - terminations) * next_values - values


def gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    terminations: jax.Array,
    truncations: jax.Array,
    gamma: float,
    lambda_: float,
) -> jax.Array:
    """Generalised advantage estimates, truncated at the stream end (Eq. 5.12).

    ``A_t = δ_t + γλ c_t A_{t+1}`` with ``δ_t`` from :func:`td_errors` and ``c_t = 1`` while
    the episode continues inside the stream (``c_t = 0`` at a termination, a truncation or
    ``t = T - 1``). For ``λ = 0`` this is the TD error; for ``λ = 1`` the discounted return
    minus ``V(s_t)`` (Eq. 5.9), bootstrapped at truncations and at the stream end.

    Args:
      rewards: ``[T]`` rewards ``r_t``.
      values: ``[T]`` ``V(s_t)``.
      next_values: ``[T]`` ``V(s'_t)`` of the true successor states (see module docstring).
      terminations: ``[T]`` 1.0 where the episode reached a terminal state at ``t``.
      truncations: ``[T]`` 1.0 where the time limit cut the episode at ``t``.
      gamma: discount factor γ.
      lambda_: GAE parameter λ.
    Returns:
      ``[T]`` advantages.
    """
    _check_stream(rewards, values, next_values, terminations, truncations)
    deltas = td_errors(rewards, values, next_values, terminations, gamma)
    _, continues = _flags(terminations, truncations)

    def backward(carry, xs):
        delta, cont = xs
        adv = delta + gamma * lambda_ * cont * carry
        return adv, adv

    _, advantages = jax.lax.scan(backward, jnp.zeros_like(rewards[0]), (deltas, continues), reverse=True)
    return advantages


def lambda_returns(
    rewards: jax.Array,
    next_values: jax.Array,
    terminations: jax.Array,
    truncations: jax.Array,
    gamma: float,
    lambda_: float,
) -> jax.Array:
    """λ-returns, the critic's targets (Eq. 5.13–5.14).

    ``R_t(λ) = r_t + γ (1 - term_t) [(1 - λ c_t) V(s'_t) + λ c_t R_{t+1}(λ)]``: the weighted
    mixture ``(1 - λ) Σ_n λ^{n-1} R_t^{(n)}`` of n-step returns where, as the thesis notes
    below Eq. 5.14, every return longer than the remaining segment equals the longest one
    ``R_t^{(T-t)}`` (bootstrapped from ``V(s_T)``), so that one keeps the tail weight
    ``λ^{T-t-1}``. The recursion stops at terminations (no bootstrap), truncations
    (bootstrap from ``V(s'_t)``) and the stream end. With matching values,
    ``lambda_returns = gae + values``.

    Args:
      rewards, next_values, terminations, truncations: ``[T]`` as in :func:`gae`.
      gamma: discount factor γ.
      lambda_: λ.
    Returns:
      ``[T]`` targets ``R_t(λ)``.
    """
    _check_stream(rewards, next_values, terminations, truncations)
    not_terminal, continues = _flags(terminations, truncations)

    def backward(carry, xs):
        r, v_next, nt, cont = xs
        ret = r + gamma * nt * ((1.0 - lambda_ * cont) * v_next + lambda_ * cont * carry)
        return ret, ret

    xs = (rewards, next_values, not_terminal, continues)
    _, returns = jax.lax.scan(backward, jnp.zeros_like(rewards[0]), xs, reverse=True)
    return returns


def n_step_returns(
    rewards: jax.Array,
    next_values: jax.Array,
    terminations: jax.Array,
    truncations: jax.Array,
    gamma: float,
    n: int | None = None,
) -> jax.Array:
    """n-step returns ``Σ_{i<k} γ^i r_{t+i} + γ^k V(s'_{t+k-1})`` (Eq. 4.3).

    Each step sums at most ``n`` rewards, stopping early at the episode end or the stream
    end, and bootstraps from the successor value of the last summed step (0 after a
    termination). ``n=None`` sums to the stream end — the A3C/A2C worker's target
    (Algorithm 3, lines 9–13), where every step bootstraps from ``V(s_{T_n})``.

    Args:
      rewards, next_values, terminations, truncations: ``[T]`` as in :func:`gae`.
      gamma: discount factor γ.
      n: horizon ``n >= 1`` (static), or ``None`` for the whole stream.
    Returns:
      ``[T]`` targets.
    """
    _check_stream(rewards, next_values, terminations, truncations)
    horizon = rewards.shape[0] if n is None else int(n)
    if horizon < 1:
        raise ValueError(f"n={n!r} must be >= 1")
    if n is None:
        return lambda_returns(rewards, next_values, terminations, truncations, gamma, 1.0)
    not_terminal, continues = _flags(terminations, truncations)
    one_step = rewards + gamma * not_terminal * next_values

    def extend(_, g):
        # g holds k-step returns; build (k+1)-step ones by looking one step further.
        g_next = jnp.concatenate([g[1:], jnp.zeros_like(g[:1])])
        tail = continues * g_next + (1.0 - continues) * next_values
        return rewards + gamma * not_terminal * tail

    return jax.lax.fori_loop(1, horizon, extend, one_step)


def over_lanes(estimator: Callable[..., jax.Array], streams: int) -> Callable[..., jax.Array]:
    """``estimator`` (one of this module's) on every lane of time-major batches: its first ``streams``
    arguments ``[T, B]`` (lane ``b``'s stream in column ``b``), mapped over axis 1; the rest (``gamma``,
    ``lambda_``, ``n``) shared by the lanes; the result ``[T, B]``."""

    def on_lanes(*args: object) -> jax.Array:
        in_axes = (1,) * streams + (None,) * (len(args) - streams)
        return jax.vmap(estimator, in_axes=in_axes, out_axes=1)(*args)

    return on_lanes
