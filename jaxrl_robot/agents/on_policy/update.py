"""The update steps the on-policy family shares, as functions of explicit arguments; they run inside
``parallel.shard_lanes`` on this device's ``B`` lanes of an iteration's data ``[N, B, ...]``.

* Mini-batches: :func:`draw_sequences` (whole sequences of ``L`` steps from every lane, ``L = 1``
  for a feed-forward policy; the draw depends only on global lane indices) and :func:`draw_segments`
  (whole segments of ``S`` steps from any of this device's lanes, as brax draws its unrolls);
  :func:`flat`.
* Returns per lane: :func:`lane_gae` (advantages, Eq. 5.12) and :func:`lane_lambda_returns` (critic
  targets, Eq. 5.14), termination and truncation apart; :func:`standardize` over every device's lanes.
* Steps: :func:`sgd_steps` (``n`` steps of a step function, a fresh key each: the mini-batch epochs),
  :func:`gradient_step` (gradients averaged over devices, one optimiser step).
* :func:`policy_kl` — the mean KL divergence from the acting policy to the updated one (Eq. 5.4).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax

from jaxrl_robot import parallel
from jaxrl_robot.acting import per_lane_keys
from jaxrl_robot.agents.core import apply_gradients
from jaxrl_robot.networks import gaussian_kl
from jaxrl_robot.returns import gae, lambda_returns, over_lanes

__all__ = [
    "draw_segments",
    "draw_sequences",
    "flat",
    "gradient_step",
    "lane_gae",
    "lane_lambda_returns",
    "policy_kl",
    "sgd_steps",
    "standardize",
]


def flat(x: jax.Array) -> jax.Array:
    """``[L, B, ...] -> [L * B, ...]``."""
    return x.reshape((-1,) + x.shape[2:])


def draw_sequences(key: jax.Array, lane_ids: jax.Array, data: Any, seq_length: int, per_lane: int) -> Any:
    """``per_lane`` whole sequences of ``seq_length`` (L) steps from every lane, drawn without replacement
    (lane ``i`` with ``fold_in(key, lane_ids[i])``): leaves ``[N, B, ...] -> [L, per_lane * B, ...]``."""
    num_steps, lanes = jax.tree.leaves(data)[0].shape[0], lane_ids.shape[0]
    keys = per_lane_keys(key, lane_ids)
    idx = jax.vmap(lambda k: jax.random.permutation(k, num_steps // seq_length)[:per_lane], out_axes=1)(keys)

    def take(x: jax.Array) -> jax.Array:
        seqs = x.reshape((num_steps // seq_length, seq_length) + x.shape[1:])
        ix = idx.reshape((per_lane, 1) + idx.shape[1:] + (1,) * (x.ndim - 2))
        picked = jnp.moveaxis(jnp.take_along_axis(seqs, ix, axis=0), 1, 0)  # [L, per_lane, B, ...]
        return picked.reshape((seq_length, per_lane * lanes) + x.shape[2:])

    return jax.tree.map(take, data)


def draw_segments(key: jax.Array, lane_ids: jax.Array, data: Any, segment: int, count: int) -> Any:
    """``count`` whole segments of ``segment`` (S) steps drawn without replacement from all of this
    device's lanes (with ``fold_in(key, lane_ids[0])``): leaves ``[N, B, ...] -> [S, count, ...]``."""
    num_steps, lanes = jax.tree.leaves(data)[0].shape[0], lane_ids.shape[0]
    idx = jax.random.permutation(jax.random.fold_in(key, lane_ids[0]), (num_steps // segment) * lanes)[:count]
    seg, lane = idx // lanes, idx % lanes

    def take(x: jax.Array) -> jax.Array:
        picked = x.reshape((num_steps // segment, segment) + x.shape[1:])[seg, :, lane]  # [count, S, ...]
        return jnp.moveaxis(picked, 0, 1)

    return jax.tree.map(take, data)


lane_gae = over_lanes(gae, 5)
"""GAE (Eq. 5.12, ``returns.gae``) of every lane's stream: ``(rewards, values, next_values, terminations,
truncations [T, B], gamma, lam) -> [T, B]``, each truncated at its end."""

lane_lambda_returns = over_lanes(lambda_returns, 4)
"""λ-returns (Eq. 5.14, ``returns.lambda_returns``) of every lane's stream: ``(rewards, next_values,
terminations, truncations [T, B], gamma, lam) -> [T, B]``."""


def standardize(x: jax.Array) -> jax.Array:
    """``x`` to zero mean and unit variance over every device's lanes (population variance, ``+ 1e-8``
    on the standard deviation)."""
    mu = parallel.pmean(jnp.mean(x))
    var = parallel.pmean(jnp.mean((x - mu) ** 2))
    return (x - mu) / (jnp.sqrt(var) + 1e-8)


def sgd_steps(step: Callable[[Any, jax.Array], tuple[Any, Any]], carry: Any, key: jax.Array, num_steps: int):
    """``num_steps`` of ``step(carry, key) -> (carry, out)`` under ``lax.scan``, step ``i`` with
    ``split(key, num_steps)[i]`` (e.g. its mini-batch draw): ``(carry, outs [num_steps, ...])``."""
    return jax.lax.scan(step, carry, jax.random.split(key, num_steps))


def gradient_step(tx: optax.GradientTransformation, grads: Any, opt_state: Any, params: Any) -> tuple[Any, Any]:
    """One optimiser step on the gradients averaged over devices: ``(params, opt_state)``."""
    return apply_gradients(tx, parallel.pmean(grads), opt_state, params)


def policy_kl(old: tuple[jax.Array, jax.Array], new: tuple[jax.Array, jax.Array]) -> jax.Array:
    """``[]`` mean ``KL(π_old ‖ π_new)`` of Gaussians ``(mean, log_std) [..., A]`` over every device's
    states (``D`` of Eq. 5.4)."""
    return parallel.pmean(jnp.mean(gaussian_kl(*old, *new)))
