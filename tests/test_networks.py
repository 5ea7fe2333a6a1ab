"""Actor/critic shapes, fixed vs learned σ, batch-norm train vs eval, Gaussian helpers."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxrl_robot.networks import (
    Critic,
    GaussianActor,
    apply_actor,
    gaussian_entropy,
    gaussian_kl,
    gaussian_log_prob,
    gaussian_sample,
)


def test_critic_and_actor_shapes_and_fixed_sigma():
    obs = jnp.ones((5, 4))
    critic = Critic(hidden=(8, 8))
    cv = critic.init(jax.random.PRNGKey(0), obs)
    assert critic.apply(cv, obs).shape == (5,)
    actor = GaussianActor(action_size=3, hidden=(8,), sigma=(0.8, 0.8, 0.1))
    av = actor.init(jax.random.PRNGKey(1), obs)
    assert "batch_stats" not in av and "log_std" not in av["params"]
    (mean, log_std), stats = apply_actor(actor, av["params"], {}, obs)
    assert mean.shape == (5, 3) and np.all(np.abs(mean) <= 1.0)
    np.testing.assert_allclose(np.exp(log_std), np.tile([0.8, 0.8, 0.1], (5, 1)), rtol=1e-6)
    assert stats == {}


def test_learned_log_std_is_a_parameter_with_gradient():
    actor = GaussianActor(action_size=2, hidden=(4,), sigma=0.5, learn_std=True)
    obs = jnp.ones((3, 2))
    params = actor.init(jax.random.PRNGKey(0), obs)["params"]
    np.testing.assert_allclose(params["log_std"], np.log([0.5, 0.5]), rtol=1e-6)

    def loss(p):
        mean, log_std = actor.apply({"params": p}, obs)
        return gaussian_log_prob(mean, log_std, jnp.zeros_like(mean)).sum()

    g = jax.grad(loss)(params)
    assert np.all(np.abs(g["log_std"]) > 0)


def test_batch_norm_uses_batch_stats_in_training_and_moving_averages_in_eval():
    actor = GaussianActor(action_size=1, hidden=(6,), batch_norm=True, bn_momentum=0.5)
    key = jax.random.PRNGKey(0)
    obs = 3.0 + 2.0 * jax.random.normal(key, (64, 2))
    variables = actor.init(jax.random.PRNGKey(1), obs)
    params, stats = variables["params"], variables["batch_stats"]
    # Fresh moving averages are mean 0 / var 1, so eval mode differs from train mode on this batch.
    (m_train, _), new_stats = apply_actor(actor, params, stats, obs, train=True)
    (m_eval, _), same = apply_actor(actor, params, stats, obs, train=False)
    assert same is stats
    assert not np.allclose(m_train, m_eval, atol=1e-3)
    # Training mode updated the input moving mean: 0.5 * 0 + 0.5 * batch mean.
    np.testing.assert_allclose(new_stats["BatchNorm_0"]["mean"], 0.5 * obs.mean(0), rtol=1e-4)
    # Train mode normalises by the batch: a shifted and scaled batch gives the same outputs.
    (m_shift, _), _ = apply_actor(actor, params, stats, 10.0 + 5.0 * obs, train=True)
    np.testing.assert_allclose(m_shift, m_train, atol=1e-4)
    # Eval mode is per-sample: one state gives the same action alone or inside a batch.
    (m_one, _), _ = apply_actor(actor, params, new_stats, obs[:1], train=False)
    (m_all, _), _ = apply_actor(actor, params, new_stats, obs, train=False)
    np.testing.assert_allclose(m_one, m_all[:1], atol=1e-6)
    # After enough training steps on the same distribution the moving averages match it,
    # and eval mode agrees with train mode.
    for _ in range(30):
        _, new_stats = apply_actor(actor, params, new_stats, obs, train=True)
    (m_eval2, _), _ = apply_actor(actor, params, new_stats, obs, train=False)
    np.testing.assert_allclose(m_eval2, m_train, atol=2e-3)


def test_gaussian_helpers_hand_computed():
    mean = jnp.array([0.0, 1.0])
    log_std = jnp.log(jnp.array([1.0, 2.0]))
    a = jnp.array([1.0, 1.0])
    expected = -0.5 * 1.0 - 0.5 * math.log(2 * math.pi) + (-math.log(2.0) - 0.5 * math.log(2 * math.pi))
    np.testing.assert_allclose(gaussian_log_prob(mean, log_std, a), expected, rtol=1e-6)
    np.testing.assert_allclose(
        gaussian_entropy(log_std), 2 * 0.5 * (1 + math.log(2 * math.pi)) + math.log(2.0), rtol=1e-6
    )
    # KL(N(0,1) ‖ N(1,2²)) = log 2 + (1 + 1)/(2*4) - 1/2 ; same distribution → 0.
    kl = gaussian_kl(jnp.array([0.0]), jnp.array([0.0]), jnp.array([1.0]), jnp.log(jnp.array([2.0])))
    np.testing.assert_allclose(kl, math.log(2.0) + 2.0 / 8.0 - 0.5, rtol=1e-6)
    np.testing.assert_allclose(gaussian_kl(mean, log_std, mean, log_std), 0.0, atol=1e-7)


def test_gaussian_sample_statistics():
    mean = jnp.array([0.5, -0.2])
    log_std = jnp.log(jnp.array([0.8, 0.1]))
    keys = jax.random.split(jax.random.PRNGKey(0), 20000)
    a = jax.vmap(lambda k: gaussian_sample(k, mean, log_std))(keys)
    np.testing.assert_allclose(a.mean(0), mean, atol=0.02)
    np.testing.assert_allclose(a.std(0), [0.8, 0.1], rtol=0.03)
