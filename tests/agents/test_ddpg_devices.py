"""The sharded path: DDPG's lanes on 4 (fake CPU) devices train like the same lanes on one device.

The single learner (``SCRIPT``): two tiny configs on the toy goal env: whole episodes with HER (``future``),
prioritised replay and observation normalisation, on the default lane map of several devices (``vmap``);
continuous steps with OU noise and uniform replay, on the other lane map of ``jaxrl_robot.parallel``
(``shard_map``). The replay memory (rows, ring position, priorities, β), the networks, the targets and the
metrics must agree, and a checkpoint of the 4-device state resumes exactly.

Distributed DDPG (``DISTRIBUTED_SCRIPT``): 4 synchronous workers (4 vmapped on one device, or one per device)
and 4 collecting workers with their own noise scales, whole episodes with HER (``future``), prioritised replay
and observation normalisation on the toy goal env, every lane acting uniformly at random for the first 3
cycles (``random_start`` until ``learning_starts`` 360 rows are stored); each device count with its default
lane map (``shard_map`` on one device, ``vmap`` on several; both implementations run the single learner,
one config each). The shared replay (rows, slots, priorities, β), the global networks, the targets, every
collector's copy and the metrics must agree up to float summation order; the gradient mean of one worker
per device is the mean over 4 workers on one.

Both scripts run in one subprocess with 4 fake CPU devices (one start of Python and JAX), each reported apart.
"""

import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from tests.subproc import ROOT, cpu_env

SCRIPT = textwrap.dedent(
    """
    import os, tempfile
    import jax, numpy as np
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.ddpg import make_trainer
    from jaxrl_robot.checkpoint import Checkpointer
    from tests.agents.test_ddpg import _tiny
    from tests.agents.test_ddpg_devices import assert_runs_agree
    from tests.replay.toy_goal_env import ToyGoalEnv

    assert len(jax.devices()) == 4, jax.devices()
    env = ToyGoalEnv(max_steps=5, action_scale=0.05)
    configs = {
        "her_per": (_tiny(episode_length=5, num_envs=4, cycles_per_epoch=2, updates_per_cycle=3, her="future",
                          her_k=2, per=True, normalize_obs=True, noise_scale=(0.3,)), None),
        "steps_ou": (_tiny(schedule="steps", total_steps=128, num_envs=4, unroll_length=4, episode_length=6,
                           updates_per_iteration=2, noise="ou", noise_scale=(0.3,)), 2),
    }

    for cname, (cfg, per_update) in configs.items():
        out = {}
        impls = ((1, 1, ""), ("vmap", 4, "vmap")) if cfg.per else ((1, 1, ""), ("shard_map", 4, "shard_map"))
        for name, n, impl in impls:
            os.environ["JAXRL_LANE_MAP"] = impl
            mesh = parallel.lane_mesh(n)
            trainer = make_trainer(cfg, env, mesh=mesh, iterations_per_update=per_update)
            state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
            if n == 1:
                init = jax.device_get(state)
            update = jax.jit(trainer.update)
            first, _ = update(state)
            state, metrics = update(first)  # the state's shardings round-trip: no second compilation
            assert update._cache_size() == 1, (cname, name)
            assert len(state.env_state.obs.sharding.device_set) == n
            assert n == 1 or state.env_state.obs.sharding.spec[0] == parallel.LANES
            if n == 4:  # a checkpoint of the sharded state continues exactly
                with tempfile.TemporaryDirectory() as d:
                    ckpt = Checkpointer(d)
                    ckpt.save(1, first, {"chunk": 1})
                    ckpt.close()
                    restored, _ = Checkpointer(d).restore(1, jax.jit(trainer.init)(jax.random.PRNGKey(1)))
                resumed, _ = update(restored)
                jax.tree.map(np.testing.assert_array_equal, jax.device_get(resumed), jax.device_get(state))
            out[name] = (jax.device_get(state), jax.device_get(metrics))
        s1 = out[1][0]
        size = int(s1.replay.size)
        assert size > 0
        for name in ("vmap",) if cfg.per else ("shard_map",):
            assert_runs_agree(out[1], out[name], f"{cname} {name}", cfg.per)
        # training moved the networks, so the comparison is not between two initial states
        for a, b in ((init.actor_params, s1.actor_params), (init.critic_params, s1.critic_params)):
            moved = max(float(np.max(np.abs(x - y))) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))
            assert moved > 1e-4, (cname, moved)
        if cfg.per:  # sampled rows were re-prioritised, so the compared priorities are not all the initial one
            assert len(np.unique(np.asarray(s1.replay.tree.leaf_values[:size]))) > 1
    try:
        make_trainer(configs["steps_ou"][0].replace(num_envs=6), env, mesh=parallel.lane_mesh(4))
    except ValueError as e:
        assert "num_envs=6 must be a multiple of the number of devices (4)" in str(e), e
    else:
        raise AssertionError("6 lanes on 4 devices did not raise")
    print("OK")
    """
)


DISTRIBUTED_SCRIPT = textwrap.dedent(
    """
    import jax, numpy as np
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.ddpg import make_trainer
    from tests.agents.test_ddpg import _tiny
    from tests.agents.test_ddpg_devices import assert_runs_agree
    from tests.replay.toy_goal_env import ToyGoalEnv

    assert len(jax.devices()) == 4, jax.devices()
    UPDATES_AT_360 = 2  # the third cycle's: its rows reach learning_starts before its updates
    env = ToyGoalEnv(max_steps=5, action_scale=0.05)
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
    # the run's lane map: vmap for an env that does not say it steps no MJX physics (the toy env), shard_map
    # for one that does (arm7 in kinematic mode), on 4 devices; every shard_lanes of the run takes it
    import envs_mjx
    from jaxrl_robot.agents import core
    assert core.setup(cfg, env, parallel.lane_mesh(4)).lane_map == "vmap"
    arm = envs_mjx.make("arm7", mode="kinematic")
    assert core.setup(cfg.replace(episode_length=0), arm, parallel.lane_mesh(4)).lane_map == "shard_map"
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


def _close(a, b, what):
    jax.tree.map(lambda x, y: np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5, err_msg=what), a, b)


def assert_runs_agree(run1, run4, what: str, per: bool) -> None:
    """Two runs' ``(state, metrics)`` (host copies) agree up to float summation order: the same replay
    contents in the same slots (priorities and β with ``per``), networks, targets, observation
    statistics, lanes, update count and metrics."""
    (s1, m1), (s4, m4) = run1, run4
    assert int(s4.replay.size) == int(s1.replay.size) > 0, what
    assert int(s4.replay.insert_pos) == int(s1.replay.insert_pos), what
    _close(s1.replay.data, s4.replay.data, what + " replay")
    if per:
        _close(s1.replay.tree, s4.replay.tree, what + " priorities")
        _close(s1.replay.scalars, s4.replay.scalars, what + " max priority, beta")
    _close((s1.actor_params, s1.critic_params), (s4.actor_params, s4.critic_params), what + " params")
    _close((s1.target_actor_params, s1.target_critic_params),
           (s4.target_actor_params, s4.target_critic_params), what + " targets")  # fmt: skip
    _close(s1.obs_stats, s4.obs_stats, what + " obs stats")
    _close((s1.env_state.obs, s1.noise_state), (s4.env_state.obs, s4.noise_state), what + " lanes")
    assert int(s4.updates) == int(s1.updates) > 0, what
    assert sorted(m1) == sorted(m4), what
    for k in m1:
        np.testing.assert_allclose(m1[k], m4[k], rtol=1e-4, atol=1e-6, err_msg=f"{what} {k}")


RUNNER = textwrap.dedent(
    """
    import os, sys, traceback
    for name, script in zip(sys.argv[1::2], sys.argv[2::2]):
        print(f"== {name}", flush=True)
        os.environ.pop("JAXRL_LANE_MAP", None)  # each script starts from the default lane map
        try:
            exec(compile(script, name, "exec"), {"__name__": name})
        except BaseException:
            traceback.print_exc(file=sys.stdout)
            print(f"{name}: FAILED", flush=True)
        else:
            print(f"{name}: PASSED", flush=True)
    """
)


def run_on_four_devices(scripts: dict[str, str]) -> dict[str, str]:
    """Run each of ``scripts`` (name -> code) in turn in one Python subprocess on 4 fake CPU devices; its
    verdict ``"PASSED"`` (it printed OK last and raised nothing) or what tells why not (its output, with the
    traceback, or the process's end)."""
    argv = [x for name, code in scripts.items() for x in (name, code)]
    proc = subprocess.run([sys.executable, "-c", RUNNER, *argv], cwd=ROOT, env=cpu_env(devices=4),
                          capture_output=True, text=True, timeout=900)  # fmt: skip
    verdicts = {}
    for name in scripts:
        _, found, rest = proc.stdout.partition(f"== {name}\n")
        lines = rest.split("\n== ")[0].splitlines()
        passed = found and lines[-2:] == ["OK", f"{name}: PASSED"]
        if passed:
            verdicts[name] = "PASSED"
        elif lines and lines[-1] == f"{name}: FAILED":  # its traceback
            verdicts[name] = "\n".join(lines)[-4000:]
        else:  # no OK before its verdict, or no verdict: the process ended in it or before it
            verdicts[name] = ("\n".join(lines)[-3000:] if found else f"{name} did not run") + (
                f"\nexit code {proc.returncode}\n{proc.stderr[-3000:]}")
    return verdicts


@pytest.fixture(scope="module")
def four_devices():
    return run_on_four_devices({"single": SCRIPT, "distributed": DISTRIBUTED_SCRIPT})


def test_four_fake_devices_match_one_device(four_devices):
    assert four_devices["single"] == "PASSED", four_devices["single"]


def test_distributed_on_four_fake_devices_matches_one_device(four_devices):
    assert four_devices["distributed"] == "PASSED", four_devices["distributed"]
