"""PPO: losses and the β rule by hand, config errors, and the training function on a toy env."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_mjx.config import ConfigError
from jaxrl_robot.agents.ppo import (
    PPOConfig,
    adapt_kl_beta,
    clipped_surrogate_loss,
    kl_penalty_loss,
    make_actor_loss,
    make_networks,
    make_train,
    make_trainer,
    optimizer_steps,
    value_loss,
)
from jaxrl_robot.networks import apply_actor, gaussian_sample, normalize
from tests.envs.toy import Toy, ToyConfig

# ---------------------------------------------------------------------------------------------
# losses, hand-computed


def test_clipped_surrogate_hand_computed_value_and_gradient():
    old = jnp.zeros(3)
    logp = jnp.log(jnp.array([1.5, 0.5, 1.1]))  # ratios 1.5, 0.5, 1.1
    adv = jnp.array([1.0, -1.0, 2.0])
    loss, clip_frac = clipped_surrogate_loss(logp, old, adv, 0.2)
    # min(1.5*1, 1.2*1) = 1.2; min(0.5*-1, 0.8*-1) = -0.8; min(2.2, 2.2) = 2.2
    np.testing.assert_allclose(loss, -(1.2 - 0.8 + 2.2) / 3, rtol=1e-6)
    np.testing.assert_allclose(clip_frac, 2 / 3, rtol=1e-6)
    # clipped terms carry no gradient; the unclipped one has d/dlogp = -r A / B
    grad = jax.grad(lambda lp: clipped_surrogate_loss(lp, old, adv, 0.2)[0])(logp)
    np.testing.assert_allclose(grad, [0.0, 0.0, -2.2 / 3], atol=1e-6)


def test_kl_penalty_loss_hand_computed():
    old = jnp.zeros(3)
    logp = jnp.log(jnp.array([1.5, 0.5, 1.1]))
    adv = jnp.array([1.0, -1.0, 2.0])
    kl = jnp.array([0.1, 0.2, 0.3])
    loss = kl_penalty_loss(logp, old, adv, kl, jnp.asarray(2.0))
    # r A - β KL = [1.5 - 0.2, -0.5 - 0.4, 2.2 - 0.6]
    np.testing.assert_allclose(loss, -(1.3 - 0.9 + 1.6) / 3, rtol=1e-6)
    g_kl = jax.grad(lambda k: kl_penalty_loss(logp, old, adv, k, jnp.asarray(2.0)))(kl)
    np.testing.assert_allclose(g_kl, [2 / 3] * 3, rtol=1e-6)


def test_extreme_ratios_give_finite_losses_and_gradients():
    # |log r| = 200 happens with σ = 0.1 when the mean swings across [-1, 1]; exp would overflow.
    logp = jnp.array([200.0, -200.0, 0.1])
    old = jnp.zeros(3)
    adv = jnp.array([-1.0, 1.0, 1.0])
    for fn in (
        lambda lp: clipped_surrogate_loss(lp, old, adv, 0.2)[0],
        lambda lp: kl_penalty_loss(lp, old, adv, jnp.ones(3), jnp.asarray(1.0)),
    ):
        value, grad = jax.value_and_grad(fn)(logp)
        assert np.isfinite(float(value)) and np.all(np.isfinite(np.asarray(grad)))
        assert float(grad[2]) != 0.0  # ordinary samples still carry their gradient


def test_beta_halves_and_doubles():
    beta = jnp.asarray(1.0)
    target = 0.01
    assert float(adapt_kl_beta(beta, jnp.asarray(0.005), target)) == 0.5  # D < D_thre / 1.5
    assert float(adapt_kl_beta(beta, jnp.asarray(0.02), target)) == 2.0  # D > 1.5 D_thre
    assert float(adapt_kl_beta(beta, jnp.asarray(0.01), target)) == 1.0
    assert float(adapt_kl_beta(beta, jnp.asarray(0.015), target)) == 1.0  # the bounds themselves keep β
    assert float(adapt_kl_beta(beta, jnp.asarray(0.01 / 1.5), target)) == 1.0
    # bounded: halving stops at the floor, doubling at the ceiling
    assert float(adapt_kl_beta(jnp.asarray(0.0015), jnp.asarray(0.0), target, 1e-3, 8.0)) == np.float32(1e-3)
    assert float(adapt_kl_beta(jnp.asarray(6.0), jnp.asarray(1.0), target, 1e-3, 8.0)) == 8.0
    assert float(adapt_kl_beta(jnp.asarray(3.0), jnp.asarray(1.0), target, 1e-3, 8.0)) == 6.0


def test_value_loss_hand_computed():
    np.testing.assert_allclose(value_loss(jnp.array([1.0, 2.0]), jnp.array([0.0, 4.0])), (1 + 4) / 2)


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match="objective='ppo'.*'clip', 'kl'"):
        PPOConfig(objective="ppo").validate()
    with pytest.raises(ConfigError, match=r"clip_eps=1.5 is out of range"):
        PPOConfig(clip_eps=1.5).validate()
    with pytest.raises(ConfigError, match="minibatch_size=30 must be a multiple of num_envs=4"):
        PPOConfig(minibatch_size=30).validate()
    with pytest.raises(ConfigError, match=r"minibatch_size=64 is out of range"):
        PPOConfig(minibatch_size=64).validate()
    with pytest.raises(ConfigError, match="state_std=True needs learn_std=True"):
        PPOConfig(state_std=True).validate()
    with pytest.raises(ConfigError, match="clip_actions=True and tanh_actions=True exclude each other"):
        PPOConfig(clip_actions=True, tanh_actions=True).validate()
    with pytest.raises(ConfigError, match="activation='gelu'.*'relu', 'swish'"):
        PPOConfig(activation="gelu").validate()
    lstm = dict(policy="lstm", batch_norm=False, num_envs=4, unroll_length=10, minibatch_size=40)
    with pytest.raises(ConfigError, match="tanh_actions=True needs policy='mlp'"):
        PPOConfig(tanh_actions=True, **lstm).validate()


# ---------------------------------------------------------------------------------------------
# the training function on a toy env


@dataclasses.dataclass(frozen=True)
class LineConfig(ToyConfig):
    max_steps: int = 8
    action_scale: float = 0.3


class Line(Toy):
    """1-D point that should move to 0 from a start in [-1, 1] (+ ``offset``), observing (x, |x|), rewarded for
    progress |x_prev| - |x|; its metric is success (|x| < 0.1, which ends the episode)."""

    name = "line"
    Config = LineConfig
    observation_size = 2
    start = (-1.0, 1.0)

    def observe(self, x):
        return jnp.concatenate([x, jnp.abs(x)])

    def reward(self, x_prev, x):
        return jnp.abs(x_prev[0]) - jnp.abs(x[0])

    def metrics(self, done, invalid):
        return {"success": done}


TOY = PPOConfig(
    total_steps=4 * 4 * 8,
    num_envs=4,
    unroll_length=8,
    minibatch_size=16,
    actor_updates=2,
    critic_updates=2,
    sigma=(0.5,),
    actor_hidden=(16,),
    critic_hidden=(16,),
    batch_norm=True,
    normalize_obs=True,
    objective="kl",
    kl_target=1e-3,
    schedule=((0.0, "offset", 0.0), (0.5, "offset", 5.0)),
)


@pytest.fixture(scope="module")
def toy():
    trainer = make_trainer(TOY, Line(), iterations_per_update=1)
    return trainer, jax.jit(trainer.init), jax.jit(trainer.update)


def test_update_runs_without_recompiling_and_reports_metrics(toy):
    trainer, init, update = toy
    assert trainer.num_updates == 4 and trainer.env_steps_per_update == 32
    state = init(jax.random.PRNGKey(0))
    state, m1 = update(state)
    state, m2 = update(state)
    assert update._cache_size() == 1
    for k in ("actor_loss", "critic_loss", "kl", "kl_beta", "entropy", "episodes", "success", "episode_return"):
        assert k in m2
    np.testing.assert_allclose(float(m1["policy_std"]), 0.5, rtol=1e-6)  # the first batch acted with σ = sigma
    assert int(state.iteration) == 2
    assert np.isfinite(float(m2["critic_loss"]))


def test_tanh_actions_act_with_tanh_of_the_mean_of_a_state_dependent_swish_actor():
    config = TOY.replace(tanh_actions=True, learn_std=True, state_std=True, activation="swish", batch_norm=False,
                         objective="clip", schedule=())  # fmt: skip
    trainer = make_trainer(config, Line())
    state, metrics = jax.jit(trainer.update)(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    assert np.isfinite(float(metrics["actor_loss"])) and np.isfinite(float(metrics["entropy"]))
    actor, _ = make_networks(config, 1)
    obs = jnp.array([[3.0, 3.0], [-0.2, 0.2]])
    (mean, log_std), _ = apply_actor(actor, state.actor_params, {}, normalize(state.obs_stats, obs))
    np.testing.assert_allclose(trainer.policy(state)(obs), jnp.tanh(mean), rtol=1e-6)
    assert not np.allclose(log_std[0], log_std[1])  # σ depends on the state
    sampled = trainer.sample_policy(state, jax.random.PRNGKey(1))
    many = jnp.tile(obs[:1], (4000, 1))
    _, actions = sampled.step(jax.tree.map(lambda c: jnp.broadcast_to(c, (4000,) + c.shape), sampled.carry), many)
    u = np.arctanh(np.asarray(actions[:, 0]))  # the env receives tanh of N(mean, σ²)
    np.testing.assert_allclose([u.mean(), u.std()], [mean[0, 0], np.exp(log_std[0, 0])], atol=0.05)


def test_kl_beta_follows_the_halve_double_rule_in_training(toy):
    _, init, update = toy
    state = init(jax.random.PRNGKey(1))
    beta = float(state.kl_beta)
    for _ in range(3):
        state, m = update(state)
        expected = float(adapt_kl_beta(jnp.asarray(beta), m["kl"], TOY.kl_target))
        assert math.isclose(float(m["kl_beta"]), expected, rel_tol=1e-6)
        assert float(state.kl_beta) == float(m["kl_beta"])
        beta = expected


def test_schedule_writes_episode_parameters_by_progress(toy):
    _, init, update = toy
    state = init(jax.random.PRNGKey(2))
    offsets = []
    for _ in range(4):
        state, _ = update(state)
        offsets.append(np.asarray(state.env_state.info["params"]["offset"]))
    # iterations 0 and 1 run at progress 0 and 0.25; iteration 2 starts at 0.5 → offset 5
    np.testing.assert_array_equal(offsets[0], 0.0)
    np.testing.assert_array_equal(offsets[1], 0.0)
    np.testing.assert_array_equal(offsets[2], 5.0)
    np.testing.assert_array_equal(offsets[3], 5.0)


def test_schedule_rejects_unknown_parameter():
    bad = TOY.replace(schedule=((0.0, "window", 1.0),))
    with pytest.raises(ConfigError, match="unknown episode parameter 'window'.*offset"):
        make_trainer(bad, Line())


def test_make_train_vmaps_over_seeds_and_matches_chunked_runs(toy):
    _, init, update = toy
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    states, metrics = jax.jit(jax.vmap(make_train(TOY, Line())))(keys)
    assert metrics["critic_loss"].shape == (2, 4)
    state = init(keys[1])
    for _ in range(4):
        state, _ = update(state)
    jax.tree.map(
        lambda a, b: np.testing.assert_allclose(a[1], b, rtol=1e-3, atol=1e-4),
        (states.actor_params, states.critic_params),
        (state.actor_params, state.critic_params),
    )
    kernels = states.actor_params["Dense_0"]["kernel"]
    assert not np.allclose(kernels[0], kernels[1])


def test_critic_first_takes_advantages_from_the_critic_after_this_iterations_updates():
    """One iteration with ``critic_first``: the critic ends where the thesis's order leaves it (its steps
    do not depend on the actor's), and the actor ends where the thesis's order takes it when it starts
    from that updated critic (its advantages come from the critic it starts with)."""
    config = TOY.replace(batch_norm=False, objective="clip", schedule=(), actor_updates=4, critic_updates=8,
                          critic_lr=0.03)
    first = jax.jit(make_trainer(config.replace(critic_first=True), Line()).update)
    plain_trainer = make_trainer(config, Line())
    plain = jax.jit(plain_trainer.update)
    s0 = jax.jit(plain_trainer.init)(jax.random.PRNGKey(4))
    s_first, _ = first(s0)
    s_plain, _ = plain(s0)
    s_oracle, _ = plain(s0.replace(critic_params=s_first.critic_params))
    close = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)  # noqa: E731
    jax.tree.map(close, s_first.critic_params, s_plain.critic_params)
    jax.tree.map(close, s_first.actor_params, s_oracle.actor_params)
    moved = lambda s: np.abs(s.actor_params["Dense_0"]["kernel"] - s0.actor_params["Dense_0"]["kernel"])  # noqa: E731
    change = np.abs(s_first.actor_params["Dense_0"]["kernel"] - s_plain.actor_params["Dense_0"]["kernel"]).max()
    assert change > 0.1 * moved(s_first).max()  # the advantages did change


def test_advantage_segments_of_the_whole_unroll_are_the_thesis_s_step_and_shorter_ones_only_cut_gae():
    """One mini-batch of the whole batch, one step each. Segments of the whole unroll: advantages and
    λ-returns from the critic that collected the data, as in the thesis's order, so actor and critic end
    where it leaves them. Segments of 2 steps with λ = 0 (one-step TD errors, which no segment end cuts)
    end there too; with λ = 0.95 the segment ends cut the λ-returns, so the critic's loss differs."""
    config = TOY.replace(batch_norm=False, objective="clip", schedule=(), minibatch_size=32, actor_updates=1,
                         critic_updates=1, critic_lr=0.03, actor_lr=0.03)  # fmt: skip
    close = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)  # noqa: E731
    s0 = jax.jit(make_trainer(config, Line()).init)(jax.random.PRNGKey(5))

    done: dict = {}

    def step(c: PPOConfig):
        if c not in done:
            done[c] = jax.jit(make_trainer(c, Line()).update)(s0)
        return done[c]

    for c in (config.replace(advantage_segment=8), config.replace(advantage_segment=2, gae_lambda=0.0)):
        (seg, m_seg), (same, m_same) = step(c), step(c.replace(advantage_segment=0))
        jax.tree.map(close, (seg.actor_params, seg.critic_params), (same.actor_params, same.critic_params))
        close(m_seg["critic_loss"], m_same["critic_loss"])
    (_, m_cut), (plain, m_plain) = step(config.replace(advantage_segment=2)), step(config)
    assert abs(float(m_cut["critic_loss"]) / float(m_plain["critic_loss"]) - 1.0) > 0.01
    assert np.abs(plain.actor_params["Dense_0"]["kernel"] - s0.actor_params["Dense_0"]["kernel"]).max() > 0.01


def test_linear_lr_schedule_anneals_each_optimiser_over_its_own_steps_by_hand():
    """Adam's step on the same gradients scales with the learning rate: two iterations of one actor and one
    critic step from the same state, linear over a run of 4 iterations against constant — the first steps
    agree, the second ones are 3/4 of the constant run's (lr · (1 − 1/4)). The planned steps by hand: 10
    iterations of 3 actor and 2 critic steps, 4 of them pre-training the actor without its optimiser."""
    config = TOY.replace(batch_norm=False, objective="clip", schedule=(), minibatch_size=32, actor_updates=1,
                         critic_updates=1, actor_lr=0.01, critic_lr=0.01, total_steps=4 * 32)  # fmt: skip
    runs = {}
    for name in ("constant", "linear"):
        trainer = make_trainer(config.replace(lr_schedule=name), Line())
        update = jax.jit(trainer.update)
        s0 = jax.jit(trainer.init)(jax.random.PRNGKey(6))
        s1, _ = update(s0)
        runs[name] = (s0, s1, update(s1)[0])
    for field in ("actor_params", "critic_params"):
        (c0, c1, c2), (l0, l1, l2) = ([getattr(s, field) for s in runs[n]] for n in ("constant", "linear"))
        jax.tree.map(lambda a, b: np.testing.assert_array_equal(a, b), c0, l0)
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-7), c1, l1)
        step = lambda a, b: np.asarray(b - a).ravel()  # noqa: E731
        for a, b, x, y in zip(*map(jax.tree.leaves, (c1, c2, l1, l2)), strict=True):
            np.testing.assert_allclose(step(x, y), 0.75 * step(a, b), rtol=1e-4, atol=1e-8)
        moved = [np.abs(step(a, b)).max() for a, b in zip(jax.tree.leaves(c1), jax.tree.leaves(c2), strict=True)]
        assert max(moved) > 1e-3
    assert optimizer_steps(TOY.replace(actor_updates=3, critic_updates=2), 10, pretrain_iters=4) == (18, 20)
    with pytest.raises(ConfigError, match="lr_schedule='cosine'.*'constant', 'linear'"):
        TOY.replace(lr_schedule="cosine").validate()


def test_advantage_segment_errors_name_the_setting():
    base = dict(num_envs=4, unroll_length=8, minibatch_size=16, actor_updates=2, critic_updates=2)
    PPOConfig(advantage_segment=4, **base).validate()
    for change, message in (
        (dict(advantage_segment=3), "advantage_segment=3 must divide unroll_length=8"),
        (dict(advantage_segment=8, minibatch_size=20), "advantage_segment=8 must divide minibatch_size=20"),
        (dict(advantage_segment=4, critic_updates=3), "actor_updates=2 must equal critic_updates=3"),
        (dict(advantage_segment=4, critic_first=True), "critic_first=True is not available with advantage_segment=4"),
        (dict(advantage_segment=-1), "advantage_segment=-1 is out of range"),
    ):
        with pytest.raises(ConfigError, match=message):
            PPOConfig(**{**base, **change}).validate()


# ---------------------------------------------------------------------------------------------
# batch-norm actor: π_old is the policy that acted


def _first_step_clip_fraction_and_kl(mode: str) -> tuple[float, float]:
    """PPO's actor loss at unchanged parameters on a thesis-like mini-batch (4 lanes x 8 steps, one
    goal per lane), π_old = the acting policy after the moving averages (decay 0.99) have settled
    over 200 such mini-batches. Returns (clip fraction, KL(π_old ‖ π_θ))."""
    k_goal, k_x, k_init, k_act = jax.random.split(jax.random.PRNGKey(0), 4)
    goals = jnp.broadcast_to(1.0 + 3.0 * jax.random.normal(k_goal, (201, 4, 1, 2)), (201, 4, 8, 2))
    moves = 0.5 * jax.random.normal(k_x, (201, 4, 8, 1))
    batches = jnp.concatenate([goals, moves], -1).reshape(201, 32, 3)
    config = PPOConfig(actor_hidden=(16, 16), sigma=(0.1,), batch_norm=True, bn_mode=mode, bn_momentum=0.99)
    actor = make_networks(config, 2)[0].clone(bn_axis_name=None)  # outside shard_map
    variables = actor.init(k_init, batches[0])
    params = dict(variables["params"])
    params["Dense_2"] = jax.tree.map(lambda w: 100.0 * w, params["Dense_2"])  # actions that depend on s

    def settle(stats, batch):
        return apply_actor(actor, params, stats, batch, train=True)[1], None

    stats, _ = jax.lax.scan(settle, variables["batch_stats"], batches[:-1])
    obs = batches[-1]
    (old_mean, old_log_std), _ = apply_actor(actor, params, stats, obs)  # acting
    action = gaussian_sample(k_act, old_mean, old_log_std)
    mb = (obs, action, jnp.ones(32), old_mean, old_log_std)
    _, (_, clip_frac, _, kl) = jax.jit(make_actor_loss(config, actor))(params, stats, mb, jnp.asarray(1.0))
    return float(clip_frac), float(kl)


def test_first_actor_step_ratio_is_one_against_the_acting_batch_norm_policy():
    """Before any update, r = π_θ(a|s) / π_old(a|s) must be 1 where π_old is the acting policy
    (moving averages) and π_θ the training-mode one. Plain batch-norm breaks this from the first
    step on few-goal mini-batches; batch renormalisation keeps it (KL 0, nothing clipped)."""
    clip_renorm, kl_renorm = _first_step_clip_fraction_and_kl("renorm")
    clip_batch, kl_batch = _first_step_clip_fraction_and_kl("batch")
    assert clip_renorm == 0.0 and kl_renorm < 1e-6, (clip_renorm, kl_renorm)
    assert clip_batch > 0.1 and kl_batch > 0.1, (clip_batch, kl_batch)


def test_tanh_actions_entropy_bonus_is_the_squashed_action_s_at_the_stored_noise():
    """With ``tanh_actions`` the loss's entropy is H(u) + Σ log(1 − tanh²(u)) at u = mean_θ + σ_θ ε, ε the noise
    that drew each stored action from π_old (by hand with numpy); without it, the Gaussian's H(u) alone."""
    mean, log_std = jnp.array([[0.2, -1.5], [2.0, 0.0]]), jnp.log(jnp.array([[0.5, 0.3], [0.4, 1.0]]))
    old_mean, old_log_std = mean + 0.1, log_std - 0.2
    eps = np.array([[0.3, -1.2], [0.8, 0.5]])
    action = old_mean + jnp.exp(old_log_std) * eps
    mb = (jnp.zeros((2, 3)), action, jnp.ones(2), old_mean, old_log_std)

    def forward(params, stats, obs):  # π_θ's outputs given directly
        return (mean, log_std), stats

    gaussian = np.sum(np.asarray(log_std) + 0.5 * (1.0 + math.log(2 * math.pi)), -1)
    u = np.asarray(mean) + np.exp(np.asarray(log_std)) * eps
    squashed = gaussian + np.sum(np.log1p(-np.tanh(u) ** 2), -1)
    for tanh, expect in ((True, squashed), (False, gaussian)):
        config = PPOConfig(tanh_actions=tanh, learn_std=True)
        _, (_, _, entropy, _) = make_actor_loss(config, None, forward)({}, {}, mb, jnp.asarray(1.0))
        np.testing.assert_allclose(float(entropy), np.mean(expect), rtol=1e-5)
