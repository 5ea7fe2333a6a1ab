"""SAC: the tanh-Gaussian log-probability against NumPy, the temperature, actor and soft-value losses by
hand, config errors, and learning the sparse toy reacher with HER and PER (the off-policy family's)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_mjx.config import ConfigError
from jaxrl_robot.agents.sac import (
    SACConfig,
    actor_loss,
    alpha_loss,
    gaussian_scale,
    make_trainer,
    soft_value,
    tanh_gaussian_log_prob,
    tanh_gaussian_sample,
)
from jaxrl_robot.evaluation import run_test_episodes, summarize_episodes
from tests.replay.toy_goal_env import ToyGoalEnv


def _np_tanh_gaussian_log_prob(a, loc, scale):
    """log-density of ``a = tanh(u)``, ``u ~ N(loc, scale²)``, per dimension ``p(u) / |da/du|`` (float64)."""
    u = np.arctanh(a)
    log_normal = -0.5 * ((u - loc) / scale) ** 2 - np.log(scale) - 0.5 * np.log(2 * np.pi)
    return np.sum(log_normal - np.log(1.0 - a**2), axis=-1)


def test_tanh_gaussian_log_prob_matches_numpy_change_of_variables():
    rng = np.random.default_rng(0)
    loc = rng.normal(size=(5, 3))
    scale = rng.uniform(0.2, 1.5, size=(5, 3))
    u = rng.normal(size=(5, 3)) * 1.5
    got = tanh_gaussian_log_prob(jnp.asarray(u, jnp.float32), jnp.asarray(loc, jnp.float32),
                                 jnp.asarray(scale, jnp.float32))  # fmt: skip
    np.testing.assert_allclose(got, _np_tanh_gaussian_log_prob(np.tanh(u), loc, scale), rtol=1e-5, atol=1e-5)
    # far in the tail (tanh(u) rounds to ±1 in float32) the stable form stays finite: log(1 - tanh²u) ≈ 2 log 2 - 2|u|
    far = tanh_gaussian_log_prob(jnp.array([[12.0]]), jnp.array([[12.0]]), jnp.array([[1.0]]))
    np.testing.assert_allclose(far, [-0.5 * np.log(2 * np.pi) - 2 * np.log(2) + 24.0], rtol=1e-6)


def test_draws_are_tanh_of_a_reparametrised_gaussian_with_their_log_prob():
    key = jax.random.PRNGKey(3)
    loc, raw = jnp.array([[0.3, -1.0]]), jnp.array([[0.0, 2.0]])
    scale = gaussian_scale(raw, 0.001)
    np.testing.assert_allclose(scale, np.log1p(np.exp([[0.0, 2.0]])) + 0.001, rtol=1e-6)
    a, log_prob = tanh_gaussian_sample(key, loc, scale)
    u = loc + scale * jax.random.normal(key, loc.shape)
    np.testing.assert_allclose(a, np.tanh(u), rtol=1e-6)
    np.testing.assert_allclose(log_prob, _np_tanh_gaussian_log_prob(np.tanh(np.asarray(u, np.float64)),
                                                                    np.asarray(loc), np.asarray(scale)), rtol=1e-4)
    # the draw is differentiable in loc: da/dloc = 1 - tanh²(u)
    grad = jax.grad(lambda m: jnp.sum(tanh_gaussian_sample(key, m, scale)[0]))(loc)
    np.testing.assert_allclose(grad, 1.0 - np.tanh(u) ** 2, rtol=1e-5)


def test_temperature_actor_and_soft_value_losses_by_hand():
    log_prob = jnp.array([-1.0, 0.5, -2.5])
    log_alpha, target = jnp.log(0.2), -2.0
    # Eq. 18: mean α (−log π − H̄) with H̄ = −2: −log π − H̄ = (3, 1.5, 4.5)
    np.testing.assert_allclose(alpha_loss(log_alpha, log_prob, target), 0.2 * np.mean([3.0, 1.5, 4.5]), rtol=1e-6)
    # its gradient in log α is α · mean(−log π − H̄) > 0 here: entropy (1) above the target lowers α
    np.testing.assert_allclose(jax.grad(alpha_loss)(log_alpha, log_prob, target), 0.2 * 3.0, rtol=1e-6)
    # no gradient flows into the policy through the temperature loss
    np.testing.assert_allclose(jax.grad(alpha_loss, argnums=1)(log_alpha, log_prob, target), 0.0)
    q = jnp.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(actor_loss(q, log_prob, 0.2), np.mean(0.2 * np.array([-1.0, 0.5, -2.5]) - [1, -2, 0.5]),
                               rtol=1e-5)  # fmt: skip
    next_q = jnp.array([[1.0, 2.0, -1.0], [0.5, 3.0, -2.0]])
    np.testing.assert_allclose(soft_value(next_q, log_prob, 0.2), [0.5 + 0.2, 2.0 - 0.1, -2.0 + 0.5], rtol=1e-6)


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match="init_alpha=0"):
        SACConfig(init_alpha=0.0).validate()
    with pytest.raises(ConfigError, match="min_std=-1"):
        SACConfig(min_std=-1.0).validate()
    with pytest.raises(ConfigError, match="her='best' is not valid"):  # the family's fields, checked too
        SACConfig(her="best").validate()
    assert SACConfig().entropy_target(6) == -6.0 and SACConfig(target_entropy=-1.5).entropy_target(6) == -1.5


@pytest.fixture(scope="module")
def her_run():
    """SAC with HER future k=4 and PER on the sparse toy reacher (the DDPG learning test's budget):
    the trained state, its last chunk's metrics and the trainer."""
    env = ToyGoalEnv(reward="sparse", max_steps=20)
    config = SACConfig(epochs=3, cycles_per_epoch=10, num_envs=8, updates_per_cycle=20, buffer_size=20_000,
                       her="future", her_k=4, per=True, target_clip=(-10.0, 0.0), actor_hidden=(64, 64),
                       critic_hidden=(64, 64), init_alpha=0.05, alpha_lr=3e-3)  # fmt: skip
    trainer = make_trainer(config, env)
    update = jax.jit(trainer.update)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    for _ in range(trainer.num_updates):
        state, metrics = update(state)
    return env, trainer, state, metrics


def test_sparse_her_learns_to_reach_goals(her_run):
    """≥ 90 % of 100 test episodes with the policy's mode, after 600 updates; the temperature has fallen
    from 0.05 (the policy's entropy was above the target −3)."""
    env, trainer, state, metrics = her_run
    assert float(metrics["updates"]) == 3 * 10 * 20 and float(metrics["beta"]) == pytest.approx(1.0, abs=1e-4)
    assert 0.0 < float(metrics["alpha"]) < 0.05 and float(jnp.exp(state.extras.log_alpha)) < 0.05
    assert state.target_actor_params == ()  # SAC keeps target critics only
    result = summarize_episodes(run_test_episodes(jax.random.PRNGKey(1), env, trainer.policy(state), 100))
    assert result["success_rate"] >= 0.9, result
