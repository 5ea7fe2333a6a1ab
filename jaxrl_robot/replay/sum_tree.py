"""An array-backed sum-tree: batched priority set, total and stratified sampling (thesis Fig. 3.2).

Leaves hold non-negative priorities; each internal node stands for the sum of its children,
so the root is the total ``p_total``.  Sampling a value ``q ∈ [0, p_total)`` descends from
the root, going to the first child whose running sum exceeds ``q``; leaf ``i`` is reached
with probability ``p_i / p_total``.  Stratified sampling (Schaul et al.; thesis §3.2) splits
``[0, p_total]`` into ``m`` equal segments and draws one query in each.

Layout.  The tree has a configurable ``branching`` factor ``b`` and depth
``d = max(1, ⌈log_b N⌉)`` (``b = 2`` is the binary tree of Fig. 3.2).  Besides the raw
``leaf_values`` it stores, for every level ``l = 1 … d``, the **running sums of each
sibling block**: ``prefix[l-1][p·b + k] = v(c_0) + … + v(c_k)`` over the children
``c_0 … c_{b-1}`` of node ``p`` of level ``l - 1``, added left to right.  A node's own sum
is the last running sum of its children's block, so the root total is ``prefix[0][b-1]``.

Why this layout (inside a jitted training step the cost is set by the number of separate
kernels XLA launches and the elements each touches, not by the arithmetic of a descent):

* **Sample: one reduction per level.**  A level of the descent gathers the ``b`` stored
  running sums of the current node's children and counts how many are ``<= q`` — no
  cumsum, sort or search at sampling time.  The count is a reduction, so XLA materialises
  it once instead of re-deriving the descent inside every consumer (an unrolled
  elementwise descent was several times slower on the CPU for exactly that reason).
* **Update: one row scatter per level.**  The leaves are scattered, then for each level the
  blocks holding a written node are recomputed from their ``b`` children and written back as
  ``[B, b]`` rows.  Blocks written twice receive the same row, so repeats need no care above
  the leaves.
* **Repeated leaf indices** are resolved by an all-pairs compare (one fused ``[B, B]``
  reduction) for batches up to :data:`PAIRWISE_MAX` rows and by a stable sort above; ``add``
  of fresh ring slots skips the search (``unique_indices=True``).

Depth against width: a level costs one reduction kernel and ``m · b`` compares to sample,
and one ``[B, b]`` row to update (built by an unrolled add chain that XLA re-evaluates per
element, so ``O(b²)`` adds per row).  Measured at capacity 10^6 on the 2-core CPU
(``benchmarks/results/cpu-2core-replay_throughput.md``, batch 128 and 256): ``b = 16``
samples fastest (``b = 32`` level with it at 128) and has the cheapest sample → write-back step
as DDPG fuses it (142 and 253 µs against ``b = 8``'s 147 and 266); ``b = 8`` updates about
2 × faster, so its sample and update timed apart add up to about 1.1 × less; ``b = 2`` (20
levels) pays a kernel per level and ``b >= 32`` pays for its rows.  On a GPU, where a kernel
launch costs more than these few thousand compares, the two extra levels of ``b = 8`` add
launches to both sample and update; ``python -m benchmarks.replay_throughput`` prints the
branchings side by side so the default can follow the GPU measurement.  On an H200 (capacity
10^6, batch 128 and 256, ``gpu-nvidia_h200-replay_throughput.md``) ``b = 8``, ``16`` and ``32``
came within 8 % of one another (sample + update 46–49 µs), so 16 stays.

All functions are pure, jittable and vmappable; nothing is jitted here.

Numerical robustness (float32):

* **No drift.**  An update never adds a delta to the ancestors of a leaf (the usual
  implementation, whose rounding errors accumulate over millions of updates until the root
  no longer equals the sum of the leaves and may even go negative).  Instead every block of
  running sums on the path of a changed leaf is *recomputed* from its children in a fixed
  order.  The stored sums are therefore a function of the current leaves only, whatever the
  history (bit-identical to :func:`rebuild`), and the root differs from the exact sum of the
  leaves only by the rounding of one summation per level — an error that does not grow with
  the number of updates.
* **Zero-priority and unwritten slots are never sampled.**  Running sums never decrease
  along a block and a zero child leaves the running sum unchanged (for ``b <= UNROLL_MAX``
  they are sequential adds; wider blocks take ``cummax`` over the cumsum at positive
  children, since a parallel cumsum may round non-monotonically).  The child chosen for
  ``q`` is the first whose running sum exceeds ``q``, so it always adds a positive amount:
  a zero child is never chosen.  Rounding can push a query to or past the total of a block
  (e.g. ``u · total`` rounding up to ``total``); the query is clamped to just below the
  block total first, which lands on the last child that raised the running sum, never a
  zero (unwritten) subtree, so a leaf with priority 0 is unreachable whenever ``total > 0``.
  Negative priorities are clamped to 0 when set.  XLA flushes subnormal floats
  (< 1.2e-38 in float32) to zero, so such priorities count as 0; the prioritised replay
  keeps every priority at or above ``ε^α``.
* **Bad input cannot poison the tree.**  NaN values are stored as 0 and values (``+inf``
  included) are clipped to :func:`value_limit` ``= max float / (4 · capacity)``, so the total
  of all leaves stays finite; indices outside ``[0, capacity)`` (negative ones included, which
  JAX indexing would otherwise wrap to the end) are ignored like masked-out rows.
* **Duplicate indices in one batch** (common when priorities of a prioritised mini-batch
  are written back) follow sequential semantics: the *last* occurrence wins.  XLA leaves
  the order of a scatter with repeated indices unspecified, so repeated indices are
  masked out before the leaf write.
* ``dtype=jnp.float64`` is accepted when ``jax_enable_x64`` is on.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

__all__ = [
    "PAIRWISE_MAX",
    "UNROLL_MAX",
    "SumTreeState",
    "clean_values",
    "find",
    "find_with_priorities",
    "get",
    "in_range",
    "init",
    "last_occurrence_mask",
    "probabilities",
    "rebuild",
    "running_sums",
    "set",
    "stratified_sample",
    "stratified_sample_with_priorities",
    "total",
    "value_limit",
]

UNROLL_MAX = 32
"""Widest block whose running sums are sequential adds; wider blocks use cumsum + cummax."""

PAIRWISE_MAX = 1024
"""Largest batch whose repeated indices are found by an all-pairs compare (else a sort)."""


@struct.dataclass
class SumTreeState:
    """Sum-tree arrays.

    Attributes:
      leaf_values: ``[b**depth]`` raw priorities (slots ``>= capacity`` stay 0).
      prefix: ``prefix[l-1]`` (``l = 1 … depth``) has ``b**l`` entries: the running sums of
        each block of ``b`` siblings of level ``l`` (see the module docstring).
      capacity: number of usable leaves (static).
      branching: children per internal node ``b`` (static).
    """

    leaf_values: jax.Array
    prefix: tuple[jax.Array, ...]
    capacity: int = struct.field(pytree_node=False)
    branching: int = struct.field(pytree_node=False)

    @property
    def depth(self) -> int:
        return len(self.prefix)

    @property
    def leaves(self) -> jax.Array:
        """``[capacity]`` leaf priorities."""
        return self.leaf_values[: self.capacity]

    @property
    def levels(self) -> tuple[jax.Array, ...]:
        """Node sums per level, root first: ``levels[l]`` has ``b**l`` entries, ``levels[-1]`` the leaves."""
        b = self.branching
        sums = [p.reshape(-1, b)[:, -1] for p in self.prefix]  # level l-1 from the blocks of level l
        return (*sums, self.leaf_values)


def value_limit(capacity: int, dtype: jnp.dtype = jnp.float32) -> float:
    """The largest value a leaf stores, ``max float / (4 · capacity)``: the sum of ``capacity`` such
    leaves, and every running sum, stays finite with room for rounding."""
    return float(jnp.finfo(dtype).max) / (4 * int(capacity))


def clean_values(values: jax.Array, capacity: int) -> jax.Array:
    """``[B] -> [B]``: values as leaves store them: NaN and negative -> 0, above :func:`value_limit` -> the limit."""
    return jnp.where(values > 0, jnp.minimum(values, value_limit(capacity, values.dtype)), 0)


def in_range(indices: jax.Array, capacity: int, mask: jax.Array | None = None) -> jax.Array:
    """``[B] bool``: ``0 <= indices < capacity`` (and ``mask``, when given)."""
    inside = (indices >= 0) & (indices < capacity)
    return inside if mask is None else inside & mask.astype(bool)


def _depth(capacity: int, branching: int) -> int:
    depth, n = 1, branching
    while n < capacity:
        n *= branching
        depth += 1
    return depth


def init(capacity: int, branching: int = 16, dtype: jnp.dtype = jnp.float32) -> SumTreeState:
    """An all-zero tree with ``capacity`` leaves.

    Raises:
      ValueError: ``capacity < 1`` or ``branching < 2``.
    """
    if int(capacity) < 1:
        raise ValueError(f"capacity={capacity!r} must be >= 1")
    if int(branching) < 2:
        raise ValueError(f"branching={branching!r} must be >= 2")
    capacity, branching = int(capacity), int(branching)
    depth = _depth(capacity, branching)
    prefix = tuple(jnp.zeros((branching**level,), dtype) for level in range(1, depth + 1))
    return SumTreeState(
        leaf_values=jnp.zeros((branching**depth,), dtype), prefix=prefix, capacity=capacity, branching=branching
    )


def total(state: SumTreeState) -> jax.Array:
    """The root: sum of all priorities, ``[]``."""
    return state.prefix[0][state.branching - 1]


def get(state: SumTreeState, indices: jax.Array) -> jax.Array:
    """Leaf priorities at ``indices [B]`` -> ``[B]``."""
    return state.leaf_values[indices]


def probabilities(state: SumTreeState, indices: jax.Array) -> jax.Array:
    """Sampling probabilities ``p_i / p_total`` at ``indices [B]`` -> ``[B]``."""
    return get(state, indices) / total(state)


def last_occurrence_mask(indices: jax.Array) -> jax.Array:
    """``[B] bool``: True where no later entry of ``indices [B]`` has the same value.

    Up to :data:`PAIRWISE_MAX` rows: an all-pairs compare, one fused ``[B, B]`` reduction.
    Above: a stable sort keeps equal indices in batch order, so the last element of each
    run of equal sorted values is the last occurrence in the batch, O(B log B).
    """
    chex.assert_rank(indices, 1)
    n = indices.shape[0]
    if n <= PAIRWISE_MAX:
        pos = jnp.arange(n)
        later_same = (indices[None, :] == indices[:, None]) & (pos[None, :] > pos[:, None])  # [i, j]
        return ~jnp.any(later_same, axis=1)
    order = jnp.argsort(indices, stable=True)
    sorted_idx = indices[order]
    last_sorted = jnp.concatenate([sorted_idx[1:] != sorted_idx[:-1], jnp.ones((1,), bool)])
    return jnp.zeros(indices.shape, bool).at[order].set(last_sorted)


def running_sums(children: jax.Array) -> jax.Array:
    """``[..., b] -> [..., b]``: running sums of sibling values, non-decreasing, flat at zero children.

    ``b <= UNROLL_MAX``: sequential adds left to right.  Wider: ``cummax`` of the cumsum
    taken at positive children (a parallel cumsum may round non-monotonically).
    """
    b = children.shape[-1]
    if b > UNROLL_MAX:
        csum = jnp.cumsum(children, axis=-1)
        return jax.lax.cummax(jnp.where(children > 0, csum, 0), axis=children.ndim - 1)
    run = [children[..., 0]]
    for k in range(1, b):
        run.append(run[-1] + children[..., k])
    return jnp.stack(run, axis=-1)


def _child_values(state: SumTreeState, level: int, parents: jax.Array, prefix: list[jax.Array]) -> jax.Array:
    """``[B, b]`` values of the children (level ``level``) of ``parents [B]`` (level ``level - 1``)."""
    b = state.branching
    if level == state.depth:
        return state.leaf_values.reshape(-1, b)[parents]
    return prefix[level].reshape(-1, b, b)[parents, :, b - 1]  # each child's sum ends its own block


def set(
    state: SumTreeState,
    indices: jax.Array,
    values: jax.Array,
    mask: jax.Array | None = None,
    unique_indices: bool = False,
) -> SumTreeState:
    """Set leaf priorities and recompute the running sums on their paths.

    Args:
      state: the tree.
      indices: ``[B]`` int leaf indices; repeats allowed (last wins); rows outside
        ``[0, capacity)`` are ignored.
      values: ``[B]`` new priorities (negative and NaN values are stored as 0, values above
        :func:`value_limit` as the limit).
      mask: optional ``[B]`` bool; entries with False are ignored.
      unique_indices: static promise that the masked-in ``indices`` are distinct (a ring
        buffer's fresh slots); skips the search for repeats.
    Returns:
      The new tree; cost O(B · depth · branching), one ``[B, b]`` row scatter per level.
    """
    chex.assert_rank([indices, values], 1)
    chex.assert_equal_shape([indices, values])
    b = state.branching
    mask = in_range(indices, state.capacity, mask)
    if unique_indices:
        keep = mask
    else:  # ignored rows must not shadow an earlier written row with the same index
        keep = last_occurrence_mask(jnp.where(mask, indices, -1)) & mask
    leaves = state.leaf_values
    write_at = jnp.where(keep, indices, leaves.shape[0])  # out of range -> dropped
    values = clean_values(values.astype(leaves.dtype), state.capacity)
    state = state.replace(leaf_values=leaves.at[write_at].set(values, mode="drop"))
    prefix = list(state.prefix)
    node = jnp.where(keep, indices, 0)  # recomputing an unchanged block is harmless
    for level in range(state.depth, 0, -1):
        node = node // b
        rows = running_sums(_child_values(state, level, node, prefix))  # [B, b]
        prefix[level - 1] = prefix[level - 1].reshape(-1, b).at[node].set(rows).reshape(-1)
    return state.replace(prefix=tuple(prefix))


def rebuild(state: SumTreeState) -> SumTreeState:
    """Recompute every running sum from the leaves (O(N)); bit-identical to what :func:`set` keeps."""
    b = state.branching
    prefix = list(state.prefix)
    children = state.leaf_values.reshape(-1, b)
    for level in range(state.depth, 0, -1):
        rows = running_sums(children)
        prefix[level - 1] = rows.reshape(-1)
        children = rows[:, -1].reshape(-1, b) if level > 1 else None
    return state.replace(prefix=tuple(prefix))


def find(state: SumTreeState, queries: jax.Array) -> jax.Array:
    """Leaves whose prefix-sum interval contains each query: ``[B] -> [B] int32``.

    Leaf ``i`` covers ``[Σ_{j<i} p_j, Σ_{j<=i} p_j)``; queries at or beyond the total (from
    rounding) land on the last leaf with positive priority.  Zero-priority leaves are
    never returned while ``total(state) > 0``.
    """
    chex.assert_rank(queries, 1)
    b = state.branching
    q = jnp.maximum(queries.astype(state.leaf_values.dtype), 0)
    node = jnp.zeros(q.shape, jnp.int32)
    for level in range(1, state.depth + 1):
        run = state.prefix[level - 1].reshape(-1, b)
        block_total = run[node, b - 1]
        q = jnp.minimum(q, jnp.nextafter(block_total, jnp.zeros_like(block_total)))  # stay inside the block
        j = jnp.minimum(jnp.sum(run[node] <= q[:, None], axis=-1, dtype=jnp.int32), b - 1)  # first sum above q
        q = jnp.maximum(q - jnp.where(j > 0, run[node, jnp.maximum(j - 1, 0)], 0), 0)
        node = node * b + j
    return node


def find_with_priorities(state: SumTreeState, queries: jax.Array) -> tuple[jax.Array, jax.Array]:
    """:func:`find` and the found leaves' priorities: ``[B] -> ([B] int32, [B])``."""
    indices = find(state, queries)
    return indices, get(state, indices)


def _stratified_queries(key: jax.Array, state: SumTreeState, batch_size: int) -> jax.Array:
    u = jax.random.uniform(key, (batch_size,), state.leaf_values.dtype)
    segment = total(state) / batch_size
    return (jnp.arange(batch_size, dtype=u.dtype) + u) * segment


def stratified_sample(key: jax.Array, state: SumTreeState, batch_size: int) -> jax.Array:
    """Stratified sampling (Fig. 3.2): one draw in each of ``batch_size`` equal segments.

    Segment ``i`` is ``[i, i + 1) · p_total / batch_size``; each draw is located by
    :func:`find`.  Returns ``[batch_size] int32`` leaf indices.  With ``total == 0`` (empty
    tree) the result is meaningless; callers sample only once something is stored.
    """
    return find(state, _stratified_queries(key, state, batch_size))


def stratified_sample_with_priorities(
    key: jax.Array, state: SumTreeState, batch_size: int
) -> tuple[jax.Array, jax.Array]:
    """:func:`stratified_sample` plus the sampled leaves' priorities: ``([m] int32, [m])``."""
    return find_with_priorities(state, _stratified_queries(key, state, batch_size))
