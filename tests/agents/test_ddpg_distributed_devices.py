"""Distributed DDPG on 4 (fake CPU) devices equals the same workers on one device.

4 synchronous workers (4 vmapped on one device, or one per device) and 4 collecting workers with
their own noise scales, whole episodes with HER (``future``), prioritised replay and observation
normalisation on the toy goal env, every lane acting uniformly at random for the first 3 cycles
(``random_start`` until ``learning_starts`` 360 rows are stored); each device count with its default lane map of
``jaxrl_robot.parallel`` (``shard_map`` on one device, ``vmap`` on several; both implementations
run the single learner in ``test_ddpg_devices.py``, one config each).
The shared replay (rows, slots, priorities, β), the global networks, the targets, every
collector's copy and the metrics must agree up to float summation order; the gradient mean of
one worker per device is the mean over 4 workers on one.
"""

import textwrap

from tests.agents.test_ddpg_devices import run_on_four_devices

SCRIPT = textwrap.dedent(
    """
    import jax, numpy as np
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.ddpg import make_trainer
    from tests.agents.test_ddpg import _tiny
    from tests.agents.test_ddpg_devices import assert_runs_agree
    from tests.replay.toy_goal_env import ToyGoalEnv

    assert len(jax.devices()) == 4, jax.devices()
    UPDATES_AT_360 = 2  # the third cycle's: its rows reach learning_starts before its updates
    env = ToyGoalEnv(max_steps=5, step_size=0.05)
    cfg = _tiny(episode_length=5, num_envs=4, cycles_per_epoch=3, updates_per_cycle=2, her="future", her_k=2,
                per=True, normalize_obs=True, noise_scale=(0.3,), distributed=True, sync_workers=4,
                collect_workers=4, collect_lanes=1, fetch_every=2, collect_noise_factors=(0.5, 1.0, 1.5, 2.0),
                random_start=True, learning_starts=360)

    out = {}
    for name, n in ((1, 1), ("vmap", 4)):
        trainer = make_trainer(cfg, env, mesh=parallel.lane_mesh(n))
        update = jax.jit(trainer.update)
        first, _ = update(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
        # 3 cycles of 8 lanes x 5 steps x (1 + her_k) rows, all acted uniformly in [-1, 1] (a policy near
        # 0 with noise sigma 0.15-0.6 would put about a fifth of them beyond 0.5, not half), no update yet
        a = np.asarray(first.replay.data.action[:360])
        assert int(first.replay.size) == 360 and int(first.updates) == UPDATES_AT_360, (name, int(first.updates))
        assert np.abs(a).max() <= 1 and abs(a.mean()) < 0.1 and 0.4 < np.mean(np.abs(a) > 0.5) < 0.6, name
        state, metrics = update(first)
        assert update._cache_size() == 1, name
        assert len(state.collectors.actor_params["params"]["Dense_0"]["kernel"].sharding.device_set) == n
        out[name] = (jax.device_get(state), jax.device_get(metrics))
    s1 = out[1][0]
    assert int(s1.updates) == UPDATES_AT_360 + 3 * 2 and int(s1.replay.size) > 0
    assert len(np.unique(np.asarray(s1.replay.tree.leaf_values[: int(s1.replay.size)]))) > 10
    assert parallel.lane_map_impl(parallel.lane_mesh(4)) == "vmap"
    assert_runs_agree(out[1], out["vmap"], "vmap", per=True)
    jax.tree.map(lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5, err_msg="collectors"),
                 out[1][0].collectors, out["vmap"][0].collectors)
    for field, value in (("sync_workers", 2), ("collect_workers", 2)):
        try:
            make_trainer(cfg.replace(collect_noise_factors=(), **{field: value}), env, mesh=parallel.lane_mesh(4))
        except ValueError as e:
            assert f"{field}=2 must be a multiple of the number of devices (4)" in str(e), e
        else:
            raise AssertionError(f"{field}=2 on 4 devices did not raise")
    print("OK")
    """
)


def test_four_fake_devices_match_one_device():
    run_on_four_devices(SCRIPT)
