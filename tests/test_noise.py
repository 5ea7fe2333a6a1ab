"""OU noise: mean reversion and stationary variance (Eq. 3.8); Gaussian noise; Table 6.1 reading."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrl_robot.noise import TABLE_6_1_DRIVING, make_gaussian_noise, make_noise, make_ou_noise, ou_stationary_std


def _run(noise, state, key, steps, lanes):
    def one_lane(k):
        def body(s, kk):
            x, s = noise.sample(kk, s)
            return s, x

        return jax.lax.scan(body, state, jax.random.split(k, steps))[1]

    return jax.jit(jax.vmap(one_lane))(jax.random.split(key, lanes))  # [lanes, steps, A]


def test_ou_reverts_to_the_mean_geometrically():
    eta, theta = jnp.array([0.0, 0.5, -0.1]), jnp.array([0.2, 0.5, 0.1])
    noise = make_ou_noise(3, mean=eta, reversion=theta, scale=0.0)
    x = _run(noise, noise.init()._replace(x=jnp.array([2.0, -1.0, 3.0])), jax.random.PRNGKey(0), 10, 1)[0]
    t = np.arange(1, 11)[:, None]
    np.testing.assert_allclose(x, eta + (1 - theta) ** t * (jnp.array([2.0, -1.0, 3.0]) - eta), rtol=1e-5, atol=1e-6)
    # with noise: the lane average follows the same mean path
    noise = make_ou_noise(3, mean=eta, reversion=theta, scale=0.3)
    x = _run(noise, noise.init()._replace(x=jnp.array([2.0, -1.0, 3.0])), jax.random.PRNGKey(1), 10, 4000)
    np.testing.assert_allclose(x.mean(0)[-1], eta + (1 - theta) ** 10 * (jnp.array([2.0, -1.0, 3.0]) - eta),
                               atol=0.03)


def test_ou_stationary_variance():
    noise = make_ou_noise(2, mean=[0.5, -0.1], reversion=[0.8, 0.3], scale=[0.2, 0.1])
    x = _run(noise, noise.init(), jax.random.PRNGKey(2), 200, 500)[:, 50:]  # drop the transient
    std = ou_stationary_std(jnp.array([0.8, 0.3]), jnp.array([0.2, 0.1]))
    np.testing.assert_allclose(std, [0.2 / np.sqrt(0.96), 0.1 / np.sqrt(0.51)], rtol=1e-6)
    np.testing.assert_allclose(x.reshape(-1, 2).std(0), std, rtol=0.03)
    np.testing.assert_allclose(x.reshape(-1, 2).mean(0), [0.5, -0.1], atol=0.01)
    # temporally correlated: lag-1 autocorrelation 1 − σ1
    d = x - x.mean((0, 1))
    rho = (d[:, 1:] * d[:, :-1]).mean((0, 1)) / d.var((0, 1))
    np.testing.assert_allclose(rho, [0.2, 0.7], atol=0.03)


def test_gaussian_noise_is_independent_with_given_scale():
    noise = make_gaussian_noise(2, scale=[0.1, 0.5])
    x = _run(noise, noise.init(), jax.random.PRNGKey(3), 100, 200).reshape(-1, 2)
    np.testing.assert_allclose(x.std(0), [0.1, 0.5], rtol=0.03)
    d = x.reshape(200, 100, 2)
    assert abs(float((d[:, 1:] * d[:, :-1]).mean() / d.var())) < 0.03


def test_table_6_1_reading_and_errors():
    noise = make_ou_noise(3, **TABLE_6_1_DRIVING)
    np.testing.assert_allclose(noise.init().x, [0.0, 0.5, -0.1])  # steering mean 0, not 0.8
    with pytest.raises(ValueError, match="reversion=2.5 is out of range"):
        make_ou_noise(2, reversion=2.5)
    with pytest.raises(ValueError, match="mean=.*must be a scalar, one value or 3 values"):
        make_ou_noise(3, mean=[0.0, 1.0])
    with pytest.raises(ValueError, match="noise='pink' is not valid; choose one of 'ou', 'gaussian'"):
        make_noise("pink", 2)
