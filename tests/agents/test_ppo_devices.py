"""The sharded path: the same lanes on 4 (fake CPU) devices train like on one device."""

import os
import subprocess
import sys
import textwrap

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

SCRIPT = textwrap.dedent(
    """
    import jax, numpy as np
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.ppo import make_trainer
    from tests.agents.test_ppo import TOY, Line

    assert len(jax.devices()) == 4, jax.devices()
    cfg = TOY.replace(num_envs=8, minibatch_size=32, schedule=(), objective="clip", reset_group=2)
    probe = np.random.default_rng(0).uniform(-1, 1, (16, 2)).astype(np.float32)
    out = {}
    for n in (1, 4):
        trainer = make_trainer(cfg, Line(), mesh=parallel.lane_mesh(n), iterations_per_update=2)
        state = jax.jit(trainer.init)(jax.random.PRNGKey(0))
        state, metrics = jax.jit(trainer.update)(state)
        assert len(state.env_state.obs.sharding.device_set) == n
        out[n] = (state, metrics, np.asarray(trainer.policy(state)(probe)))
    (s1, m1, a1), (s4, m4, a4) = out[1], out[4]
    # same lanes, same randomness: identical trajectories and statistics
    np.testing.assert_allclose(s1.env_state.obs, s4.env_state.obs, atol=1e-5)
    np.testing.assert_allclose(s1.obs_stats.mean, s4.obs_stats.mean, atol=1e-6)
    for k in ("critic_loss", "actor_loss", "kl", "reward", "episodes"):
        np.testing.assert_allclose(m1[k], m4[k], rtol=1e-4, atol=1e-6, err_msg=k)
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, atol=1e-5), s1.critic_params, s4.critic_params)
    np.testing.assert_allclose(a1, a4, atol=1e-4)
    # and training did move the policy, so the comparison is not between two initial states
    init = jax.jit(make_trainer(cfg, Line()).init)(jax.random.PRNGKey(0))
    a0 = np.asarray(make_trainer(cfg, Line()).policy(init)(probe))
    assert np.max(np.abs(a1 - a0)) > 1e-3
    print("OK")
    """
)


def test_four_fake_devices_match_one_device():
    env = dict(os.environ)
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4").strip()
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT], cwd=ROOT, env=env, capture_output=True, text=True, timeout=600
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "OK" in proc.stdout
