"""Prioritised replay: P(i) ∝ p^α (chi-square), IS weights and β annealing by hand, max-priority inserts."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from jaxrl_robot.replay import make_prioritized_replay

# the sum tree (binary, and 16-ary: one level here), and the block tree's XLA path and its kernels (interpreted)
TREES = {
    "sum2": {"tree": "sum", "branching": 2},
    "sum16": {"tree": "sum", "branching": 16},
    "block-xla": {"tree": "block", "backend": "xla"},
    "block-kernel": {"tree": "block", "backend": "interpret"},
}


def _leaves(state, indices):
    return state.tree.leaf_values[indices]


def _jit(replay):
    """The same buffer with add / sample / update_priorities compiled (one compile each, not one per op)."""
    return replay._replace(add=jax.jit(replay.add), sample=jax.jit(replay.sample),
                           update_priorities=jax.jit(replay.update_priorities))  # fmt: skip


def _item():
    return {"x": jnp.zeros((2,)), "i": jnp.zeros((), jnp.int32)}


def _items(lo, hi):
    i = jnp.arange(lo, hi, dtype=jnp.int32)
    return {"x": jnp.stack([i, -i], -1).astype(jnp.float32), "i": i}


@pytest.mark.parametrize("tree", TREES)
def test_sampling_frequencies_follow_priority_power_alpha(tree):
    alpha = 0.6
    replay = _jit(make_prioritized_replay(capacity=8, batch_size=16, alpha=alpha, beta0=0.4, priority_eps=1e-9,
                                          **TREES[tree]))
    state = replay.add(replay.init(_item()), _items(0, 6))  # slots 6, 7 stay unwritten
    td = jnp.array([0.1, 1.0, 2.0, 0.0, 5.0, 0.5])
    state = replay.update_priorities(state, jnp.arange(6), td)
    keys = jax.random.split(jax.random.PRNGKey(3), 1000)
    idx = np.asarray(jax.jit(jax.vmap(lambda k: replay.sample(k, state).indices))(keys)).ravel()
    counts = np.bincount(idx, minlength=8)
    assert counts[6] == counts[7] == 0  # unwritten slots
    assert counts[3] <= 1  # |δ| = 0 leaves only ε^α ≈ 4e-6 of the mass
    p = np.abs(np.asarray(td, np.float64))[[0, 1, 2, 4, 5]] ** alpha
    observed = counts[[0, 1, 2, 4, 5]]
    expected = p / p.sum() * observed.sum()
    chi2 = stats.chisquare(observed, expected)
    assert chi2.pvalue > 1e-3, (observed, expected)
    # the data returned are the data stored in the sampled slots
    sample = replay.sample(jax.random.PRNGKey(0), state)
    np.testing.assert_array_equal(sample.experience["i"], sample.indices)


@pytest.mark.parametrize("tree", TREES)
def test_importance_weights_and_beta_annealing_by_hand(tree):
    replay = _jit(make_prioritized_replay(capacity=4, batch_size=4, alpha=0.5, beta0=0.4, beta_increment=0.1,
                                          priority_eps=1e-12, **TREES[tree]))
    state = replay.add(replay.init(_item()), _items(0, 4))
    state = replay.update_priorities(state, jnp.arange(4), jnp.array([1.0, 4.0, 9.0, 16.0]))
    assert float(state.beta) == pytest.approx(0.5)
    # p^α = [1, 2, 3, 4]: P = [0.1, 0.2, 0.3, 0.4]; N = 4; w ∝ (N·P)^-β with β = 0.5
    sample = replay.sample(jax.random.PRNGKey(0), state)
    # stratified: one draw in each quarter of [0, 10): segments hit leaves 0-1, 1-2, 2, 3
    probs = np.array([0.1, 0.2, 0.3, 0.4])[np.asarray(sample.indices)]
    np.testing.assert_allclose(sample.probabilities, probs, rtol=1e-6)
    w = (4 * probs) ** -0.5
    np.testing.assert_allclose(sample.weights, w / w.max(), rtol=1e-5)
    hand = {0: 1.0, 1: (0.8) ** -0.5 / (0.4) ** -0.5, 2: (1.2) ** -0.5 / (0.4) ** -0.5, 3: 1.6 ** -0.5 / 0.4 ** -0.5}
    if 0 in np.asarray(sample.indices):  # normalised by the batch's largest weight (the smallest P)
        for i, wi in zip(np.asarray(sample.indices), np.asarray(sample.weights), strict=True):
            assert wi == pytest.approx(hand[int(i)], rel=1e-5)
    # β grows by the increment per update and stops at 1
    for expected in (0.6, 0.7, 0.8, 0.9, 1.0, 1.0):
        state = replay.update_priorities(state, jnp.array([0]), jnp.array([1.0]))
        assert float(state.beta) == pytest.approx(expected)
    # at β = 1 the weights undo the prioritisation exactly: w_i · P(i) is constant
    sample = replay.sample(jax.random.PRNGKey(1), state)
    prod = np.asarray(sample.weights) * np.asarray(sample.probabilities)
    np.testing.assert_allclose(prod, prod[0], rtol=1e-5)


@pytest.mark.parametrize("tree", TREES)
def test_new_items_enter_with_max_priority_or_given_priority(tree):
    replay = _jit(make_prioritized_replay(capacity=6, batch_size=2, alpha=0.5, priority_eps=1e-12, **TREES[tree]))
    state = replay.add(replay.init(_item()), _items(0, 2))
    np.testing.assert_allclose(_leaves(state, jnp.arange(2)), [1.0, 1.0])  # initial max priority 1
    state = replay.update_priorities(state, jnp.array([0, 1]), jnp.array([-9.0, 0.25]))
    assert float(state.max_priority) == pytest.approx(9.0)
    state = replay.add(state, _items(2, 4))
    np.testing.assert_allclose(_leaves(state, jnp.arange(4)), [3.0, 0.5, 3.0, 3.0], rtol=1e-6)
    # a worker's own priorities; masked rows are not stored and the ring packs the rest
    state = replay.add(state, _items(10, 13), priorities=jnp.array([16.0, 100.0, 4.0]),
                       mask=jnp.array([True, False, True]))
    assert int(state.size) == 6 and int(state.insert_pos) == 0
    np.testing.assert_array_equal(state.data["i"], [0, 1, 2, 3, 10, 12])
    np.testing.assert_allclose(_leaves(state, jnp.arange(6))[4:], [4.0, 2.0], rtol=1e-6)
    assert float(state.max_priority) == pytest.approx(16.0)
    # the ring overwrites the oldest slot next, and its priority with it
    state = replay.add(state, _items(20, 21))
    assert int(state.data["i"][0]) == 20 and float(_leaves(state, jnp.array([0]))[0]) == pytest.approx(4.0)


def test_invalid_settings_name_the_field():
    with pytest.raises(ValueError, match=r"alpha=1.5 is out of range; allowed in \[0, 1\]"):
        make_prioritized_replay(10, 4, alpha=1.5)
    with pytest.raises(ValueError, match="beta0=-0.1"):
        make_prioritized_replay(10, 4, beta0=-0.1)
    with pytest.raises(ValueError, match=r"branching=1 is out of range; allowed an integer >= 2"):
        make_prioritized_replay(10, 4, branching=1)
    with pytest.raises(ValueError, match=r"tree='heap' is out of range; allowed one of \('auto', 'sum', 'block'\)"):
        make_prioritized_replay(10, 4, tree="heap")
    replay = make_prioritized_replay(4, 2)
    with pytest.raises(ValueError, match="cannot add 5 items at once to a buffer of capacity 4"):
        replay.add(replay.init(_item()), _items(0, 5))


def test_auto_tree_is_the_sum_tree_on_every_backend():
    """``tree='auto'`` keeps the sum tree (the block tree's kernels compile and run slower inside a trainer)."""
    from jaxrl_robot.replay.block_tree import BlockTreeState
    from jaxrl_robot.replay.sum_tree import SumTreeState

    auto = make_prioritized_replay(capacity=8, batch_size=2).init(_item())
    block = make_prioritized_replay(capacity=8, batch_size=2, tree="block", backend="xla").init(_item())
    assert isinstance(auto.tree, SumTreeState) and isinstance(block.tree, BlockTreeState)
