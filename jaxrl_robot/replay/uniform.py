"""A device-resident ring buffer of transitions with uniform sampling.

``make_uniform_replay(capacity, batch_size) -> UniformReplay(init, add, sample)``, a
bundle of pure functions in the style of optax / flashbax.  Items are any pytree of
arrays (for example :class:`jaxrl_robot.replay.Transition`); the buffer stores each leaf
as a ``[capacity, ...]`` array.  When full, the oldest items are overwritten (thesis §3.1).

``add`` takes an optional ``mask``: only the masked-in rows of a batch are stored, packed
contiguously in batch order.  This lets fixed-shape producers (frozen lanes after an
episode ends, relabelled copies that a HER strategy skips) write without host logic.

Nothing is jitted here; jit the caller and donate the buffer state.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

__all__ = ["UniformReplay", "UniformReplayState", "UniformSample", "make_uniform_replay", "ring_write"]


@struct.dataclass
class UniformReplayState:
    """Ring-buffer state.

    Attributes:
      data: pytree of ``[capacity, ...]`` arrays.
      insert_pos: ``[] int32`` slot the next item goes to.
      size: ``[] int32`` number of stored items (``<= capacity``).
      capacity: static capacity.
    """

    data: Any
    insert_pos: jax.Array
    size: jax.Array
    capacity: int = struct.field(pytree_node=False)


class UniformSample(NamedTuple):
    """A sampled mini-batch: ``experience`` (pytree of ``[B, ...]``) and slot ``indices [B]``."""

    experience: Any
    indices: jax.Array


class UniformReplay(NamedTuple):
    """``init(example_item) -> state``; ``add(state, items, mask=None) -> state``;
    ``sample(key, state) -> UniformSample``."""

    init: Callable[..., UniformReplayState]
    add: Callable[..., UniformReplayState]
    sample: Callable[..., UniformSample]


def _batch_size(items: Any) -> int:
    leaves = jax.tree.leaves(items)
    if not leaves:
        raise ValueError("items must contain at least one array")
    n = leaves[0].shape[0]
    for leaf in leaves:
        if leaf.shape[:1] != (n,):
            raise ValueError(f"all item leaves need the same leading batch size; got {leaf.shape[:1]} and {(n,)}")
    return n


def ring_write(
    data: Any,
    items: Any,
    insert_pos: jax.Array,
    size: jax.Array,
    capacity: int,
    mask: jax.Array | None = None,
) -> tuple[Any, jax.Array, jax.Array, jax.Array, jax.Array]:
    """Write the (masked-in) rows of ``items`` after ``insert_pos``, wrapping around.

    Args:
      data: pytree of ``[capacity, ...]`` storage arrays.
      items: pytree of ``[N, ...]`` rows, ``N <= capacity``.
      insert_pos, size: ``[] int32`` ring position and fill level.
      capacity: static capacity.
      mask: optional ``[N] bool``; rows with False are not stored.
    Returns:
      ``(data, slots [N] int32, keep [N] bool, insert_pos, size)`` where ``slots[i]`` is
      the slot row ``i`` went to (meaningless where ``keep`` is False).
    """
    n = _batch_size(items)
    if n > capacity:
        raise ValueError(f"cannot add {n} items at once to a buffer of capacity {capacity}")
    keep = jnp.ones((n,), bool) if mask is None else mask.astype(bool)
    rank = jnp.cumsum(keep.astype(jnp.int32)) - 1
    slots = (insert_pos + rank) % capacity
    write_at = jnp.where(keep, slots, capacity)  # out of range -> dropped
    data = jax.tree.map(lambda d, x: d.at[write_at].set(x.astype(d.dtype), mode="drop"), data, items)
    n_added = jnp.sum(keep.astype(jnp.int32))
    insert_pos = (insert_pos + n_added) % capacity
    size = jnp.minimum(size + n_added, capacity)
    return data, slots.astype(jnp.int32), keep, insert_pos.astype(jnp.int32), size.astype(jnp.int32)


def empty_storage(example_item: Any, capacity: int) -> Any:
    """Zero ``[capacity, ...]`` arrays shaped like one (unbatched) ``example_item``."""
    return jax.tree.map(lambda x: jnp.zeros((capacity, *jnp.shape(x)), jnp.asarray(x).dtype), example_item)


def make_uniform_replay(capacity: int, batch_size: int) -> UniformReplay:
    """A uniform ring buffer of ``capacity`` items sampling ``batch_size`` at a time.

    Raises:
      ValueError: non-positive ``capacity`` or ``batch_size``.
    """
    if int(capacity) < 1:
        raise ValueError(f"capacity={capacity!r} must be >= 1")
    if int(batch_size) < 1:
        raise ValueError(f"batch_size={batch_size!r} must be >= 1")
    capacity, batch_size = int(capacity), int(batch_size)

    def init(example_item: Any) -> UniformReplayState:
        """Empty buffer for items shaped like ``example_item`` (one item, no batch axis)."""
        zero = jnp.zeros((), jnp.int32)
        return UniformReplayState(
            data=empty_storage(example_item, capacity), insert_pos=zero, size=zero, capacity=capacity
        )

    def add(state: UniformReplayState, items: Any, mask: jax.Array | None = None) -> UniformReplayState:
        """Store the rows of ``items`` (pytree of ``[N, ...]``) where ``mask [N]`` is True."""
        data, _, _, pos, size = ring_write(state.data, items, state.insert_pos, state.size, capacity, mask)
        return state.replace(data=data, insert_pos=pos, size=size)

    def sample(key: jax.Array, state: UniformReplayState) -> UniformSample:
        """``batch_size`` items drawn uniformly with replacement from the stored ones."""
        indices = jax.random.randint(key, (batch_size,), 0, jnp.maximum(state.size, 1))
        experience = jax.tree.map(lambda d: d[indices], state.data)
        return UniformSample(experience=experience, indices=indices)

    return UniformReplay(init=init, add=add, sample=sample)
