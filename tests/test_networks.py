"""Actor/critic shapes, fixed vs learned σ, batch-norm and batch renormalisation train vs eval, Gaussian helpers."""

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxrl_robot.networks import (
    BatchRenorm,
    Critic,
    GaussianActor,
    apply_actor,
    gaussian_entropy,
    gaussian_kl,
    gaussian_log_prob,
    gaussian_sample,
    tanh_gaussian_entropy,
    tanh_log_det_jacobian,
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


def test_state_dependent_sigma_starts_at_sigma_varies_with_the_state_and_keeps_its_floor():
    actor = GaussianActor(action_size=2, hidden=(4,), sigma=(0.7, 0.2), learn_std=True, state_std=True, squash=False)
    obs = jax.random.normal(jax.random.PRNGKey(2), (6, 3))
    params = actor.init(jax.random.PRNGKey(0), obs)["params"]
    zero = jax.tree.map(jnp.zeros_like, params["std"])
    _, log_std = actor.apply({"params": {**params, "std": zero}}, obs)
    np.testing.assert_allclose(np.exp(log_std), np.tile([0.7, 0.2], (6, 1)), rtol=1e-5)  # softplus(c) + 0.001 = σ
    _, log_std = actor.apply({"params": params}, obs)
    assert np.ptp(np.asarray(log_std)[:, 0]) > 0  # a state-dependent σ
    low = {**params, "std": {"kernel": zero["kernel"], "bias": jnp.full((2,), -50.0)}}
    _, log_std = actor.apply({"params": low}, obs)
    np.testing.assert_allclose(np.exp(log_std), 1e-3, rtol=1e-3)  # the floor min_std
    # squash=False: the mean is the last layer's output, not bounded by tanh
    big = jax.tree.map(lambda x: 1e3 * x, params)
    mean, _ = actor.apply({"params": big}, obs)
    assert np.abs(np.asarray(mean)).max() > 1.0


def test_activation_is_chosen_by_name_and_an_unknown_one_names_the_choices():
    obs = jax.random.normal(jax.random.PRNGKey(1), (4, 3))
    relu, swish = Critic(hidden=(8,)), Critic(hidden=(8,), activation="swish")
    params = relu.init(jax.random.PRNGKey(0), obs)
    h = obs @ params["params"]["MLP_0"]["Dense_0"]["kernel"] + params["params"]["MLP_0"]["Dense_0"]["bias"]
    out = params["params"]["Dense_0"]
    expect = (h * jax.nn.sigmoid(h)) @ out["kernel"][:, 0] + out["bias"][0]  # swish by hand
    np.testing.assert_allclose(swish.apply(params, obs), expect, rtol=1e-5)
    assert not np.allclose(relu.apply(params, obs), expect)
    try:
        Critic(hidden=(8,), activation="gelu").init(jax.random.PRNGKey(0), obs)
    except ValueError as e:
        assert "activation='gelu'" in str(e) and "'swish'" in str(e)
    else:
        raise AssertionError("an unknown activation must raise")


def test_batch_norm_uses_batch_stats_in_training_and_moving_averages_in_eval():
    actor = GaussianActor(action_size=1, hidden=(6,), batch_norm=True, bn_momentum=0.5, bn_mode="batch")
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


def test_batch_renorm_hand_computed_training_output_moving_averages_and_gradient():
    eps = 1e-3
    layer = BatchRenorm(momentum=0.9, epsilon=eps)
    x = jnp.array([[0.0, 1.0], [2.0, 1.0], [4.0, 1.0]])  # batch mean [2, 1], biased var [8/3, 0]
    variables = layer.init(jax.random.PRNGKey(0), x, use_running_average=True)
    stats = {"mean": jnp.array([1.0, 0.0]), "var": jnp.array([4.0, 1.0])}
    params = {"scale": jnp.array([2.0, 1.0]), "bias": jnp.array([0.5, 0.0])}
    assert set(variables["params"]) == set(params) and set(variables["batch_stats"]) == set(stats)

    def train(p, inp):
        return layer.apply({"params": p, "batch_stats": stats}, inp, use_running_average=False, mutable=["batch_stats"])

    y, upd = train(params, x)
    # Unclipped (r = sqrt((8/3 + ε)/(4 + ε)) ∈ [1/3, 3], d = 1/sqrt(4 + ε)): (x - μ)/σ with the moving stats.
    expected = np.array(params["scale"]) * (np.array(x) - [1.0, 0.0]) / np.sqrt(np.array([4.0, 1.0]) + eps)
    np.testing.assert_allclose(y[:, 0], expected[:, 0] + 0.5, rtol=1e-5)
    # Column 2 is constant in the batch: r = sqrt(ε / (1 + ε)) < 1/3 is clipped, d = 1/sqrt(1 + ε):
    # x̂ = 0 · r + d.
    np.testing.assert_allclose(y[:, 1], 1.0 / np.sqrt(1.0 + eps), rtol=1e-5)
    y_eval = layer.apply({"params": params, "batch_stats": stats}, x, use_running_average=True)
    np.testing.assert_allclose(y_eval[:, 0], y[:, 0], rtol=1e-5)
    np.testing.assert_allclose(upd["batch_stats"]["mean"], [0.9 * 1 + 0.1 * 2, 0.1 * 1.0], rtol=1e-6)
    np.testing.assert_allclose(upd["batch_stats"]["var"], [0.9 * 4 + 0.1 * 8 / 3, 0.9], rtol=1e-6)
    # Gradients flow through the batch statistics: Σ_i y_i does not depend on the inputs in
    # training (the batch mean is subtracted), but does by n·scale/σ in evaluation.
    g_train = jax.grad(lambda inp: jnp.sum(train(params, inp)[0][:, 0]))(x)
    np.testing.assert_allclose(g_train[:, 0], 0.0, atol=1e-6)
    g_eval = jax.grad(lambda inp: jnp.sum(layer.apply({"params": params, "batch_stats": stats}, inp, True)[:, 0]))(x)
    np.testing.assert_allclose(g_eval[:, 0], 2.0 / np.sqrt(4.0 + eps), rtol=1e-5)
    # Masked rows do not count in the statistics.
    mask = jnp.array([[True], [True], [False]])
    _, upd_m = layer.apply(
        {"params": params, "batch_stats": stats}, x, use_running_average=False, mask=mask, mutable=["batch_stats"]
    )
    np.testing.assert_allclose(upd_m["batch_stats"]["mean"][0], 0.9 * 1 + 0.1 * 1.0, rtol=1e-6)
    np.testing.assert_allclose(upd_m["batch_stats"]["var"][0], 0.9 * 4 + 0.1 * 1.0, rtol=1e-6)


def _few_goal_batches(key, count, lanes=4, steps=8):
    """``[count, lanes * steps, 3]`` thesis-like mini-batches: per lane one goal (2 features,
    spread 3 around 1) held for all its steps, plus a feature that changes every step."""
    k_goal, k_x = jax.random.split(key)
    goal = 1.0 + 3.0 * jax.random.normal(k_goal, (count, lanes, 1, 2))
    goal = jnp.broadcast_to(goal, (count, lanes, steps, 2))
    x = 0.5 * jax.random.normal(k_x, (count, lanes, steps, 1))
    return jnp.concatenate([goal, x], axis=-1).reshape(count, lanes * steps, 3)


def _settled_actor(mode: str):
    """Actor (BN, last layer scaled up so actions depend on the state), moving averages (decay 0.99)
    after 200 training calls on few-goal mini-batches, and a fresh mini-batch."""
    actor = GaussianActor(action_size=2, hidden=(16, 16), batch_norm=True, bn_mode=mode, bn_momentum=0.99)
    batches = _few_goal_batches(jax.random.PRNGKey(0), 201)
    variables = actor.init(jax.random.PRNGKey(1), batches[0])
    params = dict(variables["params"])
    params["Dense_2"] = jax.tree.map(lambda w: 100.0 * w, params["Dense_2"])

    def settle(stats, batch):
        return apply_actor(actor, params, stats, batch, train=True)[1], None

    stats, _ = jax.lax.scan(settle, variables["batch_stats"], batches[:-1])
    return actor, params, stats, batches[-1]


def test_batch_renorm_actor_trains_the_policy_it_acts_with_on_few_goal_minibatches():
    """The thesis preset's failure: 4 lanes give mini-batches of 4 goals. With plain batch-norm
    the training-mode policy (each mini-batch's own statistics) is far from the acting policy
    (moving averages) even when the moving averages have settled; batch renormalisation makes
    them equal."""
    gaps = {}
    for mode in ("batch", "renorm"):
        actor, params, stats, batch = _settled_actor(mode)
        (m_train, _), _ = apply_actor(actor, params, stats, batch, train=True)
        (m_eval, _), _ = apply_actor(actor, params, stats, batch, train=False)
        gaps[mode] = float(np.max(np.abs(m_train - m_eval)))
    gap_bn, gap_renorm = gaps["batch"], gaps["renorm"]
    assert gap_bn > 0.1, gap_bn
    assert gap_renorm < 1e-4, gap_renorm


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


def test_running_stats_merge_equals_numpy_over_all_rows_and_respects_the_mask():
    from jaxrl_robot.networks import init_running_stats, update_running_stats

    rng = np.random.default_rng(0)
    a, b = rng.normal(1.0, 2.0, (7, 3)), rng.normal(-3.0, 0.5, (5, 3))
    stats = update_running_stats(update_running_stats(init_running_stats(3), jnp.asarray(a)), jnp.asarray(b))
    both = np.concatenate([a, b])
    np.testing.assert_allclose(stats.count, 12, atol=1e-3)  # + the 1e-4 prior count
    np.testing.assert_allclose(stats.mean, both.mean(0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(stats.var, both.var(0), rtol=1e-4, atol=1e-4)
    # masked: only the rows marked count
    mask = np.array([1, 0, 1, 1, 0], np.float32)
    first = update_running_stats(init_running_stats(3), jnp.asarray(a))
    masked = update_running_stats(first, jnp.asarray(b), mask=mask)
    kept = np.concatenate([a, b[mask > 0]])
    np.testing.assert_allclose(masked.count, 10, atol=1e-3)
    np.testing.assert_allclose(masked.mean, kept.mean(0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(masked.var, kept.var(0), rtol=1e-4, atol=1e-4)
    # a batch with no marked row leaves the statistics as they were
    same = update_running_stats(masked, jnp.asarray(b), mask=np.zeros(5, np.float32))
    for name in ("count", "mean", "var"):
        np.testing.assert_array_equal(getattr(same, name), getattr(masked, name))


def test_tanh_log_det_jacobian_by_hand():
    u = jnp.array([[0.0, 1.0, -2.5, 12.0]])
    expect = np.sum(np.log1p(-np.tanh(np.array([0.0, 1.0, -2.5])) ** 2)) + (2 * math.log(2) - 24.0)  # u=12: 4e^-24
    np.testing.assert_allclose(float(tanh_log_det_jacobian(u)[0]), expect, rtol=1e-5)


def test_tanh_gaussian_entropy_averages_to_the_squashed_entropy_and_falls_in_the_tails():
    """Mean of the one-sample estimates over 200 000 draws against H(u) + E[log(1 − tanh²u)] by quadrature
    on a grid; a mean in the tail has less entropy, and the estimate's gradient pulls it back."""
    grid = np.linspace(-8.0, 8.0, 20001)

    def by_quadrature(mu: float, sigma: float) -> float:
        u = mu + sigma * grid
        density = np.exp(-0.5 * grid**2) / math.sqrt(2 * math.pi)
        log_det = np.trapezoid(density * np.log1p(-np.tanh(u) ** 2), grid)
        return 0.5 * math.log(2 * math.pi * math.e * sigma**2) + log_det

    noise = jax.random.normal(jax.random.PRNGKey(0), (200_000, 1))
    for mu, sigma in ((0.0, 0.5), (2.0, 0.3), (-1.0, 1.0)):
        mean, log_std = jnp.full((200_000, 1), mu), jnp.full((200_000, 1), math.log(sigma))
        estimate = float(jnp.mean(tanh_gaussian_entropy(mean, log_std, noise)))
        np.testing.assert_allclose(estimate, by_quadrature(mu, sigma), atol=5e-3)

    def entropy_at(m):  # σ = e^-1
        return jnp.mean(tanh_gaussian_entropy(jnp.full((1000, 1), m), jnp.full((1000, 1), -1.0), noise[:1000]))

    assert float(entropy_at(3.0)) < float(entropy_at(0.0)) - 3.0
    assert float(jax.grad(entropy_at)(3.0)) < -1.0  # maximising it moves a saturated mean back towards 0
