"""DDPG: losses and gradients by hand on a tiny network, soft update, termination vs truncation, learning."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_mjx.config import ConfigError
from jaxrl_robot.agents.ddpg import (
    DDPGActor,
    DDPGConfig,
    DDPGCritic,
    actor_loss,
    clipped_double_q,
    critic_loss,
    linear_noise_factor,
    make_optimizer,
    make_trainer,
    smooth_target_action,
    soft_update,
    td_target,
    twin_critic_loss,
)
from jaxrl_robot.agents.off_policy.config import with_env_target_clip
from jaxrl_robot.checkpoint import Checkpointer
from jaxrl_robot.evaluation import run_test_episodes, summarize_episodes
from tests.replay.toy_goal_env import ToyGoalEnv


def _linear_params(w, b):
    dense = {"kernel": jnp.asarray(w, jnp.float32)[:, None], "bias": jnp.asarray([b], jnp.float32)}
    return {"params": {"Dense_0": dense}}


def test_td_target_bootstraps_on_truncation_not_on_termination():
    y = td_target(jnp.array([1.0, -1.0, 0.5]), jnp.array([0.0, 1.0, 0.0]), jnp.array([2.0, 5.0, -4.0]), 0.9)
    np.testing.assert_allclose(y, [1.0 + 0.9 * 2.0, -1.0, 0.5 - 0.9 * 4.0])


def test_critic_loss_and_gradient_by_hand_with_importance_weights():
    critic = DDPGCritic(hidden=())  # Q(s, a) = w·[s, a] + b
    params = _linear_params([0.5, -1.0, 2.0], 0.1)
    obs = jnp.array([[1.0, 2.0], [0.0, -1.0]])
    act = jnp.array([[0.5], [-1.0]])
    q = critic.apply(params, obs, act)
    np.testing.assert_allclose(q, [0.5 - 2.0 + 1.0 + 0.1, 1.0 - 2.0 + 0.1], rtol=1e-6)  # [-0.4, -0.9]
    y = jnp.array([1.0, -2.0])
    weights = jnp.array([1.0, 0.25])
    loss, td = critic_loss(q, y, weights)
    np.testing.assert_allclose(td, [1.4, -1.1], rtol=1e-6)
    np.testing.assert_allclose(loss, (1.0 * 1.4**2 + 0.25 * 1.1**2) / 2, rtol=1e-6)
    grads = jax.grad(lambda p: critic_loss(critic.apply(p, obs, act), y, weights)[0])(params)["params"]["Dense_0"]
    x = np.array([[1.0, 2.0, 0.5], [0.0, -1.0, -1.0]])
    # dL/dw = mean_i 2 w_i (Q_i - y_i) x_i
    coef = 2 * np.array([1.0, 0.25]) * np.array([-1.4, 1.1]) / 2
    np.testing.assert_allclose(grads["kernel"][:, 0], coef @ x, rtol=1e-5)
    np.testing.assert_allclose(grads["bias"], [coef.sum()], rtol=1e-5)
    # without PER the weights are 1
    np.testing.assert_allclose(critic_loss(q, y)[0], (1.4**2 + 1.1**2) / 2, rtol=1e-6)


def test_actor_gradient_is_dq_da_times_dmu_dtheta():
    actor = DDPGActor(action_size=1, hidden=(), output="tanh")  # μ(s) = tanh(v·s + c)
    critic = DDPGCritic(hidden=())
    a_params = _linear_params([0.3, -0.2], 0.05)
    c_params = _linear_params([0.5, -1.0, 2.0], 0.1)
    obs = jnp.array([[1.0, 2.0], [0.0, -1.0], [3.0, 1.0]])

    def loss(p):
        return actor_loss(critic.apply(c_params, obs, actor.apply(p, obs)))

    grads = jax.grad(loss)(a_params)["params"]["Dense_0"]
    z = obs @ jnp.array([0.3, -0.2]) + 0.05
    dq_da = 2.0  # the action's critic weight
    dmu_dz = 1 - jnp.tanh(z) ** 2
    expected = -(dq_da * dmu_dz[:, None] * obs).mean(0)  # Eq. 3.6, negated as a loss
    np.testing.assert_allclose(grads["kernel"][:, 0], expected, rtol=1e-5)
    np.testing.assert_allclose(grads["bias"], [-(dq_da * dmu_dz).mean()], rtol=1e-5)
    sig = DDPGActor(action_size=2, hidden=(4,), output="sigmoid")
    out = sig.apply(sig.init(jax.random.PRNGKey(0), obs), obs * 100)
    assert out.shape == (3, 2) and bool(((out >= 0) & (out <= 1)).all())


def test_twin_critic_target_and_loss_by_hand():
    """Clipped double Q on two tiny linear critics: y = r + γ(1 − d)·min(Q1', Q2') (Eq. 6.2), and
    the loss sums each critic's mean squared error against that shared target."""
    critic = DDPGCritic(hidden=())
    p1 = _linear_params([1.0, 0.0, 1.0], 0.0)  # Q1 = s0 + a
    p2 = _linear_params([0.0, 1.0, -1.0], 0.5)  # Q2 = s1 − a + 0.5
    stacked = jax.tree.map(lambda a, b: jnp.stack([a, b]), p1, p2)
    next_obs = jnp.array([[1.0, 2.0], [3.0, -1.0], [0.0, 0.0]])
    next_act = jnp.array([[0.5], [1.0], [-2.0]])
    next_q = jax.vmap(critic.apply, in_axes=(0, None, None))(stacked, next_obs, next_act)
    np.testing.assert_allclose(next_q, [[1.5, 4.0, -2.0], [2.0, -1.5, 2.5]], rtol=1e-6)
    y = td_target(jnp.array([1.0, 0.5, -1.0]), jnp.array([0.0, 0.0, 1.0]), clipped_double_q(next_q), 0.9)
    np.testing.assert_allclose(y, [1.0 + 0.9 * 1.5, 0.5 + 0.9 * -1.5, -1.0], rtol=1e-6)
    # one critic: the plain DDPG target
    np.testing.assert_allclose(clipped_double_q(next_q[:1]), next_q[0])
    q = jnp.array([[2.0, 0.0, -1.0], [1.0, -1.0, 0.0]])
    weights = jnp.array([1.0, 0.5, 2.0])
    loss, td = twin_critic_loss(q, y, weights)
    np.testing.assert_allclose(td, y[None] - q, rtol=1e-6)
    expected = sum(np.mean(np.asarray(weights) * (np.asarray(y) - np.asarray(qk)) ** 2) for qk in q)
    np.testing.assert_allclose(loss, expected, rtol=1e-6)


def test_linear_noise_factor_by_hand():
    # 1 → 0.2 over the first half of 100 iterations, then held
    f = [float(linear_noise_factor(jnp.asarray(i), 100, 0.2, 0.5)) for i in (0, 25, 50, 90)]
    np.testing.assert_allclose(f, [1.0, 0.6, 0.2, 0.2], rtol=1e-6)
    np.testing.assert_allclose(linear_noise_factor(jnp.asarray(30), 100, 1.0, 1.0), 1.0)


def test_soft_update_by_hand():
    target = {"w": jnp.array([1.0, 2.0]), "b": jnp.array(0.0)}
    online = {"w": jnp.array([3.0, -2.0]), "b": jnp.array(1.0)}
    new = soft_update(target, online, 0.05)
    np.testing.assert_allclose(new["w"], [0.05 * 3 + 0.95 * 1, 0.05 * -2 + 0.95 * 2], rtol=1e-6)
    np.testing.assert_allclose(new["b"], 0.05, rtol=1e-6)


def test_target_smoothing_noise_is_clipped_and_actions_stay_in_range():
    a = jnp.tile(jnp.array([[0.9, -0.2, 0.0]]), (4000, 1))
    out = np.asarray(smooth_target_action(jax.random.PRNGKey(0), a, 0.2, 0.5))
    np.testing.assert_allclose(out.max(0), [1.0, 0.3, 0.5], atol=1e-6)  # ±0.5 around μ', inside [-1, 1]
    np.testing.assert_allclose(out.min(0), [0.4, -0.7, -0.5], atol=1e-6)
    np.testing.assert_allclose(out[:, 2].std(), 0.2 * 0.988, rtol=0.05)  # σ of N(0, 0.2²) clipped at ±2.5σ
    np.testing.assert_allclose(smooth_target_action(jax.random.PRNGKey(1), a, 0.0, 0.5), a)


def _tiny(**kw):
    base = dict(epochs=1, cycles_per_epoch=1, updates_per_cycle=2, num_envs=2, batch_size=8, buffer_size=500,
                actor_hidden=(8,), critic_hidden=(8,))
    base.update(kw)
    return DDPGConfig(**base)


def _trained(trainer, chunks, seed=0):
    """The state after ``chunks`` jitted update chunks from ``init(PRNGKey(seed))``."""
    update = jax.jit(trainer.update)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(seed))
    for _ in range(chunks):
        state, _ = update(state)
    return state


@pytest.mark.parametrize("step_size,noise,expected", [(1e-4, 0.0, 0.0), (2.0, 10.0, 1.0)])
def test_replay_marks_termination_only(step_size, noise, expected):
    # tiny steps: every episode is cut by the time limit (truncation, d = 0);
    # saturated actions of size 2 leave the region [-1, 1]^3 at the first step (failure, d = 1)
    env = ToyGoalEnv(max_steps=3, action_scale=step_size, threshold=1e-6)
    trainer = make_trainer(_tiny(episode_length=3, noise_scale=(noise,), failure_value=-10.0), env)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    update = jax.jit(trainer.update)
    start = state
    state, metrics = update(state)
    # the output state has the input's exact types, so the next call reuses the compiled update
    same = jax.tree.map(lambda a, b: (a.shape, a.dtype, a.weak_type) == (b.shape, b.dtype, b.weak_type), start, state)
    assert all(jax.tree.leaves(same))
    size = int(state.replay.size)
    assert size == (2 * 3 if expected == 0.0 else 2)
    np.testing.assert_array_equal(state.replay.data.termination[:size], expected)
    # a failing step carries the absorbing failure value: r + γ·failure_value = -1 + 0.9·(-10)
    np.testing.assert_allclose(state.replay.data.reward[:size], -1.0 if expected == 0.0 else -10.0, rtol=1e-6)
    assert float(metrics["episodes"]) == 2.0
    # fewer transitions than a batch: no update yet, and the loss metrics stay finite (the CLI's NaN guard)
    assert float(metrics["updates"]) == 0.0 and float(metrics["critic_loss"]) == 0.0


def test_termination_metric_bootstraps_the_other_endings():
    """With ``termination_metric="success"`` a failing step of the toy env (leaving the region, success
    0) no longer terminates: d = 0 and no failure value (compare the test above: d = 1, −10)."""
    env = ToyGoalEnv(max_steps=3, action_scale=2.0, threshold=1e-6)
    trainer = make_trainer(_tiny(episode_length=3, noise_scale=(10.0,), failure_value=-10.0,
                                 termination_metric="success"), env)
    state, _ = jax.jit(trainer.update)(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    size = int(state.replay.size)
    assert size == 2
    np.testing.assert_array_equal(state.replay.data.termination[:size], 0.0)
    np.testing.assert_allclose(state.replay.data.reward[:size], -1.0)
    with pytest.raises(ConfigError, match="termination_metric='ended' is not a metric of this env; choose from"):
        make_trainer(_tiny(episode_length=3, termination_metric="ended"), env)


def test_reward_shift_enters_the_critic_target():
    """First update's critic loss with near-zero initial Q (last layers ±3e-3): sparse reward −1 on
    every stored step, so mean (Q − y)² ≈ (−1 + shift)² = 36 with shift −5 (1 if the shift were lost)."""
    env = ToyGoalEnv(max_steps=10, action_scale=1e-4, threshold=1e-6)
    trainer = make_trainer(_tiny(episode_length=10, updates_per_cycle=1, reward_shift=-5.0, actor_hidden=(),
                                 critic_hidden=()), env)
    _, metrics = jax.jit(trainer.update)(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    np.testing.assert_allclose(float(metrics["critic_loss"]), 36.0, rtol=0.02)


class _BoundedToyEnv(ToyGoalEnv):
    """The toy goal env with a (deliberately tight) return range ``[-0.5, 0]``."""

    def return_bounds(self, gamma):
        return -0.5, 0.0


def test_targets_are_clipped_to_the_env_return_bounds():
    """As above, every stored reward is −1 and the initial Q ≈ 0: mean (Q − y)² ≈ y².  With the env's
    bounds [−0.5, 0] the target is clipped to −0.5 (loss 0.25, unclipped 1); with reward_scale 2 the
    bounds scale to [−1, 0] and the target −2 is clipped to −1 (loss 1, unclipped 4)."""
    env = _BoundedToyEnv(max_steps=10, action_scale=1e-4, threshold=1e-6)
    for scale, expected in ((1.0, 0.25), (2.0, 1.0)):
        trainer = make_trainer(_tiny(episode_length=10, updates_per_cycle=1, clip_targets_to_env=True,
                                     reward_scale=scale, actor_hidden=(), critic_hidden=()), env)
        _, metrics = jax.jit(trainer.update)(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
        np.testing.assert_allclose(float(metrics["critic_loss"]), expected, rtol=0.02)
    assert with_env_target_clip(_tiny(clip_targets_to_env=True, reward_shift=-1.0, gamma=0.9), env).target_clip \
        == pytest.approx((-0.5 - 10.0, 0.0))  # a negative shift widens the lower bound by shift / (1 − γ)
    with pytest.raises(ConfigError, match="clip_targets_to_env=True needs an env whose return_bounds"):
        make_trainer(_tiny(clip_targets_to_env=True), ToyGoalEnv())
    with pytest.raises(ConfigError, match="target_clip and clip_targets_to_env=True exclude each other"):
        _tiny(clip_targets_to_env=True, target_clip=(-1.0, 0.0)).validate()


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match=r"policy_delay=0 is out of range; allowed \[1, inf\]"):
        _tiny(policy_delay=0).validate()
    with pytest.raises(ConfigError, match=r"noise_end_factor=1.5 is out of range; allowed \[0, 1\]"):
        _tiny(noise_end_factor=1.5).validate()
    with pytest.raises(ConfigError, match=r"noise_decay_fraction=0 is out of range; allowed \(0, 1\]"):
        _tiny(noise_decay_fraction=0).validate()
    with pytest.raises(ConfigError, match="reward_shift=nan must be a finite number"):
        _tiny(reward_shift=float("nan")).validate()
    with pytest.raises(ConfigError, match="her='best' is not valid"):
        _tiny(her="best").validate()
    with pytest.raises(ConfigError, match="per_tree='heap' is not valid; choose one of 'auto', 'sum', 'block'"):
        _tiny(per_tree="heap").validate()
    with pytest.raises(ConfigError, match="her='future' needs whole episodes"):
        _tiny(her="future", schedule="steps").validate()
    with pytest.raises(ConfigError, match=r"tau=0 is out of range"):
        _tiny(tau=0).validate()
    with pytest.raises(ConfigError, match="buffer_size=10 is out of range"):
        make_trainer(_tiny(buffer_size=10, episode_length=20), ToyGoalEnv())


def test_sparse_her_learns_to_reach_goals():
    """Sparse reward + HER future k=4 with PER on the toy reacher: ≥ 90 % of 100 test episodes."""
    env = ToyGoalEnv(reward="sparse", max_steps=20)
    config = DDPGConfig(epochs=3, cycles_per_epoch=10, num_envs=8, updates_per_cycle=20, buffer_size=20_000,
                        her="future", her_k=4, per=True, target_clip=(-10.0, 0.0), actor_hidden=(64, 64),
                        critic_hidden=(64, 64))
    trainer = make_trainer(config, env)
    update = jax.jit(trainer.update)
    state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    for _ in range(trainer.num_updates):
        state, metrics = update(state)
    assert float(metrics["updates"]) == 3 * 10 * 20
    result = summarize_episodes(run_test_episodes(jax.random.PRNGKey(1), env, trainer.policy(state), 100))
    assert result["success_rate"] >= 0.9, result


@pytest.mark.parametrize("schedule", ["episodes", "steps"])
def test_observation_normaliser_tracks_stored_observations(schedule, tmp_path):
    """``normalize_obs``: the running mean/variance equal those of every stored observation
    (numpy oracle), the policy feeds the actor ``(obs − mean) / std`` and a checkpoint restores
    the statistics; off, nothing changes."""
    env = ToyGoalEnv(max_steps=5, action_scale=0.05)
    kw = dict(episode_length=5, schedule=schedule, buffer_size=500)
    if schedule == "steps":
        kw.update(total_steps=40, unroll_length=5, num_envs=2)
    trainer = make_trainer(_tiny(normalize_obs=True, **kw), env)
    state = _trained(trainer, 2)
    size = int(state.replay.size)
    assert size > 10
    stored = np.asarray(state.replay.data.obs[:size], np.float64)
    stats = state.obs_stats
    np.testing.assert_allclose(stats.count, size, rtol=1e-5)
    np.testing.assert_allclose(stats.mean, stored.mean(0), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(stats.var, stored.var(0), rtol=1e-3, atol=1e-5)
    obs = jnp.asarray(stored[:3], jnp.float32)
    actor = DDPGActor(action_size=3, hidden=(8,), output="tanh")
    expected = actor.apply(state.actor_params, (obs - stats.mean) / jnp.sqrt(stats.var + 1e-8))
    np.testing.assert_allclose(trainer.policy(state)(obs), expected, rtol=1e-5, atol=1e-6)
    assert not np.allclose(expected, actor.apply(state.actor_params, obs), atol=1e-4)
    ckpt = Checkpointer(str(tmp_path / "ckpt"))
    ckpt.save(1, state, {"chunk": 1})
    ckpt.close()
    restored, _ = Checkpointer(str(tmp_path / "ckpt")).restore(1, jax.jit(trainer.init)(jax.random.PRNGKey(1)))
    for name in ("count", "mean", "var"):
        np.testing.assert_array_equal(getattr(restored.obs_stats, name), getattr(stats, name))

    plain = make_trainer(_tiny(**kw), env)
    pstate, _ = jax.jit(plain.update)(jax.jit(plain.init)(jax.random.PRNGKey(0)))
    np.testing.assert_array_equal(pstate.obs_stats.mean, 0.0)
    np.testing.assert_allclose(plain.policy(pstate)(obs), actor.apply(pstate.actor_params, obs), rtol=1e-6)


def test_priorities_from_clipped_td_errors_bound_the_importance_weights():
    """``priority_clip`` c and ``priority_eps`` ε: every re-prioritised slot lies in [ε^α, (c + ε)^α]
    (which bounds the importance-weight ratio, Eq. 3.10); without clipping the TD errors exceed c."""
    env = ToyGoalEnv(reward="sparse", max_steps=10)
    kw = dict(per=True, alpha=0.6, episode_length=10, updates_per_cycle=20, num_envs=4, batch_size=16,
              priority_eps=0.01, noise_scale=(0.5,))
    for clip in (0.05, 0.0):
        state = _trained(make_trainer(_tiny(priority_clip=clip, **kw), env), 3)
        size = int(state.replay.size)
        leaves = np.asarray(state.replay.tree.leaf_values[:size])
        assert leaves.min() >= 0.01**0.6 * (1 - 1e-5)
        if clip:
            # sampled slots were re-prioritised (< the initial max priority 1); all within (c + ε)^α
            assert leaves.max() <= 1.0 + 1e-6 and (leaves < 1.0).sum() > 0
            updated = leaves[leaves < 1.0]
            assert updated.max() <= (clip + 0.01) ** 0.6 * (1 + 1e-5)
        else:
            assert leaves[leaves < 1.0].max() > (0.05 + 0.01) ** 0.6


def test_twin_critics_with_policy_delay_count_actor_and_target_updates():
    """``twin_critics`` keeps two critics (stacked, different initialisations) and their targets;
    with ``policy_delay`` 3 the actor and both targets move only at updates 3, 6, …: after 2 updates
    they are untouched while the critics trained, after 4 and 6 the actor has had 1 and 2 Adam steps."""
    env = ToyGoalEnv(max_steps=5, action_scale=0.05)
    trainer = make_trainer(_tiny(twin_critics=True, policy_delay=3, per=True, episode_length=5), env)
    update = jax.jit(trainer.update)
    start = jax.jit(trainer.init)(jax.random.PRNGKey(0))
    kernels = jax.tree.leaves(start.critic_params)
    assert all(k.shape[0] == 2 for k in kernels)
    assert not np.allclose(kernels[-1][0], kernels[-1][1])

    def same(a, b):
        return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))

    state, metrics = update(start)
    assert int(state.updates) == 2 and int(state.critic_opt[0].count) == 2 and int(state.actor_opt[0].count) == 0
    assert same(state.actor_params, start.actor_params) and same(state.target_actor_params, start.actor_params)
    assert same(state.target_critic_params, start.critic_params)
    assert not same(state.critic_params, start.critic_params)
    assert np.isfinite(float(metrics["critic_loss"])) and np.isfinite(float(metrics["actor_loss"]))
    assert float(metrics["per_nonfinite_td"]) == 0.0
    # a critic that returns NaN: every TD error of a batch (8) is non-finite, logged, and kept out of the tree
    poisoned = state.replace(critic_params=jax.tree.map(lambda x: x * jnp.nan, state.critic_params))
    bad_state, bad = update(poisoned)
    assert float(bad["per_nonfinite_td"]) == 8.0
    assert np.isfinite(np.asarray(bad_state.replay.scalars)).all()
    assert np.isfinite(np.asarray(bad_state.replay.tree.leaf_values)).all()
    for updates, actor_steps in ((4, 1), (6, 2)):
        state, _ = update(state)
        assert int(state.updates) == updates and int(state.actor_opt[0].count) == actor_steps
    assert not same(state.target_critic_params, start.critic_params)


def test_noise_schedule_ends_at_the_greedy_action():
    """``noise_end_factor`` 0 reached after a quarter of the run: the first iteration stores noisy
    actions, every later one exactly ``μ(s)`` (no updates run, so μ is the initial actor)."""
    env = ToyGoalEnv(max_steps=50, action_scale=0.05)
    cfg = _tiny(schedule="steps", total_steps=32, num_envs=2, unroll_length=4, episode_length=50, learning_starts=400,
                noise_scale=(0.3,), noise_end_factor=0.0, noise_decay_fraction=0.25)
    trainer = make_trainer(cfg, env)
    state = _trained(trainer, 4)
    assert int(state.updates) == 0 and int(state.replay.size) == 32
    data = state.replay.data
    greedy = np.asarray(trainer.policy(state)(data.obs[:32]))
    gap = np.abs(np.asarray(data.action[:32]) - greedy).max(axis=1)
    assert gap[:8].min() > 1e-3  # iteration 0: factor 1
    np.testing.assert_allclose(gap[8:], 0.0, atol=1e-6)


def test_random_start_acts_uniformly_until_learning_starts():
    """``random_start``: the rows stored before ``learning_starts`` spread over [-1, 1] (mean ≈ 0, std
    ≈ 1/√3) whatever the actor, later rows are exactly ``μ(s)`` (no noise, no updates yet)."""
    env = ToyGoalEnv(max_steps=50, action_scale=0.05)
    cfg = _tiny(schedule="steps", total_steps=512, num_envs=8, unroll_length=8, episode_length=50, learning_starts=256,
                buffer_size=1024, batch_size=2048, noise_scale=(0.0,), random_start=True)
    trainer = make_trainer(cfg, env)
    state = _trained(trainer, 8)
    assert int(state.updates) == 0 and int(state.replay.size) == 512
    data = state.replay.data
    first, later = np.asarray(data.action[:256]), np.asarray(data.action[256:512])
    assert np.abs(first).max() <= 1.0 and abs(first.mean()) < 0.05 and abs(first.std() - 3**-0.5) < 0.03
    np.testing.assert_allclose(later, np.asarray(trainer.policy(state)(data.obs[256:512])), atol=1e-6)
    assert later.std() < 0.05  # the untrained actor's output is near-constant (last layer ±3e-3)
    with pytest.raises(ConfigError, match="random_start=True .* set learning_starts >= 1"):
        _tiny(random_start=True).validate()


def test_lr_end_factor_decays_adam_step_linearly_by_hand():
    """Adam's step on a constant gradient is ``lr_k · m̂/(√v̂ + ε) ≈ lr_k``, so the steps read off the schedule:
    lr 1e-3 falling to 0.5e-3 over 4 steps gives 1, 0.875, 0.75, 0.625, then 0.5 held (× 1e-3)."""
    tx = make_optimizer(1e-3, 0.0, end_factor=0.5, decay_steps=4)
    p = jnp.zeros(())
    opt = tx.init(p)
    steps = []
    for _ in range(6):
        upd, opt = tx.update(jnp.ones(()), opt, p)
        steps.append(-float(upd))
    np.testing.assert_allclose(steps, [1e-3, 0.875e-3, 0.75e-3, 0.625e-3, 0.5e-3, 0.5e-3], rtol=1e-4)
    const = make_optimizer(1e-3, 0.0)  # the default (factor 1): constant step
    upd, _ = const.update(jnp.ones(()), const.init(p), p)
    np.testing.assert_allclose(-float(upd), 1e-3, rtol=1e-5)
    assert DDPGConfig(lr_end_factor=0.1).validate().lr_end_factor == 0.1
    with pytest.raises(ConfigError, match=r"lr_end_factor=0.0 is out of range; allowed \(0, 1\]"):
        DDPGConfig(lr_end_factor=0.0).validate()
    with pytest.raises(ConfigError, match=r"lr_end_factor=1.5 is out of range; allowed \(0, 1\]"):
        DDPGConfig(lr_end_factor=1.5).validate()
