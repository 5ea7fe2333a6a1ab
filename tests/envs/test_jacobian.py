"""The ``jacobian`` env setting: MJX's sparse factorisation of the mass matrix (plain JAX operations) steps the arm
as its dense one (``cho_factor``) does, and the setting reaches the model; a bad value is a one-line error."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import envs_mjx
from envs_mjx.config import ConfigError


def test_the_sparse_and_dense_mass_matrix_give_the_same_accelerations():
    dense, sparse = (envs_mjx.make("arm7", mode="pd", jacobian=j) for j in ("dense", "sparse"))
    assert dense.mjx_model.opt.jacobian == mujoco.mjtJacobian.mjJAC_DENSE
    assert sparse.mjx_model.opt.jacobian == mujoco.mjtJacobian.mjJAC_SPARSE
    rng = np.random.default_rng(0)
    qpos = jnp.asarray(rng.uniform(-1, 1, 7), jnp.float32)
    qvel = jnp.asarray(rng.uniform(-1, 1, 7), jnp.float32)
    ctrl = jnp.asarray(rng.uniform(-1, 1, dense.mj_model.nu), jnp.float32)

    def qacc(env):
        data = mjx.make_data(env.mjx_model).replace(qpos=qpos, qvel=qvel, ctrl=ctrl)
        return jax.jit(mjx.forward)(env.mjx_model, data).qacc

    a_dense, a_sparse = qacc(dense), qacc(sparse)
    assert float(jnp.max(jnp.abs(a_dense))) > 0.1  # the arm accelerates: the comparison is not of zeros
    np.testing.assert_allclose(a_sparse, a_dense, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("name", ["arm7", "unicycle", "scara"])
def test_a_jacobian_that_does_not_exist_is_a_one_line_error(name):
    with pytest.raises(ConfigError, match="jacobian='band' is not valid; choose one of 'auto', 'dense', 'sparse'"):
        envs_mjx.make(name, jacobian="band")
