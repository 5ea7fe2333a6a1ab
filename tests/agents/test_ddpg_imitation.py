"""Imitation pre-training of DDPG/TD3 (thesis §6.1.2): the teacher's share and mixing by hand, config
errors, an imitation-only run that reproduces a known expert, and a stage in which the actor moves
only by its imitation steps (the critic learns, the DDPG actor step is off)."""

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State

from envs_mjx.base import RobotEnv, sanitize_action
from envs_mjx.config import ConfigError
from jaxrl_robot.agents.ddpg import DDPGConfig, make_train, make_trainer
from jaxrl_robot.agents.off_policy.losses import anchored_actor_loss
from jaxrl_robot.imitation import expert_of, imitation_loss, mix_teacher, teacher_share


@dataclass(frozen=True)
class DriftConfig:
    action_scale: float = 0.2

    def validate(self):
        return None


class Drift(RobotEnv):
    """1-D point ``x`` moved by ``0.2 a``; reward ``−|x|``; its expert steers with ``a* = clip(−2x, −1, 1)``."""

    name = "drift"
    Config = DriftConfig
    observation_size = 2
    action_size = 1
    episode_length = 20

    def default_params(self):
        return {}

    def reset(self, rng, params=None):
        x = jax.random.uniform(rng, (1,), minval=-1.0, maxval=1.0)
        z = jnp.zeros(())
        return State(x, jnp.concatenate([x, x**2]), z, z, {"success": z}, {"params": {}})

    def step(self, state, action):
        a, _ = sanitize_action(action)
        x = jnp.clip(state.pipeline_state + self.action_scale * a, -1.5, 1.5)
        return state.replace(pipeline_state=x, obs=jnp.concatenate([x, x**2]), reward=-jnp.abs(x[0]),
                             metrics={"success": jnp.zeros(())})  # fmt: skip

    def expert(self, state):
        return jnp.clip(-2.0 * state.pipeline_state, -1.0, 1.0)


class NoExpert(Drift):
    expert = None


BASE = DDPGConfig(schedule="steps", total_steps=3200, num_envs=8, unroll_length=2, updates_per_iteration=1,
                  batch_size=32, buffer_size=4000, learning_starts=64, actor_hidden=(32, 32), critic_hidden=(32, 32),
                  gamma=0.9, tau=0.05, noise="gaussian", noise_scale=(0.3,), pretrain="imitation", pretrain_steps=1600,
                  imitation_batch=64, imitation_updates=2, imitation_lr=3e-3)  # fmt: skip


def test_teacher_share_and_mixing_by_hand():
    shares = [float(teacher_share(jnp.asarray(i), 4, 0.8)) for i in range(6)]
    np.testing.assert_allclose(shares, [0.8, 0.6, 0.4, 0.2, 0.0, 0.0], atol=1e-6)
    action, teacher = jnp.zeros((5, 2)), jnp.ones((5, 2))
    key, lanes = jax.random.PRNGKey(0), jnp.arange(5)
    np.testing.assert_array_equal(mix_teacher(key, lanes, action, teacher, jnp.float32(0.0)), action)
    np.testing.assert_array_equal(mix_teacher(key, lanes, action, teacher, jnp.float32(1.0)), teacher)
    half = mix_teacher(key, jnp.arange(2000), jnp.zeros((2000, 1)), jnp.ones((2000, 1)), jnp.float32(0.5))
    assert 0.45 < float(half.mean()) < 0.55
    loss = imitation_loss(jnp.array([[0.0, 1.0], [2.0, 0.0]]), jnp.array([[1.0, 1.0], [0.0, 0.0]]),
                          jnp.array([1.0, 1.0]), jnp.asarray(2.0))  # fmt: skip
    assert float(loss) == pytest.approx((1.0 + 4.0) / 2)
    assert expert_of(Drift()) is not None and expert_of(NoExpert()) is None


@pytest.mark.parametrize(
    "changes, field",
    [
        (dict(schedule="episodes"), "schedule"),
        (dict(pretrain="dagger"), "pretrain"),
        (dict(pretrain_steps=10_000), "pretrain_steps"),
        (dict(imitation_batch=0), "imitation_batch"),
        (dict(expert_share=1.5), "expert_share"),
        (dict(distributed=True), "distributed"),
        (dict(imitation_anchor="bc"), "imitation_anchor"),
    ],
)
def test_config_errors_name_the_field(changes, field):
    with pytest.raises(ConfigError, match=field):
        BASE.replace(**changes).validate()


def test_env_without_expert_is_a_config_error():
    with pytest.raises(ConfigError, match="pretrain='imitation' needs an env with an expert"):
        make_trainer(BASE, NoExpert())


def _grid_error(cfg, state, env):
    trainer = make_trainer(cfg, env)
    x = jnp.linspace(-1.0, 1.0, 41)[:, None]
    obs = jnp.concatenate([x, x**2], axis=1)
    expert = jnp.clip(-2.0 * x, -1.0, 1.0)
    return float(jnp.mean((trainer.policy(state)(obs) - expert) ** 2))


@pytest.fixture(scope="module")
def runs():
    """Two runs of the imitation stage alone (``pretrain_steps = total_steps``): a normal imitation step
    size, and one so small that the actor must stay where it started."""
    env = Drift()
    out = {}
    for name, lr in (("imitate", 3e-3), ("frozen", 1e-9)):
        cfg = BASE.replace(pretrain_steps=BASE.total_steps, imitation_lr=lr)
        trainer = make_trainer(cfg, env)
        init = jax.jit(trainer.init)(jax.random.PRNGKey(0))
        state, metrics = jax.jit(make_train(cfg, env))(jax.random.PRNGKey(0))
        out[name] = (cfg, init, state, metrics)
    return env, out


def test_imitation_only_run_reproduces_the_expert(runs):
    env, out = runs
    cfg, init, state, metrics = out["imitate"]
    assert _grid_error(cfg, state, env) < 0.01 < _grid_error(cfg, init, env)
    loss = np.asarray(metrics["imitation_loss"])
    assert np.isfinite(loss).all() and loss[-1] < 0.1 * loss[0]
    assert int(state.demos.size) == min(cfg.imitation_buffer, cfg.total_steps)


def test_stage_moves_the_actor_only_by_imitation(runs):
    _, out = runs
    cfg, init, state, _ = out["frozen"]

    def moved(a, b):
        return max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))

    assert int(state.updates) > 100  # the critic learned all along
    assert moved(state.actor_params, init.actor_params) < 1e-5  # no DDPG actor step (1e-3 each otherwise)
    assert moved(state.critic_params, init.critic_params) > 1e-2
    assert moved(state.target_critic_params, init.target_critic_params) > 1e-3  # targets follow the critic


def test_after_the_stage_ddpg_takes_over_and_the_anchor_keeps_imitating():
    env = Drift()
    half = BASE.replace(pretrain_steps=BASE.total_steps // 2, total_steps=BASE.total_steps)
    for weight in (0.0, 0.5):
        cfg = half.replace(imitation_weight=weight)
        trainer = make_trainer(cfg, env, iterations_per_update=cfg.iterations // 4)
        state = jax.jit(trainer.init)(jax.random.PRNGKey(1))
        update = jax.jit(trainer.update)
        losses = []
        for _ in range(trainer.num_updates):
            state, metrics = update(state)
            losses.append(float(metrics["imitation_loss"]))
        assert np.isfinite(losses[:2]).all()
        assert np.isnan(losses[2:]).all() if weight == 0 else np.isfinite(losses).all()


def test_anchored_actor_loss_by_hand():
    """``−mean Q / mean |Q| + w · bc`` with the scale held constant: Q = (1, 3, 2) gives −1 + w · bc, and
    ∂/∂Q_i = −1 / (N · mean |Q|) = −1/6 (a scale that took gradients would make the Q term constant)."""
    q, bc = jnp.array([1.0, 3.0, 2.0]), jnp.asarray(0.25)
    assert float(anchored_actor_loss(q, bc, 2.0)) == pytest.approx(-1.0 + 0.5)
    dq, dbc = jax.grad(anchored_actor_loss, argnums=(0, 1))(q, bc, 2.0)
    np.testing.assert_allclose(dq, [-1.0 / 6.0] * 3, rtol=1e-6)
    assert float(dbc) == pytest.approx(2.0)
    assert float(anchored_actor_loss(jnp.zeros(3), bc, 1.0)) == pytest.approx(0.25)  # no division by zero


def test_anchor_in_the_actor_loss_replaces_the_imitation_steps_after_the_stage():
    """``imitation_anchor='loss'``: after the stage the imitation optimiser takes no step (its Adam count
    stays at the stage's), the memory keeps the expert's labels of every visited state, and the DDPG actor
    step carries the anchor: a large weight keeps the actor at the expert, a tiny one lets DDPG move it
    (the expert's ``−2x`` is not the fastest way to ``x = 0``)."""
    env = Drift()
    cfg = BASE.replace(pretrain_steps=BASE.total_steps // 2, imitation_anchor="loss")
    errors = {}
    for weight in (1e-6, 10.0):
        c = cfg.replace(imitation_weight=weight)
        trainer = make_trainer(c, env, iterations_per_update=c.iterations // 4)
        state = jax.jit(trainer.init)(jax.random.PRNGKey(1))
        update = jax.jit(trainer.update)
        losses, counts = [], []
        for _ in range(trainer.num_updates):
            state, metrics = update(state)
            losses.append(float(metrics["imitation_loss"]))
            counts.append(int(state.imitation_opt[0].count))
        stage = c.pretrain_iterations * c.imitation_updates
        assert np.isfinite(losses[:2]).all() and np.isnan(losses[2:]).all()
        assert counts == [stage // 2, stage, stage, stage]
        assert int(state.demos.size) == c.total_steps  # labels of every step, in and after the stage
        errors[weight] = _grid_error(c, state, env)
    assert errors[10.0] < 0.005 and errors[10.0] < 0.5 * errors[1e-6], errors
