"""The library's configs fit any env as they are: with only sizes and budgets set, PPO, A2C and DDPG build and
trace their first training chunk on envs of 1 and 6 action dimensions (PPO also runs it, on the 1-D env), the
per-action defaults (σ, the exploration noise) broadcast to the action size, and a per-action field of the
wrong length is a one-line ``ConfigError`` naming it."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env, State

from envs_mjx.config import ConfigError
from jaxrl_robot.agents import a2c, ddpg, ppo
from jaxrl_robot.agents.ddpg import make_noise_for
from jaxrl_robot.agents.on_policy import action_sigma, make_actor_critic

SIZES = (1, 6)
EPISODE = 10


class Reach(Env):
    """A point in ``[-1, 1]^n`` moved by ``0.2 · clip(action, -1, 1)`` toward a random goal.

    Observation ``[position (n), goal (n)]``; action ``[n]``; reward: the decrease of the distance to
    the goal; the episode ends within 0.1 of it (``metrics["success"] = 1``).
    """

    def __init__(self, n: int):
        self.n = n

    @property
    def observation_size(self) -> int:
        return 2 * self.n

    @property
    def action_size(self) -> int:
        return self.n

    @property
    def backend(self) -> str:
        return "jax"

    def reset(self, rng: jax.Array) -> State:
        obs = jax.random.uniform(rng, (2 * self.n,), minval=-1.0, maxval=1.0)
        zero = jnp.zeros(())
        return State(pipeline_state=obs, obs=obs, reward=zero, done=zero, metrics={"success": zero}, info={})

    def step(self, state: State, action: jax.Array) -> State:
        pos, goal = state.obs[: self.n], state.obs[self.n :]
        new = jnp.clip(pos + 0.2 * jnp.clip(action, -1.0, 1.0), -1.0, 1.0)
        after = jnp.linalg.norm(goal - new)
        success = (after < 0.1).astype(jnp.float32)
        obs = jnp.concatenate([new, goal])
        return state.replace(pipeline_state=obs, obs=obs, reward=jnp.linalg.norm(goal - pos) - after, done=success,
                             metrics={"success": success})  # fmt: skip


# PPO trains one chunk on the 1-D env (the library's own usage line); every other case traces its first chunk
# (``jax.eval_shape`` of init and update: each shape of the program checked, the program not compiled), which keeps
# the file to one training compile (each costs 5-10 s of XLA:CPU compilation).


def _first_chunk_shapes(trainer):
    """The shapes of ``(state, metrics)`` after ``trainer``'s first chunk from ``PRNGKey(0)``."""
    return jax.eval_shape(lambda key: trainer.update(trainer.init(key)), jax.random.PRNGKey(0))


def _check_actor(config, n: int, params, stats) -> None:
    """The actor of ``config`` with ``params`` / ``stats`` gives log-σ ``[2, n]``; where they are arrays (not the
    shapes of ``jax.eval_shape``), all log 0.5: σ = 0.5 broadcast to the ``n`` dimensions."""
    actor, _ = make_actor_critic(config, n)
    obs = jax.random.normal(jax.random.PRNGKey(3), (2, 2 * n))

    def log_std(variables):
        return actor.apply(variables, obs)[1]

    variables = {"params": params, **({"batch_stats": stats} if stats else {})}
    assert jax.eval_shape(log_std, variables).shape == (2, n)
    assert action_sigma(config, n) == (0.5,) * n
    if not any(isinstance(x, jax.ShapeDtypeStruct) for x in jax.tree.leaves(variables)):
        np.testing.assert_allclose(jax.jit(log_std)(variables), np.full((2, n), math.log(0.5)), rtol=1e-6)


def test_per_action_defaults_hold_one_value():
    for cls in (ppo.PPOConfig, a2c.A2CConfig, a2c.A3CConfig):
        assert cls().sigma == (0.5,), cls
    d = ddpg.DDPGConfig()
    assert (d.noise_scale, d.noise_mean, d.noise_reversion) == ((0.2,), (0.0,), (0.15,))


def test_ppo_default_config_trains_a_chunk_on_a_1d_env():
    # the library's own usage line: sizes and budgets only (one iteration of 4 lanes x 8 steps)
    config = ppo.PPOConfig(num_envs=4, minibatch_size=32, total_steps=32, episode_length=EPISODE)
    state, metrics = jax.jit(ppo.make_train(config, Reach(1)))(jax.random.PRNGKey(0))
    assert int(state.iteration) == 1 and metrics["actor_loss"].shape == (1,)  # one chunk of one iteration
    for name in ("actor_loss", "critic_loss"):
        assert np.isfinite(np.asarray(metrics[name])).all(), name
    np.testing.assert_allclose(metrics["policy_std"], [0.5], rtol=1e-6)  # the lanes acted with σ = 0.5
    _check_actor(config, 1, state.actor_params, state.actor_stats)  # the trained actor's σ (fixed)


def test_ppo_default_config_traces_a_chunk_on_a_6d_env():
    config = ppo.PPOConfig(num_envs=4, minibatch_size=32, total_steps=32, episode_length=EPISODE)
    state, metrics = jax.eval_shape(ppo.make_train(config, Reach(6)), jax.random.PRNGKey(0))
    assert metrics["actor_loss"].shape == (1,)
    _check_actor(config, 6, state.actor_params, state.actor_stats)


@pytest.mark.parametrize("n", SIZES)
def test_a2c_default_config_traces_a_chunk(n):
    config = a2c.A2CConfig(num_envs=4, total_steps=32, episode_length=EPISODE)
    trainer = a2c.make_trainer(config, Reach(n))
    assert trainer.num_updates == 1
    state, metrics = _first_chunk_shapes(trainer)
    assert {"actor_loss", "critic_loss", "steps_taken"} <= set(metrics)
    _check_actor(config, n, state.params.actor, state.params.actor_stats)


@pytest.mark.parametrize("n", SIZES)
def test_ddpg_default_config_traces_a_chunk(n):
    # the 'episodes' schedule of the defaults: one cycle of 4 episodes, then 2 updates on mini-batches of 8
    config = ddpg.DDPGConfig(epochs=1, cycles_per_epoch=1, num_envs=4, updates_per_cycle=2, batch_size=8,
                             buffer_size=256, episode_length=EPISODE)  # fmt: skip
    trainer = ddpg.make_trainer(config, Reach(n))
    assert trainer.num_updates == 1
    state, metrics = _first_chunk_shapes(trainer)
    assert {"actor_loss", "critic_loss"} <= set(metrics)
    assert state.noise_state.x.shape == (4, n)  # one noise process per lane and action dimension
    # the default noise N(0, 0.2²) in every one of the n dimensions
    noise = make_noise_for(config, n)
    samples = jax.vmap(lambda k: noise.sample(k, noise.init())[0])(jax.random.split(jax.random.PRNGKey(1), 4000))
    assert samples.shape == (4000, n)
    np.testing.assert_allclose(np.std(np.asarray(samples), axis=0), 0.2, rtol=0.06)
    np.testing.assert_allclose(np.mean(np.asarray(samples), axis=0), 0.0, atol=0.02)


def test_per_action_fields_take_one_or_action_size_values_else_a_one_line_error():
    sigma = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)
    assert action_sigma(ppo.PPOConfig(sigma=sigma), 6) == sigma
    assert action_sigma(ppo.PPOConfig(sigma=(0.3,)), 6) == (0.3,) * 6
    for make, config in ((ppo.make_trainer, ppo.PPOConfig(sigma=(0.1, 0.2), episode_length=EPISODE)),
                         (a2c.make_trainer, a2c.A2CConfig(sigma=(0.1, 0.2), episode_length=EPISODE))):  # fmt: skip
        with pytest.raises(ConfigError) as e:
            make(config, Reach(6))
        assert str(e.value) == "sigma=(0.1, 0.2) must have 1 or action_size=6 values"
    for changes, field in ((dict(noise_scale=(0.1, 0.2)), "noise_scale=(0.1, 0.2)"),
                           (dict(noise_mean=(0.0, 0.1)), "noise_mean=(0.0, 0.1)"),
                           (dict(noise="ou", noise_reversion=(0.1, 0.2)), "noise_reversion=(0.1, 0.2)")):  # fmt: skip
        with pytest.raises(ConfigError) as e:
            ddpg.make_trainer(ddpg.DDPGConfig(episode_length=EPISODE, **changes), Reach(6))
        assert str(e.value) == f"{field} must have 1 or action_size=6 values"
    # one value per action: each dimension's noise has its own σ
    noise = make_noise_for(ddpg.DDPGConfig(noise_scale=sigma), 6)
    samples = jax.vmap(lambda k: noise.sample(k, noise.init())[0])(jax.random.split(jax.random.PRNGKey(2), 4000))
    np.testing.assert_allclose(np.std(np.asarray(samples), axis=0), sigma, rtol=0.06)
    # Gaussian noise has no reversion rate: its length is not checked there
    ddpg.DDPGConfig(noise_reversion=(0.1, 0.2)).check_action_size(6)
