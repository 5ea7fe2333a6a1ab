"""Recurrent (LSTM) actor and critic, sequence unrolls with stored start states, and the
start-state table of RSI episodes (thesis §5.7).

* :class:`LSTMActor` — ``FC → LSTM → FC``: one step ``(carry, obs [..., D]) -> (carry, (mean, log_std)
  [..., A])``, the Gaussian head of :class:`~jaxrl_robot.networks.GaussianActor` (``tanh`` mean;
  fixed or learned state-independent σ).
* :class:`LSTMCritic` — ``FC → LSTM → FC``: ``(carry, obs) -> (carry, V [...])``.
  The cell is ``flax.linen.OptimizedLSTMCell``; a carry is its ``(c, h)`` pair, ``[..., H]`` each.
* :func:`unroll` — run a step function over ``[T, B]`` inputs, taking the *stored* carry of a
  step wherever ``reset`` marks it (the first step of a training sequence, the first step of an
  episode) and the carry the step before produced elsewhere: truncated back-propagation through
  time from stored start states.
* The **start-state table** ``[M + 1, ...]`` holds one carry per reference time step ``k`` of a
  tracking env.  An episode that random reference-state initialisation (RSI) starts at step
  ``k`` starts from ``table[k]`` (:func:`table_lookup`) instead of from zero, so the network
  meets the reference's middle with a memory like the one it has there when it runs from
  ``t = 0``.  Update rule (:func:`table_update`), after each rollout: for every ``k`` visited by
  a step that *continues* an episode (its carry came out of the LSTM, not from the table), the
  entry moves to ``(1 − ρ) table[k] + ρ · mean`` of those carries over all lanes and devices;
  entries no such step visited keep their value.  ``table[0]`` is never continued into, so it
  stays at its initial zero: a run from ``t = 0`` — every test episode — starts from zeros.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxrl_robot import parallel
from jaxrl_robot.acting import lane_select

__all__ = ["LSTMActor", "LSTMCritic", "table_lookup", "table_update", "unroll", "zero_carry"]

Carry = tuple[jax.Array, jax.Array]
"""``(c, h)`` of an LSTM cell, ``[..., H]`` each."""


def zero_carry(batch_shape: tuple[int, ...], size: int) -> Carry:
    """The zero ``(c, h)`` carry, ``batch_shape + (size,)`` each (float32)."""
    z = jnp.zeros(tuple(batch_shape) + (size,), jnp.float32)
    return z, z


def _trunk(x: jax.Array, hidden: Sequence[int]) -> jax.Array:
    for width in hidden:
        x = nn.relu(nn.Dense(width, kernel_init=nn.initializers.orthogonal(jnp.sqrt(2.0)))(x))
    return x


class LSTMActor(nn.Module):
    """Recurrent Gaussian policy, one step: ``(carry, obs [..., D]) -> (carry, (mean, log_std) [..., A])``.

    Attributes:
      action_size: A.
      hidden: widths of the ReLU layers before the LSTM (thesis §5.7: (256,)).
      lstm_size: H, units of the LSTM cell (thesis: 256).
      sigma: initial / fixed standard deviation (one value per action dimension, or a scalar).
      learn_std: a learned state-independent log-std starting at ``log σ`` instead of a fixed σ.
    """

    action_size: int
    hidden: Sequence[int] = (256,)
    lstm_size: int = 256
    sigma: Sequence[float] | float = 0.5
    learn_std: bool = False

    @nn.compact
    def __call__(self, carry: Carry, obs: jax.Array) -> tuple[Carry, tuple[jax.Array, jax.Array]]:
        carry, y = nn.OptimizedLSTMCell(self.lstm_size, name="lstm")(carry, _trunk(obs, self.hidden))
        mean = jnp.tanh(nn.Dense(self.action_size, kernel_init=nn.initializers.orthogonal(0.01))(y))
        sigma = jnp.broadcast_to(jnp.asarray(self.sigma, jnp.float32), (self.action_size,))
        log_std = self.param("log_std", lambda _k, s: jnp.log(s), sigma) if self.learn_std else jnp.log(sigma)
        return carry, (mean, jnp.broadcast_to(log_std, mean.shape))


class LSTMCritic(nn.Module):
    """Recurrent state-value network, one step: ``(carry, obs [..., D]) -> (carry, V [...])``."""

    hidden: Sequence[int] = (256,)
    lstm_size: int = 256

    @nn.compact
    def __call__(self, carry: Carry, obs: jax.Array) -> tuple[Carry, jax.Array]:
        carry, y = nn.OptimizedLSTMCell(self.lstm_size, name="lstm")(carry, _trunk(obs, self.hidden))
        return carry, nn.Dense(1, kernel_init=nn.initializers.orthogonal(1.0))(y)[..., 0]


def unroll(
    step: Callable[[Any, jax.Array], tuple[Any, Any]], stored: Any, reset: jax.Array, inputs: jax.Array
) -> tuple[Any, Any]:
    """Run ``step`` over a batch of sequences, restarting from stored carries where ``reset`` says.

    Args:
      step: ``(carry [B, ...], x [B, ...]) -> (carry, out [B, ...])``, e.g. a bound LSTM module.
      stored: ``[T, B, ...]`` carries as they were when the sequences were collected (a pytree);
        no gradient flows into them.
      reset: ``[T, B]``, 1.0 where step ``t`` starts from ``stored[t]`` instead of the carry of
        step ``t − 1``; step 0 always starts from ``stored[0]``.
      inputs: ``[T, B, ...]``.
    Returns:
      ``(outputs [T, B, ...], carries after each step [T, B, ...])``.
    """
    stored = jax.lax.stop_gradient(stored)

    def body(carry, x):
        saved, r, inp = x
        carry = lane_select(r > 0, saved, carry)
        carry, out = step(carry, inp)
        return carry, (out, carry)

    first = jax.tree.map(lambda s: s[0], stored)
    _, (outputs, after) = jax.lax.scan(body, first, (stored, reset, inputs))
    return outputs, after


def table_lookup(table: Any, k: jax.Array) -> Any:
    """Entries ``table[k]``: ``[M + 1, ...]`` leaves indexed by ``k [B]`` (int) → ``[B, ...]``."""
    return jax.tree.map(lambda t: t[k], table)


def table_update(
    table: Any, k: jax.Array, carries: Any, mask: jax.Array, rate: float, axis_name: str | None = parallel.LANES
) -> Any:
    """Move each visited entry towards the mean of the carries seen at its step (module docstring).

    Args:
      table: ``[M + 1, ...]`` leaves, replicated over devices.
      k: ``[T, B]`` int reference step of each collected step.
      carries: ``[T, B, ...]`` the carry each step started from.
      mask: ``[T, B]``, 1.0 on the steps whose carry counts (those continuing an episode).
      rate: ρ in ``(0, 1]``; 1 replaces every visited entry by the new mean.
      axis_name: the mapped axis the lanes are split over (inside ``parallel.shard_lanes``: the
        default); sums and counts are totalled over it, so every device gets the same table.
        None: the lanes given are all the lanes.
    Returns:
      The updated table.
    """

    def total(x: jax.Array) -> jax.Array:
        return x if axis_name is None else parallel.psum(x, axis_name)

    size = jax.tree.leaves(table)[0].shape[0]
    flat_k = k.reshape(-1)
    weight = mask.reshape(-1).astype(jnp.float32)
    count = total(jax.ops.segment_sum(weight, flat_k, num_segments=size))

    def update(entry: jax.Array, seen: jax.Array) -> jax.Array:
        rows = seen.reshape((flat_k.shape[0], -1)) * weight[:, None]
        summed = total(jax.ops.segment_sum(rows, flat_k, num_segments=size)).reshape(entry.shape)
        shape = (size,) + (1,) * (entry.ndim - 1)
        mean = summed / jnp.maximum(count, 1.0).reshape(shape)
        moved = (1.0 - rate) * entry + rate * mean
        return jnp.where(count.reshape(shape) > 0, moved, entry)

    return jax.tree.map(update, table, carries)
