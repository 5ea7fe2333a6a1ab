"""Prioritised experience replay on the sum-tree (thesis §3.2, Schaul et al.).

``make_prioritized_replay(capacity, batch_size, alpha, beta0, beta_increment, ...)`` returns
``PrioritizedReplay(init, add, sample, update_priorities)``, pure functions over a
:class:`PrioritizedReplayState`.

* Sampling probability ``P(i) = p_i^α / Σ_k p_k^α`` (Eq. 3.9): the tree stores ``p_i^α``
  and is sampled stratified (Fig. 3.2).
* Importance-sampling weights ``w_i = (1 / (N · P(i)))^β`` normalised by the largest weight
  of the sampled mini-batch so that ``max w = 1`` (Eq. 3.10); ``N`` is the number of
  stored transitions.
* ``β`` starts at ``β0`` and grows by ``beta_increment`` with every priority update (one
  per learning step), capped at 1.
* New transitions enter with the largest priority seen so far (so each is replayed at
  least once soon), or with priorities the caller gives (a worker that computed its own
  TD errors, thesis §4.2).
* After learning, :func:`update_priorities` sets ``p_i = |δ_i| + ε`` from the TD errors
  ``δ`` of the sampled transitions; ``ε > 0`` keeps every stored transition reachable.

Bad input cannot poison the buffer (every raw priority stays finite and positive, so do the
total, ``max_priority``, the probabilities and the weights):

* a NaN or ``±inf`` TD error (or given priority) is replaced by the largest raw priority after
  the batch's finite ones, ``max(max_priority, max p of the batch)``; :func:`count_nonfinite`
  counts them (the DDPG/TD3 learner logs it as ``per_nonfinite_td``);
* raw priorities are kept in ``[tiny, value_limit(capacity)]`` (the smallest normal float and
  ``max float / (4 · capacity)``, :func:`~jaxrl_robot.replay.sum_tree.value_limit`);
* ``update_priorities`` ignores indices outside ``[0, size)`` (negative ones included): they
  neither write nor raise ``max_priority``, so an empty slot never gets probability mass and
  ``sample`` never returns an index ``>= size``;
* ``sample`` of an empty buffer raises a ``ValueError`` when called eagerly; under ``jit`` it
  returns index 0 with probability and weight 0.

Trees (``tree=``): the ``branching``-ary :mod:`~jaxrl_robot.replay.sum_tree` (one reduction
per level to sample, one ``[B, b]`` row scatter per level to update) is the default on every
backend; the two-level :mod:`~jaxrl_robot.replay.block_tree` (``tree="block"``), whose sample
and whose update are one Pallas kernel each on a GPU, wins on its own
(``python -m benchmarks.replay_throughput``) but not inside a trainer: in DDPG's ``fast`` arm
program on an H100 its kernels made the chunk's XLA compile take 173 s against 12 s and a chunk
run 5.3 s against 1.1 s (``python -m benchmarks.per_trees``,
``benchmarks/results/gpu-nvidia_h100_80gb_hbm3-per_trees.md``).
``add`` writes fresh ring slots, which are distinct, so it skips the search for repeated indices.

Nothing is jitted here; jit the caller and donate the buffer state.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import chex
import jax
import jax.numpy as jnp
from flax import struct

from jaxrl_robot.replay import block_tree, sum_tree
from jaxrl_robot.replay.uniform import empty_storage, ring_write

__all__ = [
    "PrioritizedReplay",
    "PrioritizedReplayState",
    "PrioritizedSample",
    "TREES",
    "count_nonfinite",
    "importance_weights",
    "make_prioritized_replay",
]

TREES = ("auto", "sum", "block")


@struct.dataclass
class PrioritizedReplayState:
    """Prioritised buffer state.

    Attributes:
      data: pytree of ``[capacity, ...]`` arrays.
      tree: sum-tree over ``p_i^α`` (a :class:`~jaxrl_robot.replay.sum_tree.SumTreeState` or a
        :class:`~jaxrl_robot.replay.block_tree.BlockTreeState`).
      insert_pos, size: ``[] int32`` ring position and fill level.
      scalars: ``[2]`` float32 ``[max_priority, beta]`` (one array, so that the block tree's
        update kernel writes both): the largest raw priority ``p`` seen (new items enter with
        it) and the current importance-sampling exponent β.
      capacity: static capacity.
    """

    data: Any
    tree: Any
    insert_pos: jax.Array
    size: jax.Array
    scalars: jax.Array
    capacity: int = struct.field(pytree_node=False)

    @property
    def max_priority(self) -> jax.Array:
        """``[]`` largest raw priority seen."""
        return self.scalars[0]

    @property
    def beta(self) -> jax.Array:
        """``[]`` current importance-sampling exponent β."""
        return self.scalars[1]


class PrioritizedSample(NamedTuple):
    """A prioritised mini-batch.

    Attributes:
      experience: pytree of ``[B, ...]`` items.
      indices: ``[B] int32`` slots (pass them back to ``update_priorities``).
      probabilities: ``[B]`` sampling probabilities ``P(i)`` (Eq. 3.9).
      weights: ``[B]`` importance weights, max-normalised (Eq. 3.10).
    """

    experience: Any
    indices: jax.Array
    probabilities: jax.Array
    weights: jax.Array


class PrioritizedReplay(NamedTuple):
    """``init(example_item)``, ``add(state, items, priorities=None, mask=None)``,
    ``sample(key, state)``, ``update_priorities(state, indices, td_errors)``."""

    init: Callable[..., PrioritizedReplayState]
    add: Callable[..., PrioritizedReplayState]
    sample: Callable[..., PrioritizedSample]
    update_priorities: Callable[..., PrioritizedReplayState]


def importance_weights(probabilities: jax.Array, size: jax.Array, beta: jax.Array) -> jax.Array:
    """Eq. 3.10: ``w_i = (N · P(i))^(-β) / max_j w_j`` over the mini-batch: ``[B] -> [B]``.

    ``N · P(i)`` below the smallest normal float counts as that float, so the weights stay finite.
    """
    chex.assert_rank(probabilities, 1)
    scaled = size.astype(probabilities.dtype) * probabilities
    log_w = -beta * jnp.log(jnp.maximum(scaled, jnp.finfo(probabilities.dtype).tiny))
    return jnp.exp(log_w - jnp.max(log_w))


def count_nonfinite(td_errors: jax.Array) -> jax.Array:
    """``[B] -> [] int32``: how many TD errors are NaN or ``±inf`` (``update_priorities`` replaces
    each by the largest priority)."""
    return jnp.sum(~jnp.isfinite(td_errors), dtype=jnp.int32)


class _Spec(NamedTuple):
    """The static settings of one prioritised replay (:func:`make_prioritized_replay`'s arguments, checked;
    ``tree`` resolved to ``"sum"`` or ``"block"``; ``rule`` the update rule of the raw priorities)."""

    capacity: int
    batch_size: int
    alpha: float
    beta0: float
    rule: block_tree.PriorityRule
    tree: str
    branching: int
    backend: str


def make_prioritized_replay(
    capacity: int,
    batch_size: int,
    alpha: float = 0.6,
    beta0: float = 0.4,
    beta_increment: float = 0.001,
    priority_eps: float = 1e-6,
    branching: int = 16,
    tree: str = "auto",
    backend: str = "auto",
) -> PrioritizedReplay:
    """Prioritised replay (thesis Table 3.2 defaults: α 0.6, β0 0.4, β increment 0.001).

    Args:
      capacity: number of transitions kept (oldest overwritten).
      batch_size: mini-batch size ``m`` (number of strata).
      alpha: priority exponent α ∈ [0, 1] (0 = uniform).
      beta0: initial importance exponent β0 ∈ [0, 1].
      beta_increment: added to β at each ``update_priorities`` (β ≤ 1).
      priority_eps: ε added to ``|δ|``.
      branching: sum-tree branching factor (2 = the binary tree of Fig. 3.2; 16, depth 5 at
        10^6, is the default — :mod:`jaxrl_robot.replay.sum_tree` explains the trade-off).
      tree: ``"sum"`` (:mod:`~jaxrl_robot.replay.sum_tree`, ``branching``-ary), ``"block"``
        (:mod:`~jaxrl_robot.replay.block_tree`, two levels, one fused kernel per sample and per
        update on a GPU) or ``"auto"`` (``"sum"``: see the module docstring).
      backend: the block tree's backend (``"auto"``, ``"pallas"``, ``"xla"``, ``"interpret"``).
    Raises:
      ValueError: naming the field and its allowed range.
    """
    checks = {
        "capacity": (capacity, int(capacity) >= 1, ">= 1"),
        "batch_size": (batch_size, int(batch_size) >= 1, ">= 1"),
        "alpha": (alpha, 0.0 <= alpha <= 1.0, "in [0, 1]"),
        "beta0": (beta0, 0.0 <= beta0 <= 1.0, "in [0, 1]"),
        "beta_increment": (beta_increment, beta_increment >= 0.0, ">= 0"),
        "priority_eps": (priority_eps, priority_eps > 0.0, "> 0"),
        "branching": (branching, int(branching) >= 2, "an integer >= 2"),
        "tree": (tree, tree in TREES, f"one of {TREES}"),
        "backend": (backend, backend in block_tree.BACKENDS, f"one of {block_tree.BACKENDS}"),
    }
    for name, (value, ok, allowed) in checks.items():
        if not ok:
            raise ValueError(f"{name}={value!r} is out of range; allowed {allowed}")
    rule = block_tree.PriorityRule(float(alpha), float(priority_eps), float(beta_increment),
                                   sum_tree.value_limit(int(capacity)))  # fmt: skip
    spec = _Spec(int(capacity), int(batch_size), alpha, beta0, rule, "block" if tree == "block" else "sum",
                 branching, backend)  # fmt: skip
    return PrioritizedReplay(init=functools.partial(_init, spec), add=functools.partial(_add, spec),
                             sample=functools.partial(_sample, spec),
                             update_priorities=functools.partial(_update_priorities, spec))  # fmt: skip


def _init(spec: _Spec, example_item: Any) -> PrioritizedReplayState:
    """Empty buffer for items shaped like ``example_item`` (one item, no batch axis)."""
    zero = jnp.zeros((), jnp.int32)
    if spec.tree == "block":
        tree = block_tree.init(spec.capacity)
    else:
        tree = sum_tree.init(spec.capacity, spec.branching)
    return PrioritizedReplayState(
        data=empty_storage(example_item, spec.capacity),
        tree=tree,
        insert_pos=zero,
        size=zero,
        scalars=jnp.asarray([1.0, spec.beta0], jnp.float32),
        capacity=spec.capacity,
    )


def _add(
    spec: _Spec,
    state: PrioritizedReplayState,
    items: Any,
    priorities: jax.Array | None = None,
    mask: jax.Array | None = None,
) -> PrioritizedReplayState:
    """Store the rows of ``items`` ``[N, ...]`` where ``mask [N]`` is True.

    ``priorities [N]``: raw priorities ``p`` (e.g. ``|δ| + ε`` from a worker's critic; NaN and
    ``±inf`` take the largest priority, as in ``update_priorities``); default: the current
    ``max_priority``.
    """
    data, slots, keep, pos, size = ring_write(state.data, items, state.insert_pos, state.size, spec.capacity, mask)
    if priorities is None:
        p = jnp.full(slots.shape, state.max_priority)
        scalars = state.scalars
    else:
        p = block_tree.raw_priorities(priorities.astype(jnp.float32), state.max_priority, spec.rule, keep)
        scalars = state.scalars.at[0].max(jnp.max(jnp.where(keep, p, 0.0)))
    values = p**spec.alpha
    if spec.tree == "block":
        tree = block_tree.set(state.tree, slots, values, mask=keep, unique_indices=True, backend=spec.backend)
    else:
        tree = sum_tree.set(state.tree, slots, values, mask=keep, unique_indices=True)  # fresh ring slots
    return state.replace(data=data, tree=tree, insert_pos=pos, size=size, scalars=scalars)


def _sample(spec: _Spec, key: jax.Array, state: PrioritizedReplayState) -> PrioritizedSample:
    """Stratified prioritised mini-batch with probabilities and IS weights at the current β.

    Raises:
      ValueError: called eagerly (outside ``jit``) on an empty buffer.  Under ``jit`` an empty
        buffer gives indices 0 with probabilities and weights 0.
    """
    if not isinstance(state.size, jax.core.Tracer) and int(state.size) == 0:
        raise ValueError("sample: the prioritised replay is empty (size 0); call add before sample")
    if spec.tree == "block":  # the block tree's descent of an empty tree already ends on 0
        indices, priorities = block_tree.stratified_sample_with_priorities(
            key, state.tree, batch_size=spec.batch_size, backend=spec.backend
        )
        total = block_tree.total(state.tree)
    else:
        indices, priorities = sum_tree.stratified_sample_with_priorities(key, state.tree, batch_size=spec.batch_size)
        total = sum_tree.total(state.tree)  # > 0 exactly when size > 0: stored leaves are >= tiny
        indices = jnp.where(total > 0, indices, 0)
    probs = priorities / jnp.maximum(total, jnp.finfo(priorities.dtype).tiny)  # empty: 0 / tiny
    weights = jnp.where(state.size > 0, importance_weights(probs, state.size, state.beta), 0.0)
    experience = jax.tree.map(lambda d: d[indices], state.data)
    return PrioritizedSample(experience=experience, indices=indices, probabilities=probs, weights=weights)


def _update_priorities(
    spec: _Spec, state: PrioritizedReplayState, indices: jax.Array, td_errors: jax.Array
) -> PrioritizedReplayState:
    """Set ``p_i = |δ_i| + ε`` at ``indices [B]`` (repeats: last wins) and anneal β.

    A NaN or ``±inf`` ``δ_i`` sets ``p_i`` to ``max(max_priority, max p of the batch's finite
    rows)``, the new ``max_priority`` (count them with :func:`count_nonfinite`); indices outside
    ``[0, size)`` are ignored: they neither write nor raise ``max_priority``.
    """
    indices = indices.astype(jnp.int32)
    td_errors = td_errors.astype(jnp.float32)
    if spec.tree == "block":  # the leaves and both scalars in one kernel on a GPU (it checks the indices)
        new_tree, scalars = block_tree.set_priorities(
            state.tree, indices, td_errors, state.scalars, spec.rule, backend=spec.backend, size=state.size
        )
        return state.replace(tree=new_tree, scalars=scalars)
    valid = (indices >= 0) & (indices < state.size)
    p = block_tree.raw_priorities(td_errors, state.max_priority, spec.rule, valid)
    new_tree = sum_tree.set(state.tree, indices, p**spec.alpha, mask=valid)
    return state.replace(tree=new_tree, scalars=block_tree.next_scalars(state.scalars, p, valid, spec.rule))
