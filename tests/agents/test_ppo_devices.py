"""The sharded path: the same lanes on 4 (fake CPU) devices train like on one device.

Both lane-map implementations of ``jaxrl_robot.parallel`` (``shard_map`` and ``vmap``) are run for the
feed-forward policy; the default one for the recurrent policy (its start-state table sums over every
device's lanes).
"""

import subprocess
import sys
import textwrap

from tests.subproc import ROOT, cpu_env

SCRIPT = textwrap.dedent(
    """
    import os
    import jax, numpy as np
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.ppo import make_trainer
    from tests.agents.test_ppo import TOY, Line

    assert len(jax.devices()) == 4, jax.devices()
    cfg = TOY.replace(num_envs=8, minibatch_size=32, schedule=(), objective="clip", reset_group=2)
    probe = np.random.default_rng(0).uniform(-1, 1, (16, 2)).astype(np.float32)
    out = {}
    for name, n, impl in ((1, 1, ""), ("shard_map", 4, "shard_map"), ("vmap", 4, "vmap")):
        os.environ["JAXRL_LANE_MAP"] = impl
        mesh = parallel.lane_mesh(n)
        assert parallel.lane_map_impl(mesh) == (impl or "shard_map")
        trainer = make_trainer(cfg, Line(), mesh=mesh, iterations_per_update=2)
        state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
        if n == 1:
            a0 = np.asarray(trainer.policy(state)(probe))
        update = jax.jit(trainer.update)
        state, metrics = update(state)
        state, metrics = update(state)  # the state's shardings round-trip: no second compilation
        assert update._cache_size() == 1
        if impl == "vmap":  # gradients and statistics all-reduced; nothing (the pool's ranking) gathered
            hlo = update.lower(state).compile().as_text()
            assert "all-reduce" in hlo and "all-gather" not in hlo and "all-to-all" not in hlo
        assert len(state.env_state.obs.sharding.device_set) == n
        assert n == 1 or state.env_state.obs.sharding.spec[0] == parallel.LANES
        out[name] = (jax.device_get(state), jax.device_get(metrics), np.asarray(trainer.policy(state)(probe)))
    s1, m1, a1 = out[1]
    for name in ("shard_map", "vmap"):
        s4, m4, a4 = out[name]
        # same lanes, same randomness: identical trajectories and statistics
        np.testing.assert_allclose(s1.env_state.obs, s4.env_state.obs, atol=1e-5, err_msg=name)
        np.testing.assert_allclose(s1.obs_stats.mean, s4.obs_stats.mean, atol=1e-6, err_msg=name)
        for k in ("critic_loss", "actor_loss", "kl", "reward", "episodes"):
            np.testing.assert_allclose(m1[k], m4[k], rtol=1e-4, atol=1e-6, err_msg=f"{name} {k}")
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-5), s1.critic_params, s4.critic_params)
        np.testing.assert_allclose(a1, a4, atol=1e-4, err_msg=name)
    # brax's update (advantage_segment): segments drawn per device, so the devices agree where every
    # mini-batch is the whole batch (4 segments of 4 steps from each device's 2 lanes)
    seg = cfg.replace(advantage_segment=4, minibatch_size=64, actor_updates=2, critic_updates=2)
    got = []
    for n in (1, 4):
        trainer = make_trainer(seg, Line(), mesh=parallel.lane_mesh(n))
        state, metrics = jax.jit(trainer.update)(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
        got.append((jax.device_get(state.critic_params), jax.device_get(metrics)["critic_loss"]))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5), got[0][0], got[1][0])
    np.testing.assert_allclose(got[0][1], got[1][1], rtol=1e-4)
    # and training did move the policy, so the comparison is not between two initial states
    assert np.max(np.abs(a1 - a0)) > 1e-3
    print("OK mlp")
    """
)


RECURRENT = textwrap.dedent(
    """
    import jax, jax.numpy as jnp, numpy as np
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.ppo import make_trainer
    from tests.agents.test_ppo import TOY, Line

    class Clock(Line):
        # Line with a reference step: episodes start at a random k in [0, 8) and count up.
        max_steps = 8

        def reset(self, rng, params=None):
            state = super().reset(rng, params)
            k = jax.random.randint(jax.random.fold_in(rng, 1), (), 0, self.max_steps)
            return state.replace(info={**state.info, "k": k})

        def step(self, state, action):
            nxt = super().step(state, action)
            return nxt.replace(info={**nxt.info, "k": jnp.minimum(state.info["k"] + 1, self.max_steps)})

    cfg = TOY.replace(num_envs=8, unroll_length=8, minibatch_size=32, schedule=(), objective="clip", reset_group=2,
                      policy="lstm", seq_length=4, lstm_size=8, batch_norm=False, lstm_start="table")
    out = {}
    for name, n in ((1, 1), ("vmap", 4)):  # the lane map several devices use by default
        trainer = make_trainer(cfg, Clock(), mesh=parallel.lane_mesh(n), iterations_per_update=2)
        state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
        update = jax.jit(trainer.update)
        for _ in range(2):
            state, metrics = update(state)
        out[name] = jax.device_get((state, metrics))
    s1, m1 = out[1]
    assert np.abs(s1.start_table["actor"][1][1:]).max() > 1e-3  # the table was filled
    for name in ("vmap",):
        s4, m4 = out[name]
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-5), s1.start_table, s4.start_table)
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-5), s1.memory, s4.memory)
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-5), s1.actor_params, s4.actor_params)
        for k in ("critic_loss", "actor_loss", "kl", "reward"):
            np.testing.assert_allclose(m1[k], m4[k], rtol=1e-4, atol=1e-6, err_msg=f"{name} {k}")
    print("OK lstm")
    """
)


def test_four_fake_devices_match_one_device():
    """Both scripts in one process (one start-up): the recurrent policy on the default lane map."""
    script = SCRIPT + '\nos.environ.pop("JAXRL_LANE_MAP")\n' + RECURRENT
    proc = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, env=cpu_env(devices=4), capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "OK mlp" in proc.stdout and "OK lstm" in proc.stdout
