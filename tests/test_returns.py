"""GAE, λ-returns and n-step returns against hand-computed values and plain Python loops."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrl_robot.returns import gae, lambda_returns, n_step_returns, over_lanes, td_errors


def segment_len(term, trunc, t):
    """Steps from ``t`` up to and including the first termination or truncation, or to the stream end."""
    for k in range(t, len(term)):
        if term[k] or trunc[k]:
            return k - t + 1
    return len(term) - t


def loop_gae(r, v, nv, term, trunc, gamma, lam):
    """Eq. 5.12 written out: A_t = Σ_k (γλ)^k δ_{t+k} up to the episode or stream end."""
    delta = [r[t] + gamma * (1 - term[t]) * nv[t] - v[t] for t in range(len(r))]

    def at(t):
        return sum((gamma * lam) ** i * delta[t + i] for i in range(segment_len(term, trunc, t)))

    return np.array([at(t) for t in range(len(r))])


def loop_nstep(r, nv, term, trunc, gamma, n):
    """R_t^{(k)} = Σ_{i<k} γ^i r_{t+i} + γ^k V(s'_{t+k-1}), k ≤ n, stopping at episode/stream end."""

    def at(t):
        k = min(n, segment_len(term, trunc, t))
        last = t + k - 1
        return sum(gamma**i * r[t + i] for i in range(k)) + (0.0 if term[last] else gamma**k * nv[last])

    return np.array([at(t) for t in range(len(r))])


def loop_lambda_returns(r, nv, term, trunc, gamma, lam):
    """(1-λ) Σ_{n=1}^{L-1} λ^{n-1} R^{(n)} + λ^{L-1} R^{(L)} with L the steps left in the episode segment."""

    def at(t):
        L = segment_len(term, trunc, t)
        rets = [loop_nstep(r[t:], nv[t:], term[t:], trunc[t:], gamma, n)[0] for n in range(1, L + 1)]
        return sum((1 - lam) * lam ** (n - 1) * rets[n - 1] for n in range(1, L)) + lam ** (L - 1) * rets[L - 1]

    return np.array([at(t) for t in range(len(r))])


def f32(x):
    return jnp.asarray(x, jnp.float32)


def test_gae_hand_computed_truncation_bootstraps_termination_does_not():
    gamma, lam = 0.5, 0.5
    r = f32([1.0, 1.0, 1.0])
    v = f32([0.0, 0.0, 0.0])
    nv = f32([2.0, 2.0, 2.0])
    # Termination at t=1: δ_1 = 1 (no bootstrap), δ_0 = 1 + 0.5*2 = 2, A_0 = 2 + 0.25*1 = 2.25, A_2 = 1 + 1 = 2.
    adv = gae(r, v, nv, f32([0, 1, 0]), f32([0, 0, 0]), gamma, lam)
    np.testing.assert_allclose(adv, [2.25, 1.0, 2.0])
    # Truncation at t=1: δ_1 = 1 + 0.5*2 = 2 (bootstraps from V(s'_1)); the recursion still stops there.
    adv = gae(r, v, nv, f32([0, 0, 0]), f32([0, 1, 0]), gamma, lam)
    np.testing.assert_allclose(adv, [2.5, 2.0, 2.0])


def test_lambda_returns_hand_computed():
    gamma, lam = 0.5, 0.5
    r = f32([1.0, 1.0])
    nv = f32([4.0, 8.0])
    # R_1 = 1 + 0.5*8 = 5; R_0 = 1 + 0.5*((1-0.5)*4 + 0.5*5) = 3.25
    np.testing.assert_allclose(lambda_returns(r, nv, f32([0, 0]), f32([0, 0]), gamma, lam), [3.25, 5.0])
    # terminal at t=1 → R_1 = 1; R_0 = 1 + 0.5*(0.5*4 + 0.5*1) = 2.25
    np.testing.assert_allclose(lambda_returns(r, nv, f32([0, 1]), f32([0, 0]), gamma, lam), [2.25, 1.0])
    # truncated at t=0 → R_0 = 1 + 0.5*4 = 3 (bootstrap, no look-ahead into the next episode)
    np.testing.assert_allclose(lambda_returns(r, nv, f32([0, 0]), f32([1, 0]), gamma, lam), [3.0, 5.0])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_against_python_loops_with_random_episode_ends(seed):
    rng = np.random.default_rng(seed)
    T, gamma, lam = 12, 0.9, 0.95
    r = rng.normal(size=T)
    v = rng.normal(size=T)
    nv = rng.normal(size=T)
    term = (rng.random(T) < 0.2).astype(float)
    trunc = ((rng.random(T) < 0.2) & (term == 0)).astype(float)
    args = [f32(x) for x in (r, v, nv, term, trunc)]
    np.testing.assert_allclose(gae(*args, gamma, lam), loop_gae(r, v, nv, term, trunc, gamma, lam), atol=1e-5)
    ret = lambda_returns(args[0], args[2], args[3], args[4], gamma, lam)
    np.testing.assert_allclose(ret, loop_lambda_returns(r, nv, term, trunc, gamma, lam), atol=1e-5)
    for n in (1, 3, T):
        got = n_step_returns(args[0], args[2], args[3], args[4], gamma, n)
        np.testing.assert_allclose(got, loop_nstep(r, nv, term, trunc, gamma, n), atol=1e-5)
    got = n_step_returns(args[0], args[2], args[3], args[4], gamma, None)
    np.testing.assert_allclose(got, loop_nstep(r, nv, term, trunc, gamma, T), atol=1e-5)


def test_lambda_returns_equal_gae_plus_values_and_limits():
    rng = np.random.default_rng(3)
    T, gamma = 9, 0.9
    v_all = rng.normal(size=T + 1)
    r, v, nv = f32(rng.normal(size=T)), f32(v_all[:-1]), f32(v_all[1:])  # consistent: nv[t] = v[t+1]
    term = f32([0, 0, 1, 0, 0, 0, 0, 0, 0])
    trunc = f32([0, 0, 0, 0, 0, 1, 0, 0, 0])
    for lam in (0.0, 0.7, 1.0):
        np.testing.assert_allclose(
            lambda_returns(r, nv, term, trunc, gamma, lam), gae(r, v, nv, term, trunc, gamma, lam) + v, atol=1e-5
        )
    # λ = 0 gives the TD error (Eq. 5.7)
    np.testing.assert_allclose(gae(r, v, nv, term, trunc, gamma, 0.0), td_errors(r, v, nv, term, gamma), atol=1e-6)


def test_over_lanes_maps_each_lane_s_stream_and_is_jittable():
    """``over_lanes`` gives, column by column, the estimator of that lane's stream (ends in some lanes only)."""
    rng = np.random.default_rng(4)
    T, B = 6, 3
    r, v, nv = (f32(rng.normal(size=(T, B))) for _ in range(3))
    term, trunc = jnp.zeros((T, B)).at[2, 0].set(1.0), jnp.zeros((T, B)).at[3, 2].set(1.0)
    out = jax.jit(over_lanes(gae, 5), static_argnums=(5, 6))(r, v, nv, term, trunc, 0.9, 0.95)
    targets = over_lanes(lambda_returns, 4)(r, nv, term, trunc, 0.9, 0.95)
    assert out.shape == targets.shape == (T, B)
    for b in range(B):
        np.testing.assert_array_equal(out[:, b], gae(r[:, b], v[:, b], nv[:, b], term[:, b], trunc[:, b], 0.9, 0.95))
        np.testing.assert_array_equal(targets[:, b], lambda_returns(r[:, b], nv[:, b], term[:, b], trunc[:, b], 0.9,
                                                                    0.95))  # fmt: skip


def test_bad_shapes_rejected():
    with pytest.raises(AssertionError):
        gae(jnp.zeros((3, 2)), jnp.zeros((3, 2)), jnp.zeros((3, 2)), jnp.zeros((3, 2)), jnp.zeros((3, 2)), 0.9, 0.9)
    with pytest.raises(AssertionError):
        gae(jnp.zeros(3), jnp.zeros(4), jnp.zeros(3), jnp.zeros(3), jnp.zeros(3), 0.9, 0.9)
    with pytest.raises(ValueError, match="n=0"):
        n_step_returns(jnp.zeros(3), jnp.zeros(3), jnp.zeros(3), jnp.zeros(3), 0.9, 0)
