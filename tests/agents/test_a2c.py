"""A2C / A3C: targets, entropy and losses by hand; gradient averaging; the asynchronous push
schedule and its staleness against a hand-worked K = 3 schedule; A3C(1 worker) = A2C(1 worker);
devices do not change the result; learning on a toy reaching task."""

import dataclasses
import math
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State

from envs_mjx.base import RobotEnv, sanitize_action
from envs_mjx.config import ConfigError, check_range
from jaxrl_robot.agents.a2c import (
    A2CConfig,
    A3CConfig,
    actor_loss,
    critic_loss,
    init_push_state,
    make_networks,
    make_train,
    make_trainer,
    make_worker_loss,
    push_in_order,
    push_order,
    staleness_histogram,
    worker_targets,
)
from jaxrl_robot.evaluation import run_test_episodes
from jaxrl_robot.networks import gaussian_entropy
from jaxrl_robot.types import Transition
from tests.subproc import ROOT, cpu_env


def f32(x):
    return jnp.asarray(x, jnp.float32)


# ---------------------------------------------------------------------------------------------
# toy reaching env: a point moves by Δp toward a random goal (the arm7 task without the arm)


@dataclasses.dataclass(frozen=True)
class ReachConfig:
    max_steps: int = 30
    action_scale: float = 0.15
    goal_radius: float = 0.1

    def validate(self):
        check_range("max_steps", self.max_steps, 1)


class Reach(RobotEnv):
    """obs = [p, g - p]; reward = distance progress / C (+1 on success, -1 outside the box)."""

    name = "reach"
    Config = ReachConfig
    observation_size = 6
    action_size = 3

    def reset(self, rng, params=None):
        kp, kg = jax.random.split(rng)
        p = jax.random.uniform(kp, (3,), minval=-0.5, maxval=0.5)
        g = jax.random.uniform(kg, (3,), minval=-0.5, maxval=0.5)
        zero = jnp.zeros(())
        return State(
            pipeline_state=(p, g),
            obs=jnp.concatenate([p, g - p]),
            reward=zero,
            done=zero,
            metrics={"success": zero},
            info={},
        )

    def step(self, state, action):
        a, _ = sanitize_action(action)
        p, g = state.pipeline_state
        q = p + self.action_scale * a
        d0, d1 = jnp.linalg.norm(g - p), jnp.linalg.norm(g - q)
        success = (d1 < self.config.goal_radius).astype(jnp.float32)
        out = jnp.any(jnp.abs(q) > 1.0).astype(jnp.float32)
        reward = (d0 - d1) / self.config.action_scale + success - out
        return state.replace(
            pipeline_state=(q, g),
            obs=jnp.concatenate([q, g - q]),
            reward=reward,
            done=jnp.maximum(success, out),
            metrics={"success": success},
        )


SMALL = dict(actor_hidden=(16, 16), critic_hidden=(16, 16), sigma=(0.3,), total_steps=10_000)
# Without batch-norm where runs are compared leaf by leaf: the input BN's shift has an analytically
# zero gradient (the next BN removes any shift), and Adam turns two computations' different
# rounding there into full-size steps, so such runs drift apart by rounding alone.
K3_CONFIG = A3CConfig(num_envs=3, unroll_length=4, push_order="fixed", batch_norm=False, **SMALL)


# ---------------------------------------------------------------------------------------------
# targets (Algorithm 3, lines 9-13; Eq. 4.3), entropy, losses — hand-computed


def test_worker_targets_hand_computed_termination_truncation_and_short_buffer():
    g = 0.5
    r = f32([1.0, 2.0, 4.0])
    nv = f32([10.0, 20.0, 40.0])  # V(s'_t)
    zeros, full = f32([0, 0, 0]), f32([1, 1, 1])
    # full buffer, no episode end: R_2 = 4 + .5*40 = 24, R_1 = 2 + .5*24 = 14, R_0 = 1 + .5*14 = 8
    np.testing.assert_allclose(worker_targets(r, nv, zeros, zeros, full, g), [8.0, 14.0, 24.0])
    # termination at t=1 (Algorithm 3: R = 0 at a terminal state), buffer closed there
    mask = f32([1, 1, 0])
    got = worker_targets(r, nv, f32([0, 1, 0]), zeros, mask, g)
    np.testing.assert_allclose(got[:2], [1 + 0.5 * 2, 2.0])
    # truncation (time limit) at t=1: not terminal, so R starts from V(s'_1) = 20
    got = worker_targets(r, nv, zeros, f32([0, 1, 0]), mask, g)
    np.testing.assert_allclose(got[:2], [1 + 0.5 * (2 + 0.5 * 20), 2 + 0.5 * 20])
    # an empty slot never leaks into the filled ones, whatever it holds
    got2 = worker_targets(f32([1.0, 2.0, 1e6]), f32([10.0, 20.0, 1e6]), zeros, f32([0, 1, 0]), mask, g)
    np.testing.assert_allclose(got2[:2], got[:2])


def test_gaussian_entropy_of_the_thesis_sigma():
    sigma = np.array([0.8, 0.8, 0.1])
    expected = float(np.sum(0.5 * np.log(2 * math.pi * math.e * sigma**2)))
    np.testing.assert_allclose(gaussian_entropy(jnp.log(f32(sigma))), expected, rtol=1e-6)
    # the actor with fixed σ reports it for every state
    actor, _ = make_networks(A2CConfig(batch_norm=False, sigma=(0.8, 0.8, 0.1)), 3)
    _, log_std = jax.jit(lambda k, o: actor.apply(actor.init(k, o), o))(jax.random.PRNGKey(0), jnp.ones((2, 6)))
    np.testing.assert_allclose(gaussian_entropy(log_std), [expected, expected], rtol=1e-6)


def test_actor_and_critic_losses_hand_computed_with_mask():
    logp = f32([-1.0, -2.0, -3.0])
    adv = f32([2.0, -1.0, 100.0])
    ent = f32([0.5, 0.5, 0.5])
    mask = f32([1, 1, 0])
    # -(1/2) Σ [logp A + β H] over the two filled slots, β = 0.1
    expected = -((-1.0 * 2.0 + 0.05) + (-2.0 * -1.0 + 0.05)) / 2
    np.testing.assert_allclose(actor_loss(logp, adv, ent, mask, 0.1), expected, rtol=1e-6)
    # gradient wrt log π is -A/N on filled slots; the advantage is a constant
    g_logp, g_adv = jax.grad(lambda lp, a: actor_loss(lp, a, ent, mask, 0.1), argnums=(0, 1))(logp, adv)
    np.testing.assert_allclose(g_logp, [-1.0, 0.5, 0.0])
    np.testing.assert_allclose(g_adv, [0.0, 0.0, 0.0])
    # Eq. 4.5
    np.testing.assert_allclose(critic_loss(f32([1.0, 2.0, 9.0]), f32([0.0, 4.0, 0.0]), mask), (1 + 4) / 2)


# ---------------------------------------------------------------------------------------------
# A2C: the applied gradient is the mean of the workers' gradients


def _random_buffer(key, N, K, obs=6, act=3):
    ks = jax.random.split(key, 5)
    lengths = jnp.array([N, 3, 1, N][:K])  # buffers closed early at an episode end
    mask = (jnp.arange(N)[:, None] < lengths[None, :]).astype(jnp.float32)
    ends = (jnp.arange(N)[:, None] == lengths[None, :] - 1).astype(jnp.float32) * (lengths < N)
    traj = Transition(
        obs=jax.random.normal(ks[0], (N, K, obs)),
        action=jax.random.normal(ks[1], (N, K, act)),
        reward=jax.random.normal(ks[2], (N, K)),
        next_obs=jax.random.normal(ks[3], (N, K, obs)),
        termination=ends * jnp.array([0, 1, 0, 0][:K], jnp.float32),
        truncation=ends * jnp.array([0, 0, 1, 0][:K], jnp.float32),
    )
    return traj, mask


def test_a2c_gradient_is_the_mean_of_the_worker_gradients():
    cfg = A2CConfig(bn_batch="lane", actor_hidden=(8, 8), critic_hidden=(8, 8))
    actor, critic = make_networks(cfg.replace(bn_batch="lane"), 3)
    loss = make_worker_loss(cfg, actor, critic)
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(0), 3)
    av = actor.init(k1, jnp.zeros((1, 6)))
    diff = (av["params"], critic.init(k2, jnp.zeros((1, 6)))["params"])
    buf = _random_buffer(k3, N=5, K=4)
    grad = jax.jit(jax.grad(lambda d, b: loss(d, av["batch_stats"], *b)[0]))
    all_workers = grad(diff, buf)
    single = [grad(diff, _lane(buf, i)) for i in range(4)]
    mean = jax.tree.map(lambda *g: sum(g) / 4, *single)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6), all_workers, mean)
    # and the workers' gradients differ, so the mean is not trivially any one of them
    assert not np.allclose(single[0][1]["Dense_0"]["kernel"], single[1][1]["Dense_0"]["kernel"])


def _lane(buf, i):
    return jax.tree.map(lambda x: x[:, i : i + 1], buf)


# ---------------------------------------------------------------------------------------------
# A3C: push schedule and staleness


def _sgd_apply(global_, g):
    return global_ - g


def test_push_schedule_k3_fixed_order_hand_worked():
    """Pushes in order 0, 1, 2 each round; gradients 1, 10, 100; SGD with step 1.

    Round 1: worker 0 pushes with nothing applied since its sync → staleness 0, θ = -1, it
    re-syncs; worker 1 computed at θ = 0, one update since → staleness 1, θ = -11; worker 2 →
    staleness 2, θ = -111. From round 2 on every worker has missed the other two pushes: 2.
    """
    state = init_push_state(jnp.zeros(()), jnp.zeros(()), 3)
    grads = f32([1.0, 10.0, 100.0])
    order = push_order(None, 3, "fixed")
    local = jnp.arange(3)
    state, st = push_in_order(state, grads, order, _sgd_apply, lambda g: g, local)
    np.testing.assert_array_equal(st, [0, 1, 2])
    np.testing.assert_allclose(state.global_, -111.0)
    np.testing.assert_allclose(state.snapshots, [-1.0, -11.0, -111.0])  # each synced right after its push
    np.testing.assert_array_equal(state.versions, [1, 2, 3])
    for r in range(3):
        state, st = push_in_order(state, grads, order, _sgd_apply, lambda g: g, local)
        np.testing.assert_array_equal(st, [2, 2, 2])
        np.testing.assert_allclose(state.snapshots, -111.0 * (r + 1) - np.array([1.0, 11.0, 111.0]))
    assert int(state.pushes) == 12


def test_push_schedule_random_order_matches_a_python_simulation():
    W, rounds = 4, 6
    state = init_push_state(jnp.zeros(()), jnp.zeros(()), W)
    versions, pushes = [0] * W, 0
    key = jax.random.PRNGKey(3)
    all_st = []
    for _ in range(rounds):
        key, k = jax.random.split(key)
        order = push_order(k, W, "random")
        state, st = push_in_order(state, jnp.ones((W,)), order, _sgd_apply, lambda g: g, jnp.arange(W))
        expected = []
        for w in np.asarray(order):
            expected.append(pushes - versions[w])
            pushes += 1
            versions[w] = pushes
        np.testing.assert_array_equal(st, expected)
        all_st += expected
    assert max(all_st) > W - 1 or min(all_st[W:]) < W - 1  # a random order spreads the staleness
    edges, shares = staleness_histogram(jnp.asarray(all_st), 8, 2 * (W - 1))
    assert edges == list(range(7))
    np.testing.assert_allclose(shares, np.bincount(all_st, minlength=7) / len(all_st))


def test_push_only_resyncs_this_devices_workers():
    # workers 2 and 3 live here (local ids); 0 and 1 elsewhere: pushed but not stored
    state = init_push_state(jnp.zeros(()), jnp.zeros((2,)), 4)
    state = state.replace(snapshots=jnp.zeros((2,)))
    state, st = push_in_order(
        state, f32([1, 2, 3, 4]), jnp.array([3, 0, 2, 1]), _sgd_apply, lambda g: g, jnp.array([2, 3])
    )
    np.testing.assert_array_equal(st, [0, 1, 2, 3])
    np.testing.assert_allclose(state.snapshots, [-(4 + 1 + 3), -4.0])  # worker 2 after 3 pushes, worker 3 after 1


# ---------------------------------------------------------------------------------------------
# the training functions on the toy env


@pytest.fixture(scope="module")
def a3c_k3():
    trainer = make_trainer(K3_CONFIG, Reach(max_steps=5), iterations_per_update=1)
    return trainer, jax.jit(trainer.init), jax.jit(trainer.update)


def test_a3c_trainer_reports_the_hand_worked_staleness(a3c_k3):
    trainer, init, update = a3c_k3
    state = init(jax.random.PRNGKey(0))
    state, m = update(state)
    assert float(m["staleness_mean"]) == pytest.approx(1.0)
    assert [float(m[f"staleness_hist_{i}"]) for i in range(3)] == pytest.approx([1 / 3] * 3)
    # worker 2 pushed last: its snapshot is the global network; worker 0's is two pushes old
    g = state.push.global_[0]
    snap = state.push.snapshots
    same = jax.tree.map(lambda s, x: bool(jnp.allclose(s[2], x)), snap.actor, g.actor)
    assert all(jax.tree.leaves(same))
    assert not np.allclose(snap.actor["Dense_0"]["kernel"][0], g.actor["Dense_0"]["kernel"])
    for _ in range(2):
        state, m = update(state)
        assert float(m["staleness_mean"]) == 2.0 and float(m["staleness_max"]) == 2.0
        assert float(m["staleness_hist_2"]) == 1.0
    assert float(m["applied_gradients"]) == 3.0
    # every lane took its first step; lanes idle after an episode end
    assert 3 <= float(m["steps_taken"]) <= 12
    assert int(update._cache_size()) == 1  # no recompilation


def _one_worker_runs(rounds, chunks):
    common = dict(num_envs=1, unroll_length=8, actor_lr=1e-2, critic_lr=1e-2, batch_norm=False, **SMALL)
    out = []
    for cfg in (A2CConfig(**common), A3CConfig(**common)):
        trainer = make_trainer(cfg, Reach(max_steps=5), iterations_per_update=rounds)
        state = jax.jit(trainer.init)(jax.random.PRNGKey(7))
        for _ in range(chunks):
            state, m = jax.jit(trainer.update)(state)
        params = state.push.global_[0] if isinstance(cfg, A3CConfig) else state.params
        out.append((params, m))
    return out


def test_a3c_with_one_worker_equals_a2c_with_one_worker():
    (p2, m2), (p3, m3) = _one_worker_runs(rounds=6, chunks=2)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6), p2, p3)
    for k in ("episode_return", "critic_loss", "steps_taken", "reward"):
        np.testing.assert_allclose(m2[k], m3[k], rtol=1e-5)
    assert float(m3["staleness_mean"]) == 0.0
    assert float(m2["episodes"]) >= 2  # episodes ended inside the rounds (short buffers exercised)


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match="push_order='lifo'.*'random', 'fixed'"):
        A3CConfig(push_order="lifo").validate()
    with pytest.raises(ConfigError, match="lanes_per_worker=3 must divide num_envs=4"):
        A3CConfig(lanes_per_worker=3).validate()
    with pytest.raises(ConfigError, match=r"gamma=1.5 is out of range"):
        A2CConfig(gamma=1.5).validate()
    with pytest.raises(ConfigError, match="lr_schedule='cosine'.*'constant', 'linear'"):
        A2CConfig(lr_schedule="cosine").validate()
    with pytest.raises(ConfigError, match="bn_batch='all'.*'update', 'lane'"):
        A2CConfig(bn_batch="all").validate()
    with pytest.raises(ConfigError, match="sigma"):
        make_trainer(A2CConfig(sigma=(0.1, 0.2)), Reach())


_DEVICES_SCRIPT = """
import os, sys
sys.path.insert(0, {root!r})
import jax, numpy as np
from jaxrl_robot import parallel
from jaxrl_robot.agents.a2c import make_trainer
from tests.agents.test_a2c import K3_CONFIG, Reach
assert len(jax.devices()) == 3
ref = np.load({ref!r})
for impl in ("shard_map", "vmap"):
    os.environ["JAXRL_LANE_MAP"] = impl
    mesh = parallel.lane_mesh(3)
    assert parallel.lane_map_impl(mesh) == impl
    tr = make_trainer(K3_CONFIG, Reach(max_steps=5), mesh=mesh, iterations_per_update=1)
    s = jax.jit(tr.init)(jax.random.PRNGKey(0))
    update = jax.jit(tr.update)
    for _ in range(3):
        s, m = update(s)
    leaves = jax.tree.leaves(jax.device_get(s))
    assert len(leaves) == len(ref.files)
    for i, leaf in enumerate(leaves):
        np.testing.assert_allclose(leaf, ref[f"a{{i}}"], rtol=1e-4, atol=1e-5, err_msg=impl)
    print(impl, "ok", float(m["staleness_mean"]))
"""


def test_a3c_on_three_devices_gives_the_same_run_as_on_one(a3c_k3, tmp_path):
    """One worker per device: gathered gradients, one push order, re-sync of the local snapshots; both lane
    maps of ``jaxrl_robot.parallel`` (``shard_map``, ``vmap``), one after the other in one process."""
    _, init, update = a3c_k3
    state = init(jax.random.PRNGKey(0))
    for _ in range(3):
        state, _ = update(state)
    ref = str(tmp_path / "one_device.npz")
    np.savez(ref, **{f"a{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(jax.device_get(state)))})
    script = _DEVICES_SCRIPT.format(root=ROOT, ref=ref)
    cmd = [sys.executable, "-c", textwrap.dedent(script)]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=cpu_env(devices=3))
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().splitlines()[-2:] == ["shard_map ok 2.0", "vmap ok 2.0"]


# ---------------------------------------------------------------------------------------------
# learning


def test_a2c_learns_to_reach():
    cfg = A2CConfig(
        num_envs=16,
        unroll_length=8,
        actor_lr=3e-3,
        critic_lr=3e-3,
        sigma=(0.3,),
        actor_hidden=(64, 64),
        critic_hidden=(64, 64),
        batch_norm=False,  # as the cpu/fast presets: the batch-norm actor is tested apart
        normalize_advantages=True,
        total_steps=200_000,
    )
    env = Reach()
    trainer = make_trainer(cfg, env, iterations_per_update=10)
    train = make_train(cfg, env, iterations_per_update=10)

    @jax.jit
    def train_and_test(key):
        state, metrics = train(key)
        return run_test_episodes(jax.random.PRNGKey(99), env, trainer.policy(state), 100), metrics

    untrained = jax.jit(lambda k: run_test_episodes(jax.random.PRNGKey(99), env, trainer.policy(trainer.init(k)), 100))
    assert float(untrained(jax.random.PRNGKey(0))["success"].mean()) < 0.2
    test, metrics = train_and_test(jax.random.PRNGKey(0))
    assert metrics["success"].shape == (trainer.num_updates,)
    assert float(test["success"].mean()) >= 0.9
