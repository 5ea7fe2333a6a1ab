"""``unicycle``: Eq. 3.18 circle, Eq. 3.17 no-slip, Eq. 3.19–3.20, Eq. 3.23, RSI, early termination,
solvability in both physics modes, batched robustness, curriculum without recompiling.

Compiled functions are module fixtures, each used with one input shape, so each compiles once.
"""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs_mjx
from envs_mjx import tracking
from envs_mjx.config import ConfigError
from envs_mjx.unicycle import Unicycle, unicycle_reward, wheel_speeds, wheel_torques
from tests.envs import tracking_checks as checks


def _record(s):
    return {
        "reward": s.reward,
        "done": s.done,
        "pose": s.info["pose"],
        "vel": s.info["vel"],
        "k": s.info["k"],
        "tau": s.info["wheel_torque"],
        "wheel_speed": s.info["wheel_speed"],
        **s.metrics,
    }


def _rollout_fn(env, lanes):
    """``run(params, actions [lanes, T, 2])`` -> (start state, per-step records ``[lanes, max_steps]``)."""
    return checks.rollout_fn(env, jax.random.split(jax.random.PRNGKey(0), lanes), _record)


@pytest.fixture(scope="module")
def kin_sine():
    env = Unicycle(mode="kinematic", trajectory="sine")
    return env, _rollout_fn(env, 1)


@pytest.fixture(scope="module")
def dyn_ellipse():
    """Dynamic ellipse over 20 s (past the 2π → 0 jump of θ_r at 16 s), 8 lanes."""
    env = Unicycle(mode="dynamic", trajectory="ellipse", duration=20.0)
    return env, _rollout_fn(env, 8)


def test_registry_and_config_errors():
    assert {"scara", "unicycle"} <= set(envs_mjx.names())
    env = envs_mjx.make("unicycle", mode="kinematic", trajectory="ellipse")
    assert env.max_steps == 160 and env.config.duration == 16.0
    np.testing.assert_allclose(env.action_scale, [1.2, 1.2])
    assert Unicycle(mode="kinematic").max_steps == 314  # 10π s at dt = 0.1
    assert Unicycle(mode="kinematic", dt=0.05, duration=2.0).max_steps == 40
    with pytest.raises(ConfigError, match="mode='torque'.*'dynamic', 'kinematic'"):
        Unicycle(mode="torque")
    with pytest.raises(ConfigError, match="trajectory='circle'.*'sine', 'ellipse'"):
        Unicycle(trajectory="circle")
    with pytest.raises(ConfigError, match="max_steps=10 disagrees with duration"):
        Unicycle(mode="kinematic", duration=5.0, max_steps=10)
    with pytest.raises(ConfigError, match=r"mass=0.*\(0, inf\]"):
        Unicycle(mass=0.0)
    with pytest.raises(ConfigError, match="observation='full'.*'thesis', 'extended'"):
        Unicycle(observation="full")


def test_extended_observation_hand_computed():
    """The 5 preview elements at the start of the sine (pose = reference at t = 0), by hand."""
    env = Unicycle(mode="kinematic", trajectory="sine", observation="extended")
    thesis = Unicycle(mode="kinematic", trajectory="sine")
    assert (env.observation_size, thesis.observation_size) == (19, 14)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0), checks.start(0.0))
    obs = np.asarray(state.obs)
    assert obs.shape == (19,)
    np.testing.assert_allclose(obs[:14], jax.jit(thesis.reset)(jax.random.PRNGKey(0), checks.start(0.0)).obs, atol=1e-6)
    th0 = math.atan(0.4)  # Eq. 3.25 at t = 0; the robot starts there
    x1, y1, th1 = 0.1, 2 * math.sin(0.02), math.atan(0.4 * math.cos(0.02))  # reference at t = dt
    d_par = math.cos(th0) * x1 + math.sin(th0) * y1
    d_perp = -math.sin(th0) * x1 + math.cos(th0) * y1
    # Reference command at t = dt/2: v = |(1, 0.4 cos(0.01))|, w = θ̇_r = -0.08 sin(0.01) / v² (sine: ẋ = 1).
    v_mid = math.hypot(1.0, 0.4 * math.cos(0.01))
    w_mid = -0.08 * math.sin(0.01) / v_mid**2
    c_v, c_w, dt = 1.5, 0.5, 0.1
    expect = [d_par / (c_v * dt), d_perp / (c_v * dt), (th1 - th0) / (c_w * dt), v_mid / c_v, w_mid / c_w]
    np.testing.assert_allclose(obs[14:], expect, rtol=1e-4, atol=1e-5)


def test_extended_observation_in_action_units_tracks_with_a_linear_policy():
    """Oracle: a = (d_∥, turn + 2 d_⊥) read off the preview tracks the sine from t = 0 with per-axis
    error sums well below the thesis's (Table 5.4: 2.998, 2.961, 1.495); the residual is the Euler
    update's (Eq. 3.18 at the heading of the start of each step)."""
    env = Unicycle(mode="kinematic", trajectory="sine", observation="extended")
    res = tracking.test_episode(env, lambda o: jnp.stack([o[14], o[16] + 2.0 * o[15]]))
    assert res["steps"] == env.max_steps == 314
    assert np.all(res["sum_abs_error"] < [0.5, 1.5, 1.0]), res["sum_abs_error"]
    assert np.all(res["abs_error"].max(axis=0) < [0.01, 0.01, 0.01])


def test_kinematic_constant_command_gives_closed_form_circle(kin_sine):
    """Eq. 3.18 with Euler steps from (0, 0, θ0): chords of length v·dt turning by φ = w·dt, so
    p_k = v dt sin(kφ/2)/sin(φ/2) (cos, sin)(θ0 + (k−1)φ/2), all on a circle of radius
    v dt / (2 sin(φ/2)) (→ v/w as dt → 0)."""
    env, run = kin_sine
    v, w, dt, n = 0.6, 0.3, env.dt, env.max_steps
    a = jnp.broadcast_to(jnp.array([v / 1.5, w / 0.5]), (1, n, 2))
    _, rec = run(checks.start(0.0), a)  # the sine starts at (0, 0) with heading arctan(0.4)
    pose = np.asarray(rec["pose"][0], np.float64)
    th0, k, phi = math.atan(0.4), np.arange(1, n + 1), w * dt
    chord = v * dt * np.sin(k * phi / 2) / np.sin(phi / 2)
    np.testing.assert_allclose(pose[:, 0], chord * np.cos(th0 + (k - 1) * phi / 2), atol=5e-4)
    np.testing.assert_allclose(pose[:, 1], chord * np.sin(th0 + (k - 1) * phi / 2), atol=5e-4)
    np.testing.assert_allclose(pose[:, 2], th0 + k * phi, atol=2e-4)
    rho = v * dt / (2 * np.sin(phi / 2))
    centre = rho * np.array([-np.sin(th0 - phi / 2), np.cos(th0 - phi / 2)])
    np.testing.assert_allclose(np.hypot(pose[:, 0] - centre[0], pose[:, 1] - centre[1]), rho, atol=5e-4)
    assert abs(rho - v / w) < 0.001
    np.testing.assert_allclose(rec["vel"][0, -1], [v * np.cos(pose[-2, 2]), v * np.sin(pose[-2, 2]), w], atol=1e-4)


def test_reward_eq_3_23_hand_computed():
    pos_err = jnp.array([0.1, -0.2, 0.3, 0.0])
    vel_err = jnp.array([0.5, 0.0, -0.1])
    r, r_p, r_v = unicycle_reward(pos_err, vel_err, 0.4, 0.6, 1.0, 2.0)
    np.testing.assert_allclose(r_p, math.exp(-0.14), rtol=1e-6)
    np.testing.assert_allclose(r_v, math.exp(-2 * 0.26), rtol=1e-6)
    np.testing.assert_allclose(r, 0.4 * math.exp(-0.14) + 0.6 * math.exp(-0.52), rtol=1e-6)


def test_step_reward_and_observation_match_eq_3_23(kin_sine):
    env, run = kin_sine
    _, rec = run(checks.start(0.25), jnp.array([[[0.3, -0.4], [0.9, 0.2]]]))
    k0 = int(0.25 * env.max_steps)
    for i in range(2):
        ref = env.reference(k0 + 1 + i)
        pose, vel = np.asarray(rec["pose"][0, i]), np.asarray(rec["vel"][0, i])
        ex, ey = ref.pos[0] - pose[0], ref.pos[1] - pose[1]
        es, ec = math.sin(ref.pos[2]) - math.sin(pose[2]), math.cos(ref.pos[2]) - math.cos(pose[2])
        ev = np.asarray(ref.vel) - vel
        assert ex**2 + ey**2 + np.sum(ev**2) > 1e-3  # a real error
        expect = 0.4 * math.exp(-(ex**2 + ey**2 + es**2 + ec**2)) + 0.6 * math.exp(-2 * np.sum(ev**2))
        np.testing.assert_allclose(rec["reward"][0, i], expect, rtol=1e-5)
        np.testing.assert_allclose(rec["r_p"][0, i], math.exp(-(ex**2 + ey**2 + es**2 + ec**2)), rtol=1e-5)
        th_err = (ref.pos[2] - pose[2] + math.pi) % (2 * math.pi) - math.pi
        np.testing.assert_allclose(rec["err_theta"][0, i], abs(th_err), atol=1e-5)


def test_rsi_starts_exactly_on_reference_state(kin_sine, dyn_ellipse):
    for env in (kin_sine[0], dyn_ellipse[0]):
        pose_and_rate = lambda k, env=env: (env.reference(k).pos, env.reference(k).vel)
        for state in checks.rsi_starts(env, jax.random.PRNGKey(3), (0.0, 0.37, 0.99), pose_and_rate, atol=1e-6):
            np.testing.assert_allclose(state.info["pose"], env.reference(state.info["k"]).pos, atol=1e-6)


def test_early_termination_after_limit_plus_one_and_zero_reward_after(kin_sine):
    env, run = kin_sine
    _, rec = run(checks.start(0.0, limit=3.0), jnp.broadcast_to(jnp.array([-1.0, 1.0]), (1, 30, 2)))  # drive away
    checks.assert_early_termination(env, rec, 30, limit=3)


def test_kinematic_reference_commands_track_the_reference(kin_sine):
    env, run = kin_sine
    _, rec = run(checks.start(0.0, limit=0.0), jnp.full((1, env.max_steps, 2), jnp.nan))
    assert float(jnp.max(rec["pos_error"])) < 0.05
    assert float(jnp.max(rec["err_theta"])) < 0.01
    assert int(jnp.argmax(rec["done"][0])) == env.max_steps - 1  # ends with the reference, no ET
    assert float(rec["reward"][0].min()) > 0.99


def test_dynamic_solvable_across_heading_wrap_and_lateral_slip_bounded(dyn_ellipse):
    """Lane 0 follows the reference's own commands from t = 0 to 20 s (θ_r jumps 2π → 0 at 16 s);
    lanes 1..7 send random commands.  Lateral velocity (Eq. 3.17) stays near zero in every lane."""
    env, run = dyn_ellipse
    n = env.max_steps
    rand = jax.random.uniform(jax.random.PRNGKey(1), (7, n, 2), minval=-1.0, maxval=1.0)
    _, rec = run(checks.start(0.0, limit=0.0), jnp.concatenate([jnp.full((1, n, 2), jnp.nan), rand]))
    th_ref = np.asarray(jax.vmap(lambda k: env.reference(k).pos[2])(rec["k"][0]))
    assert th_ref[158] > 6.1 and th_ref[161] < 0.3  # t = 15.9 s and 16.2 s: the reference heading wrapped
    assert float(jnp.max(rec["pos_error"][0])) < 0.07
    assert float(jnp.max(rec["err_theta"][0])) < 0.03  # wrapped error stays small across the jump
    assert int(jnp.argmax(rec["done"][0])) == n - 1 and float(rec["reward"][0].min()) > 0.99
    speed = jnp.hypot(rec["vel"][..., 0], rec["vel"][..., 1])
    assert float(jnp.max(speed[1:])) > 0.8 and float(jnp.max(jnp.abs(rec["vel"][1:, :, 2]))) > 0.8
    # slip ≈ v w (h + m / c): the heading advances by w h after each velocity solve (see unicycle.py)
    assert float(jnp.max(rec["lateral_velocity"])) < 2e-2
    # wheel speeds are Eq. 3.19 of the body's (v, w); torques within the limit
    th = rec["pose"][..., 2]
    v = rec["vel"][..., 0] * jnp.cos(th) + rec["vel"][..., 1] * jnp.sin(th)
    np.testing.assert_allclose(rec["wheel_speed"], wheel_speeds(v, rec["vel"][..., 2], 0.05, 0.15), atol=1e-3)
    assert float(jnp.max(jnp.abs(rec["tau"]))) <= env.config.torque_limit + 1e-5


def test_controller_inverts_eq_3_20_and_mjcf_applies_it():
    """τ from the controller satisfies τ1 + τ2 = R m k_v Δv, τ1 − τ2 = R I k_w Δw / L; and MuJoCo
    (C engine, the model MJX runs) accelerates the body by v̇ = (τ1 + τ2)/(R m), ẇ = L (τ1 − τ2)/(R I)."""
    env = Unicycle(mode="dynamic", mass=4.0, inertia=0.3, wheel_radius=0.06, half_axle=0.2)
    cfg = env.config
    tau = np.asarray(wheel_torques(jnp.array([1.0, 0.2]), 0.8, 0.5, cfg))
    r, m, inertia, l = 0.06, 4.0, 0.3, 0.2
    np.testing.assert_allclose(tau.sum(), r * m * 30.0 * 0.2, rtol=1e-5)
    np.testing.assert_allclose(tau[0] - tau[1], r * inertia * 30.0 * (0.2 - 0.5) / l, rtol=1e-5)
    assert np.all(np.abs(np.asarray(wheel_torques(jnp.array([9.0, -9.0]), 0.0, 0.0, cfg))) == cfg.torque_limit)

    mj, d = env.mj_model, mujoco.MjData(env.mj_model)
    theta = 0.7
    d.qpos[:] = [0.3, -0.2, theta]
    d.qvel[:] = [0.8 * math.cos(theta), 0.8 * math.sin(theta), 0.5]  # no lateral slip
    d.ctrl[:] = [tau[0], tau[1], 0.0]
    mujoco.mj_forward(mj, d)
    np.testing.assert_allclose(d.actuator_force[:2], tau, rtol=1e-6)
    v_dot = d.qacc[0] * math.cos(theta) + d.qacc[1] * math.sin(theta)
    np.testing.assert_allclose(v_dot, tau.sum() / (r * m), rtol=1e-5)
    np.testing.assert_allclose(d.qacc[2], l * (tau[0] - tau[1]) / (r * inertia), rtol=1e-5)
    np.testing.assert_allclose(-d.qacc[0] * math.sin(theta) + d.qacc[1] * math.cos(theta), 0.0, atol=1e-6)
    np.testing.assert_allclose(wheel_speeds(0.8, 0.5, r, l), [(0.8 + 0.5 * l) / r, (0.8 - 0.5 * l) / r], rtol=1e-6)


@pytest.fixture(scope="module")
def wrapped_1024():
    """``{mode: (wrapped env, jitted step, trace list)}`` over 1024 lanes, built lazily."""
    cache = {}

    def get(mode, env):
        if mode not in cache:
            wrapped = envs_mjx.wrap_for_training(env, num_envs=1024)
            cache[mode] = (wrapped, *checks.counting_step(wrapped))
        return cache[mode]

    return get


@pytest.mark.parametrize("mode", ["kinematic", "dynamic"])
def test_jit_vmap_1024_lanes_no_nan_no_recompile(mode, kin_sine, dyn_ellipse, wrapped_1024):
    env = kin_sine[0] if mode == "kinematic" else dyn_ellipse[0]
    wrapped, jstep, traces = wrapped_1024(mode, env)
    checks.step_extreme_actions(jstep, jax.jit(wrapped.reset)(jax.random.PRNGKey(0)), 2, 0)
    assert len(traces) == 1


def test_curriculum_params_change_without_recompile(kin_sine, wrapped_1024):
    """The RSI window and early-termination limit live in the state; a trainer rewrites them and the
    auto-resets follow, with the same compiled step (shared with the 1024-lane test)."""
    env = kin_sine[0]
    wrapped, jstep, traces = wrapped_1024("kinematic", env)
    state = jax.jit(wrapped.reset)(jax.random.PRNGKey(0), {"start_lo": 0.0, "start_hi": 0.0, "et_limit": 0.0})
    np.testing.assert_array_equal(state.info["k"], 0)
    away = jnp.tile(jnp.array([-1.0, 1.0], jnp.float32), (1024, 1))  # backwards: > 0.3 m off after 2 steps
    state = jstep(state, away)
    assert not bool(state.done.any())
    state = tracking.with_params(state, start_lo=0.25, start_hi=0.5)
    state = jstep(state, away)  # limit 0: every lane terminates here and auto-resets in the new window
    assert bool(state.done.all()) and float(state.info["truncation"].max()) == 0.0
    k, n = np.asarray(state.info["k"]), env.max_steps
    assert k.min() >= int(0.25 * n) and k.max() < int(0.5 * n) and len(set(k.tolist())) > 40
    ref = jax.vmap(lambda kk: env.reference(kk).pos)(state.info["k"])
    np.testing.assert_allclose(state.info["pose"], ref, atol=1e-5)  # started on the reference
    np.testing.assert_array_equal(state.info["params"]["start_lo"], np.full(1024, 0.25, np.float32))
    assert len(traces) == 1
