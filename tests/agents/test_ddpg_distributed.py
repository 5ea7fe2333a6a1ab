"""Distributed DDPG (thesis §4.2): the workers' mean gradient by hand, the sampling rule over the whole
memory (chi-square), collecting workers' copies exactly ``fetch_every`` iterations stale and their own
priorities, exact resume, config errors and presets."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from scipy import stats

from envs_mjx.config import ConfigError
from jaxrl_robot import parallel
from jaxrl_robot.agents.ddpg import (
    DDPGActor,
    DDPGConfig,
    DDPGCritic,
    DDPGState,
    make_distributed_trainer,
    make_learner,
    make_trainer,
    worker_shards,
)
from jaxrl_robot.agents.off_policy.learner import sample
from jaxrl_robot.checkpoint import Checkpointer
from jaxrl_robot.networks import init_running_stats
from jaxrl_robot.replay import Transition, make_prioritized_replay
from tests.agents.test_ddpg import _linear_params, _tiny
from tests.replay.toy_goal_env import ToyGoalEnv
from train.presets import ddpg_preset

EPS, ALPHA = 1e-6, 0.6


def _memory(raw_priorities, capacity=16, batch=3, obs_size=2, seed=0):
    """A prioritised replay holding one row per raw priority (``p_i``, stored as ``(p_i + ε)^α``)."""
    n = len(raw_priorities)
    replay = make_prioritized_replay(capacity, batch, ALPHA, 0.4, 0.001, priority_eps=EPS)
    k = jax.random.split(jax.random.PRNGKey(seed), 4)
    rows = Transition(
        obs=jax.random.normal(k[0], (n, obs_size)),
        action=jax.random.uniform(k[1], (n, 1), minval=-1.0, maxval=1.0),
        reward=jax.random.normal(k[2], (n,)),
        next_obs=jax.random.normal(k[3], (n, obs_size)),
        termination=(jnp.arange(n) % 4 == 3).astype(jnp.float32),
    )
    example = jax.tree.map(lambda x: x[0], rows)
    return replay, replay.add(replay.init(example), rows, priorities=jnp.asarray(raw_priorities, jnp.float32))


def test_workers_mean_gradient_equals_the_gradient_of_their_concatenated_batches_by_hand():
    """One update with 4 synchronous workers of 3 rows each on linear nets, SGD so that the step shows the
    gradient: the critic moves by the gradient of ``mean w (Q − y)²`` over the 12 concatenated rows (each
    row with its worker's importance weight, Eq. 3.10), the actor by ``−mean ∂Q/∂a ∂μ/∂θ`` over them with
    the updated critic (Algorithm 4), targets softly; the gathered priorities are written back."""
    m, n, lr, gamma, tau = 4, 3, 0.1, 0.9, 0.5
    replay, buf = _memory([0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.0, 1.5, 2.0, 3.0], batch=n)
    actor, critic = DDPGActor(action_size=1, hidden=(), output="tanh"), DDPGCritic(hidden=())
    config = DDPGConfig(per=True, batch_size=n, gamma=gamma, tau=tau, alpha=ALPHA, priority_eps=EPS, actor_hidden=(),
                        critic_hidden=(), distributed=True, sync_workers=m, num_envs=m)  # fmt: skip
    learner = make_learner(config, actor, critic, replay, optax.sgd(lr), optax.sgd(lr), lambda _, x: x, n)
    a_p, c_p = _linear_params([0.3, -0.2], 0.05), _linear_params([0.5, -1.0, 2.0], 0.1)
    ta_p, tc_p = _linear_params([0.1, 0.4], -0.1), _linear_params([0.2, 0.3, 1.0], 0.0)
    state = DDPGState(actor_params=a_p, critic_params=c_p, target_actor_params=ta_p, target_critic_params=tc_p,
                      actor_opt=optax.sgd(lr).init(a_p), critic_opt=optax.sgd(lr).init(c_p), replay=buf,
                      env_state=None, noise_state=None, obs_stats=init_running_stats(2), key=None,
                      iteration=jnp.zeros((), jnp.int32), updates=jnp.zeros((), jnp.int32), demos=(),
                      imitation_opt=())  # fmt: skip
    key = jax.random.PRNGKey(7)

    def update(state):
        workers = worker_shards(parallel.global_lane_ids(m))
        new, sums, _ = learner.learn(state, key, 1, workers)
        return new, sums, sample(replay, workers, jax.random.split(key, 1)[0], state.replay)

    same = parallel.P()
    new, sums, smp = jax.jit(parallel.shard_lanes(update, parallel.lane_mesh(1), (same,), same))(state)
    idx, w = np.asarray(smp.indices), np.asarray(smp.weights, np.float64)
    assert idx.shape == (m, n) and len({tuple(r) for r in idx}) > 1  # each worker its own batch
    np.testing.assert_allclose(w.max(axis=1), 1.0, rtol=1e-6)  # normalised within each worker's batch
    data = jax.tree.map(lambda x: np.asarray(x, np.float64)[idx.reshape(-1)], buf.data)
    w = w.reshape(-1)

    def lin(p):
        d = p["params"]["Dense_0"]
        return np.asarray(d["kernel"], np.float64)[:, 0], float(d["bias"][0])

    (v, c), (W, b), (tv, tc), (tW, tb) = lin(a_p), lin(c_p), lin(ta_p), lin(tc_p)
    next_a = np.tanh(data.next_obs @ tv + tc)
    y = data.reward + gamma * (1 - data.termination) * (np.c_[data.next_obs, next_a] @ tW + tb)
    x = np.c_[data.obs, data.action]
    delta = y - (x @ W + b)
    g_W = np.mean(-2 * w[:, None] * delta[:, None] * x, axis=0)  # the concatenated 12 rows
    g_b = np.mean(-2 * w * delta)
    W1, b1 = W - lr * g_W, b - lr * g_b
    np.testing.assert_allclose(lin(new.critic_params)[0], W1, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(lin(new.critic_params)[1], b1, rtol=1e-5, atol=1e-7)
    one = np.mean(-2 * w[:n, None] * delta[:n, None] * x[:n], axis=0)  # worker 0 alone: a different step
    assert np.abs(one - g_W).max() > 1e-3
    np.testing.assert_allclose(float(sums["critic_loss"]), np.mean(w * delta**2), rtol=1e-5)
    mu = np.tanh(data.obs @ v + c)
    dmu = W1[2] * (1 - mu**2)  # ∂Q/∂a of the updated critic times ∂μ/∂z
    v1, c1 = v + lr * np.mean(dmu[:, None] * data.obs, axis=0), c + lr * np.mean(dmu)
    np.testing.assert_allclose(lin(new.actor_params)[0], v1, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(lin(new.actor_params)[1], c1, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(lin(new.target_critic_params)[0], tau * W1 + (1 - tau) * tW, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(lin(new.target_actor_params)[0], tau * v1 + (1 - tau) * tv, rtol=1e-5, atol=1e-7)
    last = dict(zip(idx.reshape(-1).tolist(), np.abs(delta), strict=True))  # repeats: the last worker's wins
    leaves = np.asarray(new.replay.tree.leaf_values)
    for slot, err in last.items():
        np.testing.assert_allclose(leaves[slot], (err + EPS) ** ALPHA, rtol=1e-5)
    assert int(new.updates) == 1 and abs(float(new.replay.beta) - 0.401) < 1e-6  # β anneals once per update


def test_workers_draws_follow_p_alpha_over_the_whole_memory_chi_square():
    """4 workers × 8 stratified draws × 2000 updates from 10 stored rows of known priorities: the counts
    over all workers (and of each worker) agree with ``P(i) = p_i^α / Σ_k p_k^α`` (Eq. 3.9) by a
    chi-square test; uniform sampling is rejected.  Stratified draws vary less than multinomial ones, so
    the test errs towards passing a right rule, never towards passing a wrong one at this sample size."""
    p = np.array([0.05, 0.1, 0.2, 0.3, 0.5, 0.8, 1.0, 1.5, 2.0, 3.0])
    replay, buf = _memory(p, batch=8)
    workers = worker_shards(jnp.arange(4))
    draws = jax.jit(jax.vmap(lambda k: sample(replay, workers, k, buf).indices))(
        jax.random.split(jax.random.PRNGKey(3), 2000)
    )  # [2000, 4, 8]
    draws = np.asarray(draws)
    assert draws.max() < len(p)  # never an empty slot of the 16
    prob = (p + EPS) ** ALPHA / np.sum((p + EPS) ** ALPHA)
    counts = np.bincount(draws.reshape(-1), minlength=len(p))
    assert stats.chisquare(counts, counts.sum() * prob).pvalue > 1e-3
    for w in range(4):
        c = np.bincount(draws[:, w].reshape(-1), minlength=len(p))
        assert stats.chisquare(c, c.sum() * prob).pvalue > 1e-3, w
    assert stats.chisquare(counts, np.full(len(p), counts.sum() / len(p))).pvalue < 1e-10
    assert not np.array_equal(draws[:, 0], draws[:, 1])  # the workers' keys differ


F, C = 3, 2
STEPS = _tiny(schedule="steps", total_steps=4 * 12, num_envs=2, unroll_length=1, updates_per_iteration=1,
              episode_length=50, batch_size=4, learning_starts=8, buffer_size=500, per=True, noise_scale=(0.0,),
              distributed=True, sync_workers=2, collect_workers=C, collect_lanes=1, fetch_every=F)  # fmt: skip


@pytest.fixture(scope="module")
def steps_trainer():
    trainer = make_trainer(STEPS, ToyGoalEnv(max_steps=50, action_scale=0.05), iterations_per_update=1)
    return trainer, jax.jit(trainer.init), jax.jit(trainer.update)


def _worker(tree, c):
    """Worker ``c``'s slice of ``[C, ...]`` leaves."""
    return jax.tree.map(lambda x: x[c], tree)


def _same(a, b):
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def test_collecting_workers_act_with_copies_exactly_fetch_every_iterations_stale(steps_trainer):
    """F = 3, collectors fetch at t ≡ ⌊cF/C⌋ = 0, 1 (mod 3): the copy a collector acts with in iteration t is
    the global parameters at the start of its last fetch iteration, and when it is replaced it is exactly
    the parameters of F iterations before; the stored actions (noise 0) are its copy's μ(s); the metrics
    report the staleness t − fetch."""
    trainer, init, update = steps_trainer
    actor = DDPGActor(action_size=3, hidden=(8,))
    state = init(jax.random.PRNGKey(0))
    history, metrics = [jax.device_get(state)], []
    for _ in range(9):
        state, m = update(state)
        history.append(jax.device_get(state))
        metrics.append(jax.device_get(m))
    assert int(history[-1].updates) == 8  # learning from iteration 1 on (8 rows stored)
    rows_per_it = 4  # 2 synchronous lanes, then 2 collecting lanes

    def age(t, c):  # iterations since collector c's copy was fetched (at 0, before its first fetch)
        phase = (c * F) // C
        return (t - phase) % F if t >= phase else t

    for t in range(9):
        col = history[t + 1].collectors
        for c in range(C):
            fetched = t - age(t, c)
            assert int(col.fetched[c]) == fetched, (t, c)
            copy = _worker((col.actor_params, col.critic_params), c)
            assert _same(copy, (history[fetched].actor_params, history[fetched].critic_params)), (t, c)
            if age(t, c) == 0 and t >= F + (c * F) // C:  # a fetch: the copy it replaces is F iterations old
                prev = _worker(history[t].collectors.actor_params, c)
                assert _same(prev, history[t - F].actor_params) and not _same(prev, history[t].actor_params)
            slot = t * rows_per_it + 2 + c
            obs = history[t + 1].replay.data.obs[slot]
            np.testing.assert_allclose(history[t + 1].replay.data.action[slot], actor.apply(copy[0], obs), atol=1e-6)
        sync_obs = history[t + 1].replay.data.obs[t * rows_per_it]
        np.testing.assert_allclose(history[t + 1].replay.data.action[t * rows_per_it],
                                   actor.apply(history[t].actor_params, sync_obs), atol=1e-6)
        ages = [age(t, c) for c in range(C)]
        np.testing.assert_allclose(metrics[t]["staleness_mean"], np.mean(ages))
        assert metrics[t]["staleness_max"] == max(ages)
    assert max(m["staleness_max"] for m in metrics) == F - 1


def test_workers_store_priorities_from_their_own_networks(steps_trainer):
    """Iteration 0 with collector 1's copy replaced (it fetches first at t = 1): its row enters the replay
    with ``(|δ| + ε)^α`` from that copy, ``δ = r + γ(1 − d)Q(s', μ(s')) − Q(s, a)`` (Algorithm 6, line 9),
    and with its copy's action; the other rows with the global networks' δ."""
    trainer, init, update = steps_trainer
    actor, critic = DDPGActor(action_size=3, hidden=(8,)), DDPGCritic(hidden=(8,))
    state = init(jax.random.PRNGKey(0))
    other = init(jax.random.PRNGKey(5))
    col = state.collectors
    put = lambda mine, new: jax.tree.map(lambda x, y: x.at[1].set(y), mine, new)  # noqa: E731
    state = state.replace(collectors=col.replace(actor_params=put(col.actor_params, other.actor_params),
                                                 critic_params=put(col.critic_params, other.critic_params)))
    state, _ = update(state)
    assert int(state.updates) == 0  # 4 rows < learning_starts: the priorities are the stored ones
    data = jax.device_get(state.replay.data)
    leaves = np.asarray(state.replay.tree.leaf_values)
    for slot, nets in ((0, state), (1, state), (2, state), (3, other)):
        a_p, c_p = nets.actor_params, nets.critic_params
        q = critic.apply(c_p, data.obs[slot], data.action[slot])
        next_q = critic.apply(c_p, data.next_obs[slot], actor.apply(a_p, data.next_obs[slot]))
        delta = data.reward[slot] + STEPS.gamma * (1 - data.termination[slot]) * next_q - q
        np.testing.assert_allclose(leaves[slot], (abs(float(delta)) + STEPS.priority_eps) ** ALPHA, rtol=1e-4)
        np.testing.assert_allclose(data.action[slot], actor.apply(a_p, data.obs[slot]), atol=1e-6)
    assert not np.allclose(data.action[3], actor.apply(state.actor_params, data.obs[3]), atol=1e-3)


def test_resume_from_a_checkpoint_equals_an_uninterrupted_run(steps_trainer, tmp_path):
    """The replay, the sum-tree, every collector's copy, lanes and noise are in the state: 2 + 2 chunks with
    a checkpoint between them end bit for bit where 4 chunks end."""
    trainer, init, update = steps_trainer
    state = init(jax.random.PRNGKey(2))
    for _ in range(2):
        state, _ = update(state)
    ckpt = Checkpointer(str(tmp_path))
    ckpt.save(2, state, {"chunk": 2})
    ckpt.close()
    straight = state
    for _ in range(2):
        straight, _ = update(straight)
    resumed, _ = Checkpointer(str(tmp_path)).restore(2, init(jax.random.PRNGKey(9)))
    for _ in range(2):
        resumed, _ = update(resumed)
    assert int(resumed.updates) > 0 and _same(jax.device_get(resumed), jax.device_get(straight))


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match=r"num_envs=4 must be a multiple of sync_workers \(3\)"):
        _tiny(num_envs=4, distributed=True, sync_workers=3).validate()
    with pytest.raises(ConfigError, match=r"fetch_every=0 is out of range; allowed \[1, inf\]"):
        _tiny(distributed=True, sync_workers=2, fetch_every=0).validate()
    with pytest.raises(ConfigError, match=r"collect_workers=-1 is out of range; allowed \[0, inf\]"):
        _tiny(distributed=True, sync_workers=2, collect_workers=-1).validate()
    with pytest.raises(ConfigError, match=r"collect_noise_factors=\(1.0, 2.0, 3.0\) must have 0, 1 or collect_workers"):
        _tiny(distributed=True, sync_workers=2, collect_workers=2, collect_noise_factors=(1.0, 2.0, 3.0)).validate()
    _tiny(num_envs=4, sync_workers=3).validate()  # the worker fields matter only when distributed
    with pytest.raises(ValueError, match="needs distributed=True"):
        make_distributed_trainer(_tiny(), ToyGoalEnv())
    with pytest.raises(ConfigError, match="buffer_size=60 is out of range; one iteration stores up to 80"):
        make_trainer(_tiny(episode_length=20, buffer_size=60, distributed=True, sync_workers=2, collect_lanes=1,
                           collect_workers=2), ToyGoalEnv())  # 2 + 2 lanes of 20 steps


def test_presets_thesis_and_accelerator_settings():
    """thesis (§4.2.2): 4 + 4 workers, 4 × 32 = 128 transitions per update, memory 200 000, a fetch every 5
    steps, the single learner's updates; cpu and fast validate for the tracking envs and arm7."""
    for env, length in (("scara", 314), ("unicycle", 314)):
        single = ddpg_preset("thesis", env, length)
        cfg = ddpg_preset("thesis", env, length, distributed=True).validate()
        assert (cfg.sync_workers, cfg.collect_workers, cfg.batch_size, cfg.buffer_size) == (4, 4, 32, 200_000)
        assert cfg.sync_workers * cfg.batch_size == 128 and cfg.fetch_every == 5 and cfg.per
        assert cfg.num_envs == 4 and cfg.collect_lanes == 1 and cfg.unroll_length == 1  # one env per worker
        assert cfg.iterations == single.iterations and cfg.gamma == single.gamma == 0.9  # Table 3.3 otherwise
    for env, length in (("scara", 314), ("unicycle", 314), ("arm7", 100)):
        for name in ("cpu", "fast"):
            cfg = ddpg_preset(name, env, length, "sparse", distributed=True).validate()
            assert cfg.distributed and cfg.num_envs % cfg.sync_workers == 0
            assert cfg.iterations == ddpg_preset(name, env, length, "sparse").iterations


@pytest.mark.parametrize("schedule", ["steps", "episodes"])
def test_one_collection_of_both_kinds_of_lane_equals_two_separate_ones(schedule):
    """Synchronous and collecting lanes step as one batch (``collect(..., split=n)``): the rows, the
    lanes' states and noise, and the episode sums of each part equal those of collecting each part
    alone with the same key (every lane's randomness is keyed by its global id)."""
    from jaxrl_robot.agents.ddpg import make_member
    from jaxrl_robot.agents.off_policy import trainer

    config = _tiny(schedule=schedule, episode_length=3, unroll_length=4, noise_scale=(0.3,), num_envs=6)
    s = trainer.setup(config, ToyGoalEnv(max_steps=3, action_scale=0.3), make_member)
    sizes = (s.run.obs_size, s.run.action_size)
    params = s.member.init(jax.random.PRNGKey(1), jax.random.PRNGKey(0), *sizes)["actor_params"]
    stats = init_running_stats(s.run.obs_size)
    ids, n = jnp.arange(6), 2
    env_state, noise_state = s.acting.reset(jax.random.split(jax.random.PRNGKey(2), 6))

    def collect(lanes, split=None):
        policy = s.acting.policy(ids[lanes], params, stats, None)
        part = jax.tree.map(lambda x: x[lanes], (env_state, noise_state))
        return jax.jit(lambda *a: s.acting.collect(jax.random.PRNGKey(3), ids[lanes], policy, *a, split=split))(*part)

    both = collect(slice(None), split=n)
    for i, lanes in enumerate((slice(0, n), slice(n, None))):
        alone = collect(lanes)
        part = jax.tree.map(lambda x, sl=lanes: x[sl], (both.env_state, both.noise_state, both.rows, both.mask))
        assert _same(part, (alone.env_state, alone.noise_state, alone.rows, alone.mask))
        sums = {k: float(v[i]) for k, v in both.sums.items()}
        assert sums == {k: float(v) for k, v in alone.sums.items()}
    assert float(both.sums["episodes"][0] + both.sums["episodes"][1]) > 0  # episodes ended in the window
