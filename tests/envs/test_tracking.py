"""Shared tracking machinery: RSI window, early-termination counter, angle wrap, the test episode."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_mjx import tracking
from envs_mjx.unicycle import Unicycle


def _params(lo, hi, limit=20.0):
    return tracking.make_params({"start_lo": lo, "start_hi": hi, "et_limit": limit})


def test_rsi_index_window_bounds_and_spread():
    keys = jax.random.split(jax.random.PRNGKey(0), 4000)
    draw = jax.jit(jax.vmap(lambda k, p: tracking.rsi_index(k, p, 100), in_axes=(0, None)))
    k = np.asarray(draw(keys, _params(0.25, 0.5)))
    assert k.min() == 25 and k.max() == 49  # floor(U[25, 50))
    counts = np.bincount(k - 25, minlength=25)
    assert counts.min() > 100  # every step of the window is drawn (~160 each)
    np.testing.assert_array_equal(np.asarray(draw(keys[:50], _params(0.0, 0.0))), 0)
    whole = np.asarray(draw(keys, _params(0.0, 1.0)))
    assert whole.min() == 0 and whole.max() == 99  # at least one step is always left
    np.testing.assert_array_equal(np.asarray(draw(keys[:50], _params(1.0, 1.0))), 99)
    rev = np.asarray(draw(keys, _params(0.5, 0.25)))  # reversed bounds are swapped
    assert rev.min() == 25 and rev.max() == 49


def test_early_termination_counts_over_threshold_steps_not_consecutive():
    errors = [0.5, 0.1, 0.5, 0.5, 0.1, 0.5, 0.5]  # threshold 0.3, limit 2
    count, term = jnp.float32(0.0), jnp.float32(0.0)
    counts, terms = [], []
    for e in errors:
        count, term = tracking.early_termination(count, term, jnp.float32(e), 0.3, jnp.float32(2.0))
        counts.append(float(count))
        terms.append(float(term))
    # the third over-threshold step (limit + 1) terminates; termination is sticky
    assert counts == [1, 1, 2, 3, 3, 3, 3]
    assert terms == [0, 0, 0, 1, 1, 1, 1]
    _, term = tracking.early_termination(jnp.float32(5.0), jnp.float32(0.0), jnp.float32(9.0), 0.3, jnp.inf)
    assert float(term) == 0.0  # an infinite limit disables it


def test_wrap_angle_and_axis_errors_across_zero_two_pi():
    np.testing.assert_allclose(tracking.wrap_angle(jnp.float32(2 * math.pi - 0.1)), -0.1, atol=1e-6)
    np.testing.assert_allclose(tracking.wrap_angle(jnp.float32(-2 * math.pi + 0.1)), 0.1, atol=1e-6)
    ref = jnp.array([1.0, 2.0, 2 * math.pi - 0.05])
    real = jnp.array([0.5, 2.5, 0.05 + 4 * math.pi])  # robot heading unwrapped two turns further
    err = tracking.axis_errors(ref, real, (False, False, True))
    np.testing.assert_allclose(err, [0.5, -0.5, -0.1], atol=1e-5)


def test_make_params_rejects_unknown_keys():
    with pytest.raises(ValueError, match=r"unknown episode parameter.*'start'.*start_lo, start_hi, et_limit"):
        tracking.make_params({"start_lo": 0.0, "start_hi": 1.0, "et_limit": 1.0}, {"start": 0.5})


def _still(obs):
    """A policy that stands still (one object, so both test episodes share one compiled rollout)."""
    return jnp.zeros(2)


@pytest.fixture(scope="module")
def kin_sine():
    return Unicycle(mode="kinematic", trajectory="sine")


def test_test_episode_sums_hand_computed_errors(kin_sine):
    """A robot that stands still from t = 0: errors are the reference's own offsets from its start."""
    env = kin_sine
    out = tracking.test_episode(env, _still)
    n = env.max_steps
    t = np.arange(1, n + 1) * env.dt
    theta_r = np.arctan(0.4 * np.cos(0.2 * t))
    expect = np.stack([t, np.abs(2 * np.sin(0.2 * t)), np.abs(theta_r - math.atan(0.4))], axis=1)
    assert out["steps"] == n == 314
    assert out["axis_names"] == ("x", "y", "theta")
    np.testing.assert_allclose(out["abs_error"], expect, atol=2e-4)
    np.testing.assert_allclose(out["sum_abs_error"], expect.sum(0), rtol=1e-4)
    np.testing.assert_allclose(out["sum_abs_error"][0], 0.1 * n * (n + 1) / 2, rtol=1e-4)
    np.testing.assert_allclose(out["mean_abs_error"], expect.sum(0) / n, rtol=1e-4)
    assert out["ref_path"].shape == out["real_path"].shape == (n + 1, 3)
    np.testing.assert_allclose(out["real_path"], np.tile([0.0, 0.0, math.atan(0.4)], (n + 1, 1)), atol=1e-6)
    np.testing.assert_allclose(out["ref_path"][-1, :2], [n * 0.1, 2 * math.sin(0.2 * n * 0.1)], atol=1e-4)


def test_test_episode_stops_at_early_termination_when_asked(kin_sine):
    env = kin_sine
    # standing still: the position error first exceeds 0.3 m at t = 0.3 (x_r = t, y_r ≈ 0.4 t);
    # with limit 4 the fifth over-threshold step ends the episode.
    t = np.arange(1, env.max_steps + 1) * env.dt
    over = np.hypot(t, 2 * np.sin(0.2 * t)) > env.config.et_threshold
    expect_steps = int(np.nonzero(np.cumsum(over) > 4)[0][0]) + 1
    out = tracking.test_episode(env, _still, {"et_limit": 4.0})
    assert out["steps"] == expect_steps
    assert out["valid"].sum() == expect_steps and not out["valid"][expect_steps:].any()
    assert np.isnan(out["real_path"][expect_steps + 1 :]).all()
    assert np.isfinite(out["real_path"][: expect_steps + 1]).all()
    np.testing.assert_allclose(out["sum_abs_error"][0], t[:expect_steps].sum(), rtol=1e-5)
