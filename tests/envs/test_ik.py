"""Chain kinematics and IK of ``envs_mjx.ik`` against MuJoCo's C engine and MJX."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from envs_mjx import ik, xla
from envs_mjx.arm7 import ASSET


@pytest.fixture(scope="module")
def model():
    return mujoco.MjModel.from_xml_path(str(ASSET))


@pytest.fixture(scope="module")
def chain(model):
    return ik.chain_from_model(model, "ee")


def c_site_and_jac(model, q):
    """MuJoCo C engine oracle: site position [3] and position Jacobian [3, 7] at joint angles q."""
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    jacp = np.zeros((3, model.nv))
    mujoco.mj_jacSite(model, data, jacp, None, 0)
    return data.site_xpos[0].copy(), jacp


def random_configs(chain, n, seed, fraction=1.0):
    rng = np.random.default_rng(seed)
    mid, half = (chain.lower + chain.upper) / 2, (chain.upper - chain.lower) / 2
    return rng.uniform(mid - fraction * half, mid + fraction * half, size=(n, chain.n)).astype(np.float32)


def test_chain_matches_mujoco_c_engine_and_mjx(model, chain):
    qs = random_configs(chain, 16, seed=0)
    site, jac = jax.jit(jax.vmap(lambda q: ik.fk_jac(chain, q)))(qs)
    mjx_model = mjx.put_model(model)
    site_m, jac_m = xla.jit(jax.vmap(ik.mjx_site_fk_jac(mjx_model, 0)))(qs)
    for i, q in enumerate(qs):
        site_c, jac_c = c_site_and_jac(model, q)
        np.testing.assert_allclose(site[i], site_c, atol=2e-6)
        np.testing.assert_allclose(jac[i], jac_c, atol=2e-6)
        np.testing.assert_allclose(site_m[i], site_c, atol=2e-6)
        np.testing.assert_allclose(jac_m[i], jac_c, atol=2e-6)
    assert np.ptp(np.asarray(site), axis=0).min() > 0.2  # the configurations really differ


def test_numpy_forward_kinematics_is_numpy_and_matches_the_c_engine(model, chain):
    """A NumPy ``q`` (an env's constants at build time) is computed in NumPy: no JAX array comes back, and the
    site is MuJoCo's."""
    for q in random_configs(chain, 4, seed=1):
        site, anchors, axes = ik.forward_kinematics(chain, q)
        assert all(type(x) is np.ndarray for x in (site, anchors, axes))
        assert anchors.shape == axes.shape == (chain.n, 3)
        np.testing.assert_allclose(site, c_site_and_jac(model, q)[0], atol=2e-6)


def test_update_rules_match_their_formulas():
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(3, 7)).astype(np.float32)
    err = rng.normal(size=3).astype(np.float32)
    lam = 0.3
    expected_dls = jac.T @ np.linalg.solve(jac @ jac.T + lam**2 * np.eye(3), err)
    np.testing.assert_allclose(ik.dls_step(jac, err, lam), expected_dls, rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(ik.pinv_step(jac, err), np.linalg.pinv(jac) @ err, rtol=1e-4, atol=1e-5)
    # DLS tends to the pseudo-inverse as the damping vanishes; it stays bounded at a singularity
    np.testing.assert_allclose(ik.dls_step(jac, err, 1e-4), ik.pinv_step(jac, err), rtol=1e-3, atol=1e-4)
    singular = np.array([[1.0, 0, 0, 0, 0, 0, 0], [1e-7, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0, 0]], np.float32)
    e = np.array([0.0, 0.01, 0.0], np.float32)
    assert np.abs(ik.dls_step(singular, e, 0.05)).max() < 1e-3
    assert np.all(np.isfinite(ik.pinv_step(singular, e)))


@pytest.mark.parametrize("method", ik.METHODS)
def test_ik_reaches_random_reachable_targets(model, chain, method):
    """Targets are end-effector positions of random configurations (reachable); the solution's
    end-effector is checked with MuJoCo's C engine."""
    n = 64
    starts = random_configs(chain, n, seed=2, fraction=0.5)
    rng = np.random.default_rng(3)
    goals_q = np.clip(starts + rng.uniform(-0.4, 0.4, size=starts.shape), chain.lower, chain.upper)
    targets = np.stack([c_site_and_jac(model, q)[0] for q in goals_q]).astype(np.float32)

    def solve(q0, target):
        return ik.solve(
            lambda q: ik.fk_jac(chain, q),
            q0,
            target,
            method=method,
            damping=0.02,
            iters=30,
            lower=chain.lower,
            upper=chain.upper,
            nullspace_gain=0.05,
        )

    qs = np.asarray(jax.jit(jax.vmap(solve))(starts, targets))
    reached = np.stack([c_site_and_jac(model, q)[0] for q in qs])
    err = np.linalg.norm(reached - targets, axis=1)
    start_err = np.linalg.norm(np.stack([c_site_and_jac(model, q)[0] for q in starts]) - targets, axis=1)
    assert start_err.mean() > 0.1  # the targets are not where the arm starts
    assert np.all((qs >= chain.lower - 1e-6) & (qs <= chain.upper + 1e-6))
    assert np.quantile(err, 0.95) < 1e-3, np.sort(err)[-5:]
    assert err.max() < 1e-2


def test_ik_clamps_joint_at_limit_and_uses_the_others(chain):
    """Joint 1 starts at its upper limit and the target needs more rotation about the base: the
    result keeps joint 1 within its limit while the other joints still close most of the error."""
    fk = jax.jit(lambda q: ik.fk_jac(chain, q))
    q0 = np.array([chain.upper[0], 0.6, 0.0, -1.0, 0.0, 0.8, 0.0], np.float32)
    p0, jac = fk(q0)
    push = jac[:, 0] / jnp.linalg.norm(jac[:, 0]) * 0.05  # the direction joint 1 would move the hand
    target = p0 + push
    q = jax.jit(
        lambda q0, t: ik.solve(
            lambda q: ik.fk_jac(chain, q), q0, t, iters=10, lower=chain.lower, upper=chain.upper
        )
    )(q0, target)
    assert float(q[0]) <= chain.upper[0] + 1e-6
    assert float(jnp.linalg.norm(fk(q)[0] - target)) < 0.1 * 0.05


def test_chain_rejects_models_that_are_not_a_hinge_chain():
    free = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='.1'/><site name='ee'/></body></worldbody></mujoco>"
    )
    with pytest.raises(ValueError, match="hinge"):
        ik.chain_from_model(free, "ee")
    with pytest.raises(ValueError, match="site 'nope' not found"):
        ik.chain_from_model(free, "nope")
    with pytest.raises(ValueError, match="method='svd' is not valid"):
        ik.solve(lambda q: (q[:3], jnp.eye(3)), jnp.zeros(3), jnp.zeros(3), method="svd")
