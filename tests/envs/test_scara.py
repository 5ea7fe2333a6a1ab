"""``scara``: Eq. 3.15 against MJX and MuJoCo's C engine, Eq. 3.22, RSI, early termination,
solvability with the reference's own increments, batched robustness."""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import envs_mjx
from envs_mjx.config import ConfigError
from envs_mjx.scara import Scara, build_model, forward_kinematics, scara_reward
from tests.envs import tracking_checks as checks


def _eq_3_15(q, l1, l2, d):
    t1, t2, d3 = q[..., 0], q[..., 1], q[..., 2]
    return np.stack([l1 * np.cos(t1) + l2 * np.cos(t1 - t2), l1 * np.sin(t1) + l2 * np.sin(t1 - t2), d - d3], -1)


@pytest.fixture(scope="module")
def scara():
    """The default env and a jit(vmap) scan feeding ``actions [B, T, 3]`` (NaN rows: reference increments)."""
    env = Scara()

    def record(s):
        return {"reward": s.reward, "done": s.done, "q": s.info["q"], "ee": s.info["ee_pos"],
                "ref": s.info["ref_pos"], "k": s.info["k"], "obs": s.obs, **s.metrics}  # fmt: skip

    return env, checks.rollout_fn(env, jax.random.PRNGKey(0)[None], record)


def _mjx_sites(env, site, qs):
    data = mjx.make_data(env.mjx_model)
    kin = jax.jit(jax.vmap(lambda q: mjx.kinematics(env.mjx_model, data.replace(qpos=q)).site_xpos[site]))
    return kin(jnp.asarray(qs, jnp.float32))


def test_site_matches_eq_3_15_in_mjx_and_c_engine():
    """Random joints, default and non-default geometry: the MJCF site is Eq. 3.15 (C engine for
    both geometries, MJX for the rewritten one)."""
    rng = np.random.default_rng(0)
    for l1, l2, d in ((1.0, 0.8, 1.0), (0.35, 0.25, 0.6)):
        env = Scara(l1=l1, l2=l2, height=d, joint_hi=(2.6, 2.6, 0.3), ref_center=(0.0, 1.2, 0.15),
                    ref_amplitude=(0.8, 0.5, 0.1))
        mj = env.mj_model
        site = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_SITE, "ee")
        qs = np.stack([rng.uniform(-2.6, 2.6, 16), rng.uniform(-2.6, 2.6, 16), rng.uniform(0.0, 0.3, 16)], 1)
        expect = _eq_3_15(qs, l1, l2, d)
        data = mujoco.MjData(mj)
        c_sites = []
        for q in qs:
            data.qpos[:] = q
            mujoco.mj_kinematics(mj, data)
            c_sites.append(data.site_xpos[site].copy())
        np.testing.assert_allclose(np.stack(c_sites), expect, atol=1e-9)
        np.testing.assert_allclose(forward_kinematics(jnp.asarray(qs), l1, l2, d), expect, atol=2e-6)
    np.testing.assert_allclose(_mjx_sites(env, site, qs), expect, atol=2e-6)


def test_mjx_servo_step_matches_c_engine(scara):
    """One control step (n_substeps of implicitfast with position servos) agrees with MuJoCo C."""
    env, run = scara
    state, rec = run(checks.start(0.3), jnp.array([[[0.7, -0.4, 0.9]]]))
    k0 = int(0.3 * env.max_steps)
    r = env.joint_reference(k0)
    mj, d = env.mj_model, mujoco.MjData(env.mj_model)
    d.qpos[:], d.qvel[:] = np.asarray(r.q), np.asarray(r.qd)
    d.ctrl[:] = np.clip(np.asarray(r.q) + np.array([0.07, -0.04, 0.045]), [-2.6, -2.6, 0.0], [2.6, 2.6, 0.5])
    for _ in range(env.config.n_substeps):
        mujoco.mj_step(mj, d)
    np.testing.assert_allclose(rec["q"][0, 0], d.qpos, atol=2e-5)
    np.testing.assert_allclose(rec["ee"][0, 0], _eq_3_15(d.qpos, 1.0, 0.8, 1.0), atol=2e-5)


def test_reward_eq_3_22_hand_computed(scara):
    np.testing.assert_allclose(scara_reward(jnp.array([0.1, -0.2, 0.3])), math.exp(-2 * 0.14), rtol=1e-6)
    np.testing.assert_allclose(scara_reward(jnp.zeros(3)), 1.0)
    env, run = scara
    _, rec = run(checks.start(0.5), jnp.array([[[1.0, -1.0, 1.0], [1.0, 0.5, -1.0]]]))
    for i in range(2):
        e = np.asarray(rec["ref"][0, i], np.float64) - np.asarray(rec["ee"][0, i])
        assert np.linalg.norm(e) > 0.05  # a real error, not a trivially perfect step
        np.testing.assert_allclose(rec["reward"][0, i], math.exp(-2 * np.sum(e**2)), rtol=1e-5)
        np.testing.assert_allclose(rec["obs"][0, i, 7:], e / env.config.obs_error_scale, rtol=1e-4, atol=1e-5)
        q = np.asarray(rec["q"][0, i])
        np.testing.assert_allclose(rec["obs"][0, i, :4], [np.sin(q[0]), np.cos(q[0]), np.sin(q[1]), np.cos(q[1])],
                                   atol=1e-6)
    # reference at k0 + 1 + i is the forward kinematics of the joint reference
    k0 = int(0.5 * env.max_steps)
    np.testing.assert_allclose(rec["ref"][0, 0], _eq_3_15(np.asarray(env.joint_reference(k0 + 1).q), 1.0, 0.8, 1.0),
                               atol=2e-6)


def test_rsi_starts_exactly_on_reference_state(scara):
    env, _ = scara
    joints = lambda k: (env.joint_reference(k).q, env.joint_reference(k).qd)
    for state in checks.rsi_starts(env, jax.random.PRNGKey(5), (0.0, 0.42, 0.999), joints, atol=1e-7):
        np.testing.assert_allclose(state.info["ee_pos"], state.info["ref_pos"], atol=1e-7)
    reset = jax.jit(env.reset)
    ks = jax.vmap(lambda k: reset(k, {"start_lo": 0.25, "start_hi": 0.5}).info["k"])(
        jax.random.split(jax.random.PRNGKey(0), 64)
    )
    assert int(ks.min()) >= int(0.25 * env.max_steps) and int(ks.max()) < int(0.5 * env.max_steps)


def test_early_termination_after_limit_plus_one_and_zero_reward_after(scara):
    env, run = scara
    _, rec = run(checks.start(0.0, limit=5.0), jnp.ones((1, 30, 3)))  # run away from the reference
    first = checks.assert_early_termination(env, rec, 30, limit=5)
    assert float(rec["reward_tracking"][0, first]) > 0  # the tracking term itself is not zero


def test_reference_increments_track_the_reference(scara):
    env, run = scara
    _, rec = run(checks.start(0.0, limit=0.0), jnp.full((1, env.max_steps, 3), jnp.nan))
    assert float(jnp.max(rec["pos_error"])) < 5e-3
    assert int(jnp.argmax(rec["done"][0])) == env.max_steps - 1  # ends with the reference, no ET
    assert float(rec["reward"][0].min()) > 0.9999
    acts = jax.vmap(env.reference_action)(jnp.arange(env.max_steps))
    assert float(jnp.max(jnp.abs(acts))) < 1.0  # the reference is reachable with |a| <= 1


def test_extended_observation_is_the_error_to_the_next_reference_point():
    """``observation="extended"``: the thesis's 10 elements unchanged, then ``(p_ref(k+1) − p) / s_e``
    with ``p_ref`` from Eq. 3.15 of the joint reference, at reset and after a step."""
    thesis, extended = Scara(), Scara(observation="extended")
    assert (thesis.observation_size, extended.observation_size) == (10, 13)
    key, params = jax.random.PRNGKey(3), {"start_lo": 0.3, "start_hi": 0.3}
    states = [env.reset(key, params) for env in (thesis, extended)]
    action = jnp.array([0.7, -0.4, 0.9])
    states += [env.step(s, action) for env, s in zip((thesis, extended), states, strict=True)]
    for plain, ext in ((states[0], states[1]), (states[2], states[3])):
        assert ext.obs.shape == (13,)
        np.testing.assert_allclose(ext.obs[:10], plain.obs, atol=1e-6)
        k = int(ext.info["k"])
        nxt = _eq_3_15(np.asarray(extended.joint_reference(k + 1).q, np.float64), 1.0, 0.8, 1.0)
        expect = (nxt - np.asarray(ext.info["ee_pos"], np.float64)) / extended.config.obs_error_scale
        np.testing.assert_allclose(ext.obs[10:], expect, rtol=1e-4, atol=1e-4)
        assert np.linalg.norm(expect) > 0.1  # the reference moves: not the current error again
    with pytest.raises(ConfigError, match="observation='full'.*'thesis', 'extended'"):
        Scara(observation="full")


def test_config_errors_and_registry():
    env = envs_mjx.make("scara", dt=0.05, n_substeps=10)
    assert env.max_steps == 314 and env.mj_model.opt.timestep == pytest.approx(0.005)
    assert Scara(max_steps=50).config.duration == pytest.approx(5.0)
    with pytest.raises(ConfigError, match=r"ref_center\[1\] ± ref_amplitude\[1\].*theta2 range"):
        Scara(ref_amplitude=(0.8, 2.0, 0.15))
    with pytest.raises(ConfigError, match=r"rsi=\(0.6, 0.2\) must satisfy start_lo <= start_hi"):
        Scara(rsi=(0.6, 0.2))
    with pytest.raises(ConfigError, match=r"l1=-1.*\(0, inf\]"):
        Scara(l1=-1.0)
    assert build_model(Scara.default_config().resolved()).body_pos[3][0] == pytest.approx(1.0)


def test_jit_vmap_1024_lanes_no_nan_no_recompile(scara):
    env, _ = scara
    wrapped = envs_mjx.wrap_for_training(env, num_envs=1024)
    jstep, traces = checks.counting_step(wrapped)

    def joints_in_range(state):
        q = state.info["q"]
        assert bool(jnp.all((q >= env._lo - 0.02) & (q <= env._hi + 0.02)))

    checks.step_extreme_actions(jstep, jax.jit(wrapped.reset)(jax.random.PRNGKey(0)), 3, 1, joints_in_range)
    assert len(traces) == 1
