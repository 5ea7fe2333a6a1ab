"""The MuJoCo Warp backend (env setting ``impl="warp"``, ``envs_mjx.backend``) and its config errors.

Every rollout runs three lanes under ``jax.vmap`` through the training wrappers, one lane ending its episode
at the first step and one at the second (mixed ``done`` across lanes, so the auto-reset's lane select meets
the Warp data's fields that all lanes share).

* ``arm7`` (``pd``, ``AutoResetWrapper``): MJX's JAX implementation and MuJoCo Warp step the same model, so
  both backends give the same observations, rewards and ``done`` from the same reset key and actions.
* ``scara`` (``AutoResetWrapper``) and ``unicycle`` (``PoolResetWrapper``): Warp's physics against MuJoCo's
  C engine stepping the env's own control (servo targets; the wheel-torque controller every physics step).
  ``unicycle``'s lateral grip is a velocity actuator that ``implicitfast`` integrates implicitly; MuJoCo (C)
  and MuJoCo Warp factorise ``M - h D`` in the sparsity of the mass matrix, diagonal for this body, so they
  drop the grip's off-diagonal terms at headings off the axes, where MJX's JAX implementation keeps them:
  there the two backends differ by the engines' design, and C is the reference Warp must match.

Each rollout is one jitted program (reset and steps); the fixtures are module-scoped.  MuJoCo Warp compiles
its CPU kernels once per machine (``~/.cache/warp``, or ``$WARP_CACHE_PATH``): about a minute of CPU on a
fresh cache, a few seconds after.
"""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import envs_mjx
from envs_mjx import backend
from envs_mjx.config import ConfigError

LANES = 3
EPISODE = 3
STEPS = 3
START_STEPS = (0, EPISODE - 1, EPISODE - 2)
"""Each lane's time-limit counter at the start: lane 1 ends at the first step, lane 2 at the second, lane 0
at the third."""


def _rollout(env, reset_refresh):
    """A jitted ``run(key, actions [STEPS, LANES, A]) -> (first state, per-step (state, obs, reward, done))``."""
    wrapped = envs_mjx.wrap_for_training(
        env, episode_length=EPISODE, num_envs=LANES, reset_refresh=reset_refresh, reset_group=LANES
    )

    def run(key, actions):
        state = wrapped.reset(key)
        state = state.replace(info={**state.info, "steps": jnp.asarray(START_STEPS, jnp.int32)})

        def body(s, a):
            s = wrapped.step(s, a)
            return s, (s.pipeline_state.qpos, s.pipeline_state.qvel, s.info, s.obs, s.reward, s.done)

        return state, jax.lax.scan(body, state, actions)[1]

    return jax.jit(run)


def _actions(env):
    return jax.random.uniform(jax.random.PRNGKey(1), (STEPS, LANES, env.action_size), minval=-1.0, maxval=1.0)


def _run(name, impl, reset_refresh, **config):
    """``(env, actions [STEPS, LANES, A], first state, per-step records)`` as host arrays."""
    env = envs_mjx.make(name, impl=impl, **config)
    assert env.mjx_model.impl == mjx.Impl(impl)
    actions = _actions(env)
    first, per_step = _rollout(env, reset_refresh)(jax.random.PRNGKey(0), actions)
    return env, np.asarray(actions), jax.device_get(first), jax.device_get(per_step)


def _check_lanes_end(done):
    """The time limits end lane 1 at the first step, lane 2 at the second, lane 0 at the third."""
    assert done[0, 1] == 1 and done[1, 2] == 1 and done[2, 0] == 1
    assert 0 < done[0].sum() < LANES


@pytest.fixture(scope="module")
def arm7_runs():
    return {impl: _run("arm7", impl, 1.0, mode="pd") for impl in backend.IMPLS}


def test_arm7_warp_and_jax_backends_agree_under_vmap_with_resets(arm7_runs):
    *_, obs_j, rew_j, done_j = arm7_runs["jax"][3]
    *_, obs_w, rew_w, done_w = arm7_runs["warp"][3]
    assert obs_j.shape == obs_w.shape == (STEPS, LANES, 9)
    _check_lanes_end(done_j)
    np.testing.assert_array_equal(done_w, done_j)
    np.testing.assert_allclose(obs_w, obs_j, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(rew_w, rew_j, rtol=1e-4, atol=1e-4)
    assert np.abs(obs_w - obs_w[:, :1]).max() > 1e-3  # the lanes differ (no broadcast of one lane)


def test_lane_select_keeps_the_warp_fields_all_lanes_share(arm7_runs):
    """``evaluation.freeze`` (through ``backend.select``) picks lane by lane and leaves the Warp data's shared
    fields (no lane axis) as they were; on MJX's JAX data every leaf is a lane's."""
    from jaxrl_robot.evaluation import freeze

    live = jnp.asarray([1.0, 0.0, 1.0])
    for impl, shared_fields in (("jax", False), ("warp", True)):
        old = arm7_runs[impl][2]
        new = backend.lane_map(lambda x: x + 1 if jnp.issubdtype(x.dtype, jnp.floating) else x, old)
        out = freeze(live, old, new)
        np.testing.assert_array_equal(np.asarray(out.pipeline_state.qpos)[[0, 2]], new.pipeline_state.qpos[[0, 2]])
        np.testing.assert_array_equal(out.pipeline_state.qpos[1], old.pipeline_state.qpos[1])
        np.testing.assert_array_equal(out.obs[1], old.obs[1])
        assert backend.has_shared(old) == shared_fields
        if shared_fields:
            contact = old.pipeline_state._impl.contact__pos
            assert contact.shape[0] != LANES and out.pipeline_state._impl.contact__pos is contact


def _scara_control_step(env, d, action):
    """``scara``'s control: servo targets ``clip(q + C a)`` held for ``n_substeps`` physics steps."""
    cfg = env.config
    d.ctrl[:] = np.clip(d.qpos + np.asarray(env.action_scale) * np.clip(action, -1.0, 1.0), cfg.joint_lo, cfg.joint_hi)
    for _ in range(cfg.n_substeps):
        mujoco.mj_step(env.mj_model, d)


def _unicycle_control_step(env, d, action):
    """``unicycle``'s control (``dynamic``): the wheel-torque controller every physics step."""
    cfg = env.config
    cmd = np.asarray(env.action_scale) * np.clip(action, -1.0, 1.0)
    kv, kw = cfg.ctrl_gain
    for _ in range(cfg.n_substeps):
        c, s = math.cos(d.qpos[2]), math.sin(d.qpos[2])
        v, w = d.qvel[0] * c + d.qvel[1] * s, d.qvel[2]
        total = cfg.wheel_radius * cfg.mass * kv * (cmd[0] - v)
        diff = cfg.wheel_radius * cfg.inertia * kw * (cmd[1] - w) / cfg.half_axle
        tau = np.clip([0.5 * (total + diff), 0.5 * (total - diff)], -cfg.torque_limit, cfg.torque_limit)
        d.ctrl[:] = [tau[0], tau[1], 0.0]
        mujoco.mj_step(env.mj_model, d)


# env: (reset refresh, MuJoCo control step, the info entry a fresh episode's qpos equals)
ORACLE = {"scara": (1.0, _scara_control_step, "q"), "unicycle": (0.5, _unicycle_control_step, "pose")}


@pytest.fixture(scope="module", params=sorted(ORACLE))
def warp_run(request):
    return request.param, _run(request.param, "warp", ORACLE[request.param][0])


def test_warp_steps_as_mujoco_under_vmap_with_resets(warp_run):
    name, (env, actions, first, (qpos, qvel, info, obs, reward, done)) = warp_run
    _, control_step, start_key = ORACLE[name]
    _check_lanes_end(done)
    prev_q, prev_v = first.pipeline_state.qpos, first.pipeline_state.qvel
    for t in range(STEPS):
        for lane in range(LANES):
            if done[t, lane]:  # a fresh episode: the physics is the new start's (RSI on the reference)
                np.testing.assert_allclose(qpos[t, lane], info[start_key][t, lane], atol=1e-6)
                continue
            d = mujoco.MjData(env.mj_model)
            d.qpos[:], d.qvel[:] = prev_q[lane], prev_v[lane]
            control_step(env, d, actions[t, lane])
            np.testing.assert_allclose(qpos[t, lane], d.qpos, atol=2e-4)
            np.testing.assert_allclose(qvel[t, lane], d.qvel, atol=2e-3)
        prev_q, prev_v = qpos[t], qvel[t]
    assert np.abs(qpos - qpos[:, :1]).max() > 1e-3  # the lanes differ (no broadcast of one lane)
    assert np.abs(qpos[0, 0] - first.pipeline_state.qpos[0]).max() > 1e-4  # the physics moved
    assert np.isfinite(obs).all() and np.isfinite(reward).all()


@pytest.mark.parametrize(
    "name, config, match",
    [
        ("arm7", {"impl": "cuda"}, r"impl='cuda' is not valid; choose one of 'jax', 'warp'"),
        ("scara", {"impl": "Warp"}, r"impl='Warp' is not valid; choose one of 'jax', 'warp'"),
        ("unicycle", {"impl": None}, r"impl=None is not valid; choose one of 'jax', 'warp'"),
        ("arm7", {"impl": "warp", "mode": "kinematic"}, r"impl='warp' is not valid with mode='kinematic'.*'pd'"),
        ("unicycle", {"impl": "warp", "mode": "kinematic"}, r"impl='warp' is not valid with mode='kinematic'.*'dyn"),
        ("racecar", {"impl": "warp"}, r"racecar: unknown setting 'impl'"),
    ],
)
def test_config_errors_are_one_line_and_name_impl(name, config, match):
    with pytest.raises(ConfigError, match=match) as err:
        envs_mjx.make(name, **config)
    assert "\n" not in str(err.value)


def test_warp_missing_names_the_extra(monkeypatch):
    monkeypatch.setattr(backend, "warp_installed", lambda: False)
    for name in ("arm7", "scara", "unicycle"):
        with pytest.raises(backend.WarpMissingError, match=r'warp-lang.*pip install -e "\.\[warp\]"') as err:
            envs_mjx.make(name, impl="warp")
        assert "\n" not in str(err.value)
    assert envs_mjx.make("arm7", mode="kinematic").config.impl == "jax"  # the default needs no Warp


def test_default_is_jax():
    for name in ("arm7", "arm7_precise", "scara", "unicycle"):
        assert envs_mjx.env_class(name).default_config().impl == "jax"
