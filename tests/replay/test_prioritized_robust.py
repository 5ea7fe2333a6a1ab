"""Prioritised replay under bad input: NaN / ±inf / huge TD errors and out-of-range indices never
poison the tree, against a NumPy oracle of the same semantics (hypothesis streams of add / update /
sample, and 10^6 updates in one scan), for the sum tree and the block tree (XLA path and kernels)."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrl_robot.replay import block_tree, count_nonfinite, make_prioritized_replay, sum_tree

CAPACITY, ADD, UPDATE, BATCH = 40, 16, 8, 8  # fixed shapes: each jitted function compiles once per tree
ALPHA, BETA0, BETA_INC, EPS = 0.6, 0.4, 0.05, 1e-6
F32 = np.finfo(np.float32)
# sum tree: 4-ary, depth 3, 64 leaves; block tree: 4 blocks of 16 leaves (XLA path, and its kernels interpreted)
TREES = {
    "sum4": {"tree": "sum", "branching": 4},
    "block-xla": {"tree": "block", "backend": "xla"},
    "block-kernel": {"tree": "block", "backend": "interpret"},
}


@functools.cache
def _replay(name, capacity=CAPACITY, batch_size=BATCH, alpha=ALPHA):
    """The replay of ``name`` with add / sample / update_priorities jitted (shared by every test)."""
    r = make_prioritized_replay(capacity, batch_size, alpha=alpha, beta0=BETA0, beta_increment=BETA_INC,
                                priority_eps=EPS, **TREES[name])  # fmt: skip
    return r._replace(add=jax.jit(r.add), sample=jax.jit(r.sample), update_priorities=jax.jit(r.update_priorities))


def _total(tree):
    return sum_tree.total(tree) if isinstance(tree, sum_tree.SumTreeState) else block_tree.total(tree)


def _item():
    return {"i": jnp.zeros((), jnp.int32)}


class Oracle:
    """The replay's semantics in float64 NumPy, one row at a time.

    Raw priority ``|δ| + ε`` kept in ``[tiny, max float / (4 · capacity)]``, and where ``δ`` is not
    finite the largest after the batch's finite rows; leaves ``p^α``; updates only at
    ``0 <= i < size`` (the last repeat wins); ``P = leaf / Σ leaves``; ``w = (N·P)^-β / max w``.
    """

    def __init__(self, capacity=CAPACITY, alpha=ALPHA):
        self.capacity, self.alpha = capacity, alpha
        self.raw = np.zeros(capacity)
        self.ids = np.zeros(capacity, np.int64)
        self.size = self.pos = 0
        self.max_p, self.beta = 1.0, BETA0
        self.limit = float(np.float32(F32.max / (4 * capacity)))

    def raw_of(self, td, valid=None):
        """Raw priorities of ``td``; ``valid`` rows' finite priorities count toward the largest."""
        td = np.asarray(td, np.float32).astype(np.float64)
        finite = np.isfinite(td)
        p = np.clip(np.where(finite, np.abs(td) + EPS, 0.0), F32.tiny, self.limit)
        seen = finite if valid is None else finite & valid
        return np.where(finite, p, max(self.max_p, p[seen].max(initial=0.0)))

    def add(self, ids, priorities=None):
        p = np.full(len(ids), self.max_p) if priorities is None else self.raw_of(priorities)
        for i, pi in zip(ids, p, strict=True):
            self.raw[self.pos], self.ids[self.pos] = pi, i
            self.pos, self.size = (self.pos + 1) % self.capacity, min(self.size + 1, self.capacity)
        if priorities is not None and len(ids):
            self.max_p = max(self.max_p, float(p.max()))

    def update(self, indices, td):
        p = self.raw_of(td, (np.asarray(indices) >= 0) & (np.asarray(indices) < self.size))
        for i, pi in zip(indices, p, strict=True):
            if 0 <= i < self.size:
                self.raw[i] = pi
                self.max_p = max(self.max_p, float(pi))
        self.beta = min(self.beta + BETA_INC, 1.0)

    @property
    def leaves(self):
        return self.raw**self.alpha

    def probabilities(self):
        return self.leaves / self.leaves.sum()

    def weights(self, indices):
        w = (self.size * self.probabilities()[indices]) ** -self.beta
        return w / w.max()


def _check_state(state, oracle):
    """Leaves, total, max priority, β, ring position and stored ids equal the oracle's."""
    leaves, total, scalars, size, pos, ids = jax.device_get(
        (state.tree.leaf_values, _total(state.tree), state.scalars, state.size, state.insert_pos, state.data["i"]))
    assert int(size) == oracle.size and int(pos) == oracle.pos
    np.testing.assert_array_equal(ids[: oracle.size], oracle.ids[: oracle.size])
    np.testing.assert_allclose(leaves[: oracle.capacity], oracle.leaves, rtol=1e-5, atol=0)
    assert np.all(leaves[oracle.capacity :] == 0)  # the padding beyond the capacity is never written
    assert np.isfinite(total) and np.isfinite(scalars).all()
    np.testing.assert_allclose(total, oracle.leaves.sum(), rtol=1e-5)
    np.testing.assert_allclose(scalars, [oracle.max_p, oracle.beta], rtol=1e-6)


def _check_sample(sample, oracle):
    """Indices of stored rows, their probabilities and importance weights (no NaN), the rows' data."""
    idx, probs, weights, ids = jax.device_get((sample.indices, sample.probabilities, sample.weights,
                                               sample.experience["i"]))  # fmt: skip
    if oracle.size == 0:  # under jit: index 0 with probability and weight 0
        np.testing.assert_array_equal(idx, 0)
        np.testing.assert_array_equal(probs, 0.0)
        np.testing.assert_array_equal(weights, 0.0)
        return
    assert idx.min() >= 0 and idx.max() < oracle.size
    np.testing.assert_allclose(probs, oracle.probabilities()[idx], rtol=1e-5)
    assert np.isfinite(weights).all()
    np.testing.assert_allclose(weights, oracle.weights(idx), rtol=1e-4, atol=1e-7)
    np.testing.assert_array_equal(ids, oracle.ids[idx])


# TD errors: ordinary, non-finite, huge (clipped to the limit), zero, tiny
TD = st.one_of(
    st.floats(-1e3, 1e3, allow_subnormal=False, width=32),
    st.sampled_from([np.nan, np.inf, -np.inf, 0.0, -3e38, 3e38, 1e30, -1e-30]),
)
# indices: few distinct (repeats in a batch), or anywhere from negative to past the padded leaves (64)
INDEX = st.one_of(st.integers(0, 5), st.integers(-45, 70))
OP = st.one_of(
    st.tuples(st.just("add"), st.integers(0, ADD), st.none() | st.lists(TD, min_size=ADD, max_size=ADD)),
    st.tuples(st.just("update"), st.lists(INDEX, min_size=UPDATE, max_size=UPDATE),
              st.lists(TD, min_size=UPDATE, max_size=UPDATE)),
    st.tuples(st.just("sample"), st.integers(0, 2**31 - 1)),
)  # fmt: skip


@settings(max_examples=25, deadline=None)
@given(st.lists(OP, min_size=1, max_size=10))
def test_random_streams_match_the_numpy_oracle_on_every_tree(ops):
    replays = {name: _replay(name) for name in TREES}
    states = {name: r.init(_item()) for name, r in replays.items()}
    oracle = Oracle()
    next_id = 0
    for op in [*ops, ("sample", 0)]:
        if op[0] == "add":
            _, n, prio = op
            ids = jnp.arange(next_id, next_id + ADD, dtype=jnp.int32)
            mask = jnp.arange(ADD) < n
            given_p = None if prio is None else jnp.asarray(prio, jnp.float32)
            states = {k: replays[k].add(s, {"i": ids}, given_p, mask) for k, s in states.items()}
            oracle.add(np.arange(next_id, next_id + n), None if prio is None else prio[:n])
            next_id += ADD
        elif op[0] == "update":
            _, idx, td = op
            args = (jnp.asarray(idx, jnp.int32), jnp.asarray(td, jnp.float32))
            states = {k: replays[k].update_priorities(s, *args) for k, s in states.items()}
            oracle.update(idx, td)
        else:
            key = jax.random.PRNGKey(op[1])
            for k, s in states.items():
                _check_sample(replays[k].sample(key, s), oracle)
        for s in states.values():
            _check_state(s, oracle)


@pytest.mark.parametrize("tree", TREES)
def test_nonfinite_td_takes_the_largest_priority_and_later_adds_stay_finite(tree):
    replay = _replay(tree)
    mask = jnp.arange(ADD) < 8
    state = replay.add(replay.init(_item()), {"i": jnp.arange(ADD, dtype=jnp.int32)}, None, mask)
    td = jnp.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])  # raw priorities |δ| + ε: max 7
    state = replay.update_priorities(state, jnp.arange(8), td)
    assert float(state.max_priority) == pytest.approx(7.0)
    bad = jnp.array([jnp.nan, jnp.inf, -jnp.inf, 1.0, 1.0, 1.0, 1.0, 1.0])
    assert int(count_nonfinite(bad)) == 3
    state = replay.update_priorities(state, jnp.arange(8), bad)
    raw = np.array([7.0, 7.0, 7.0, 1.0, 1.0, 1.0, 1.0, 1.0])  # + ε
    assert float(state.max_priority) == pytest.approx(7.0)  # neither NaN nor inf
    np.testing.assert_allclose(state.tree.leaf_values[:8], raw**ALPHA, rtol=1e-5)
    # new rows enter with the (finite) largest priority; the tree stays finite
    state = replay.add(state, {"i": jnp.arange(ADD, dtype=jnp.int32)}, None, jnp.arange(ADD) < 2)
    np.testing.assert_allclose(float(_total(state.tree)), (raw**ALPHA).sum() + 2 * 7.0**ALPHA, rtol=1e-5)
    sample = replay.sample(jax.random.PRNGKey(0), state)
    assert np.isfinite(sample.weights).all() and len(np.unique(sample.indices)) > 1
    # a priority given to add is cleaned the same way
    state = replay.add(state, {"i": jnp.arange(ADD, dtype=jnp.int32)}, jnp.full((ADD,), jnp.nan), mask)
    np.testing.assert_allclose(state.tree.leaf_values[10:18], 7.0**ALPHA, rtol=1e-5)
    assert float(state.max_priority) == pytest.approx(7.0)
    # the batch's own finite rows count first: a NaN next to δ = 9 takes 9 (out-of-range rows don't count)
    idx = jnp.array([0, 1, 2, 2, 3, 3, 50, -1])
    state = replay.update_priorities(state, idx, jnp.array([jnp.nan, 9.0, 1.0, jnp.inf, 2.0, 2.0, 20.0, 30.0]))
    np.testing.assert_allclose(state.tree.leaf_values[:4], np.array([9.0, 9.0, 9.0, 2.0]) ** ALPHA, rtol=1e-5)
    assert float(state.max_priority) == pytest.approx(9.0)


@pytest.mark.parametrize("tree", TREES)
def test_out_of_range_indices_neither_write_nor_raise_the_max(tree):
    replay = _replay(tree)
    state = replay.add(replay.init(_item()), {"i": jnp.arange(ADD, dtype=jnp.int32)}, None, jnp.arange(ADD) < 8)
    before = np.asarray(state.tree.leaf_values)
    # -1 would wrap to the last slot; 8 is an empty slot (size 8); 40 is the capacity; 64 past the padded leaves
    idx = jnp.array([-1, 8, 39, 40, 63, 64, 100, -17])
    state = replay.update_priorities(state, idx, jnp.full((UPDATE,), 5.0))
    np.testing.assert_array_equal(np.asarray(state.tree.leaf_values), before)
    assert float(state.max_priority) == 1.0 and float(state.beta) == pytest.approx(BETA0 + BETA_INC)
    # in-range rows of the same batch are written, and only they raise the max
    state = replay.update_priorities(state, jnp.array([-1, 3, 8, 3, 40, 7, -8, 100]), jnp.full((UPDATE,), 4.0))
    leaves = np.asarray(state.tree.leaf_values)
    np.testing.assert_allclose(leaves[[3, 7]], (4.0 + EPS) ** ALPHA, rtol=1e-5)
    assert leaves[8:].sum() == 0 and float(state.max_priority) == pytest.approx(4.0)
    idx = [replay.sample(jax.random.PRNGKey(k), state).indices for k in range(16)]  # 128 draws
    assert int(jnp.max(jnp.stack(idx))) < 8 and int(jnp.min(jnp.stack(idx))) >= 0


@pytest.mark.parametrize("tree", TREES)
def test_empty_buffer_raises_eagerly_and_gives_zero_weights_under_jit(tree):
    replay = _replay(tree)
    plain = make_prioritized_replay(CAPACITY, BATCH, **TREES[tree])  # not jitted
    state = replay.init(_item())
    with pytest.raises(ValueError, match=r"^sample: the prioritised replay is empty \(size 0\); call add before"):
        plain.sample(jax.random.PRNGKey(0), state)
    _check_sample(replay.sample(jax.random.PRNGKey(0), state), Oracle())


MILLION_CAPACITY, MILLION_SIZE, MILLION_BATCHES, MILLION_ROWS = 1 << 16, 50_000, 250, 4096


def _million_stream(seed=0):
    """``[250, 4096]`` indices (5 % negative, 5 % in ``[size, capacity)``, 5 % ``>= capacity``) and TD
    errors over 12 orders of magnitude with 1 % each of NaN, +inf, -inf and ``±3e38``."""
    rng = np.random.default_rng(seed)
    shape = (MILLION_BATCHES, MILLION_ROWS)
    idx = rng.integers(0, MILLION_SIZE, shape)
    kind = rng.random(shape)
    idx = np.where(kind < 0.05, -rng.integers(1, 2 * MILLION_CAPACITY, shape), idx)
    idx = np.where((kind >= 0.05) & (kind < 0.10), rng.integers(MILLION_SIZE, MILLION_CAPACITY, shape), idx)
    idx = np.where((kind >= 0.10) & (kind < 0.15), rng.integers(MILLION_CAPACITY, 3 * MILLION_CAPACITY, shape), idx)
    td = rng.standard_normal(shape) * 10.0 ** rng.uniform(-6, 6, shape)
    special = rng.random(shape)
    td = np.where(special < 0.01, np.nan, td)
    td = np.where((special >= 0.01) & (special < 0.02), np.inf, td)
    td = np.where((special >= 0.02) & (special < 0.03), -np.inf, td)
    td = np.where((special >= 0.03) & (special < 0.04), 3e38 * np.sign(td - 0.5), td)
    return idx.astype(np.int32), td.astype(np.float32)


def _million_oracle(idx, td):
    """The oracle's update, vectorised per batch (the last valid repeat of an index wins)."""
    oracle = Oracle(MILLION_CAPACITY, alpha=1.0)
    oracle.raw[:MILLION_SIZE], oracle.size, oracle.pos = 1.0, MILLION_SIZE, MILLION_SIZE  # ids stay 0
    for i, d in zip(idx, td, strict=True):
        valid = (i >= 0) & (i < oracle.size)
        vi, vp = i[valid], oracle.raw_of(d, valid)[valid]
        slots, last = np.unique(vi[::-1], return_index=True)
        oracle.raw[slots] = vp[::-1][last]
        oracle.max_p = max(oracle.max_p, float(vp.max(initial=0.0)))
        oracle.beta = min(oracle.beta + BETA_INC, 1.0)
    return oracle


@pytest.fixture(scope="module")
def million():
    idx, td = _million_stream()
    return idx, td, _million_oracle(idx, td)


@pytest.mark.parametrize("tree", ["sum16", "block-xla"])
def test_a_million_updates_with_bad_rows_match_the_oracle(tree, million):
    """α = 1: without the limit on raw priorities two TD errors of 3e38 would make the total inf."""
    idx, td, oracle = million
    kw = {"sum16": {"tree": "sum", "branching": 16}, "block-xla": {"tree": "block", "backend": "xla"}}[tree]
    replay = make_prioritized_replay(MILLION_CAPACITY, BATCH, alpha=1.0, beta0=BETA0, beta_increment=BETA_INC,
                                     priority_eps=EPS, **kw)  # fmt: skip
    rebuild = sum_tree.rebuild if tree == "sum16" else block_tree.rebuild

    @jax.jit
    def run(idx, td):
        # MILLION_SIZE rows at the initial largest priority 1, as add leaves them (add itself compiles longer)
        state = replay.init(_item())
        leaves = state.tree.leaf_values.at[:MILLION_SIZE].set(1.0)
        size = jnp.asarray(MILLION_SIZE, jnp.int32)
        state = state.replace(tree=rebuild(state.tree.replace(leaf_values=leaves)), size=size, insert_pos=size)
        state, _ = jax.lax.scan(lambda s, x: (replay.update_priorities(s, *x), None), state, (idx, td))
        return state, replay.sample(jax.random.PRNGKey(0), state)

    state, sample = run(idx, td)
    _check_state(state, oracle)
    assert oracle.max_p == oracle.limit  # the ±3e38 rows, clipped
    _check_sample(sample, oracle)
