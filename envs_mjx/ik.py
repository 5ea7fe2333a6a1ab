"""Serial-chain kinematics and inverse kinematics in plain JAX (thesis §3.4.1).

The arm's forward kinematics and its site Jacobian are read off a compiled ``mujoco.MjModel``
(:func:`chain_from_model`) and evaluated with a few 3x3 products per joint.  MuJoCo's C engine
(``mj_kinematics``, ``mj_jacSite``) and MJX (``mjx.kinematics`` + ``mjx.jac``) compute the same
quantities; the tests check all three agree.  The plain form is used on every backend because
XLA:CPU's default pipeline compiles MJX's quaternion chain of a 7-link arm into code that runs
thousands of times slower than this (see ``envs_mjx/xla.py`` and ``benchmarks/env_throughput.py``).

Inverse kinematics turns a Cartesian target ``p`` for the end-effector into joint angles by
iterating ``q <- clip(q + dq)`` with

* pseudo-inverse:           ``dq = J^+ e``                          (Moore-Penrose, via SVD)
* damped least squares:     ``dq = J^T (J J^T + lambda^2 I)^-1 e``

where ``e = p - fk(q)`` and ``J = d fk / d q`` is the ``[3, n]`` position Jacobian.  Both are
pure functions of arrays; ``solve`` takes any ``fk_jac(q) -> (pos [3], J [3, n])`` so MJX's
Jacobian can be plugged in instead of the chain's (``mjx_site_fk_jac``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

__all__ = [
    "METHODS",
    "Chain",
    "chain_from_model",
    "dls_step",
    "fk_jac",
    "forward_kinematics",
    "mjx_site_fk_jac",
    "dls_matrix",
    "pinv_matrix",
    "pinv_step",
    "solve",
]

METHODS = ("dls", "pinv")

FkJac = Callable[[jax.Array], tuple[jax.Array, jax.Array]]


class Chain(NamedTuple):
    """Static description of a serial chain of hinge joints ending at a site (NumPy arrays).

    For joint ``i`` (in qpos order) the link frame is reached from the previous link frame by
    the fixed transform ``(pre_pos[i], pre_rot[i])`` (all fixed bodies folded in); the hinge turns
    about ``axis[i]`` through the point ``anchor[i]``, both in that link frame.  The site sits at
    ``(site_pos, site_rot)`` in the last link frame; ``base_pos``/``base_rot`` place the chain's
    first frame in the world.
    """

    base_pos: np.ndarray  # [3]
    base_rot: np.ndarray  # [3, 3]
    pre_pos: np.ndarray  # [n, 3]
    pre_rot: np.ndarray  # [n, 3, 3]
    anchor: np.ndarray  # [n, 3]
    axis: np.ndarray  # [n, 3], unit
    qpos0: np.ndarray  # [n] reference angles (MuJoCo measures hinges from qpos0)
    site_pos: np.ndarray  # [3]
    lower: np.ndarray  # [n] joint lower limits (-inf if unlimited)
    upper: np.ndarray  # [n] joint upper limits (+inf if unlimited)

    @property
    def n(self) -> int:
        """Number of joints."""
        return int(self.axis.shape[0])


def _quat_to_mat(quat: np.ndarray) -> np.ndarray:
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    return mat.reshape(3, 3)


def chain_from_model(model: mujoco.MjModel, site: str = "ee") -> Chain:
    """Extract the hinge chain from the world to ``site``.

    Every body on the path must have at most one joint, of type hinge, and the joints' qpos
    addresses must be ``0 .. n-1`` in path order (a single arm with nothing else in qpos).

    Raises:
      ValueError: if the model is not such a chain.
    """
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, site)
    if sid < 0:
        raise ValueError(f"site {site!r} not found in the model")
    path = []
    b = int(model.site_bodyid[sid])
    while b != 0:
        path.append(b)
        b = int(model.body_parentid[b])
    path.reverse()

    base_pos, base_rot = np.zeros(3), np.eye(3)
    acc_pos, acc_rot = np.zeros(3), np.eye(3)  # fixed transform accumulated since the last joint
    pre_pos, pre_rot, anchor, axis, qpos0, lower, upper = [], [], [], [], [], [], []
    for b in path:
        bpos, brot = np.asarray(model.body_pos[b], float), _quat_to_mat(model.body_quat[b])
        acc_pos, acc_rot = acc_pos + acc_rot @ bpos, acc_rot @ brot
        nj = int(model.body_jntnum[b])
        if nj == 0:
            continue
        j = int(model.body_jntadr[b])
        if nj > 1 or model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            raise ValueError(f"body {b} must have at most one hinge joint for a serial chain")
        if int(model.jnt_qposadr[j]) != len(axis):
            raise ValueError("joint qpos addresses must follow the chain order from 0")
        if not axis:
            base_pos, base_rot = acc_pos, acc_rot
            acc_pos, acc_rot = np.zeros(3), np.eye(3)
        pre_pos.append(acc_pos)
        pre_rot.append(acc_rot)
        anchor.append(np.asarray(model.jnt_pos[j], float))
        axis.append(np.asarray(model.jnt_axis[j], float) / np.linalg.norm(model.jnt_axis[j]))
        qpos0.append(float(model.qpos0[model.jnt_qposadr[j]]))
        limited = bool(model.jnt_limited[j])
        lower.append(float(model.jnt_range[j, 0]) if limited else -np.inf)
        upper.append(float(model.jnt_range[j, 1]) if limited else np.inf)
        acc_pos, acc_rot = np.zeros(3), np.eye(3)
    if not axis:
        raise ValueError(f"no hinge joints between the world and site {site!r}")
    if model.nq != len(axis):
        raise ValueError(f"model has nq={model.nq} but the chain has {len(axis)} joints")
    # the site's placement in the last link frame, including fixed bodies after the last joint
    site_pos = acc_pos + acc_rot @ np.asarray(model.site_pos[sid], float)
    f32 = lambda x: np.asarray(x, np.float32)
    return Chain(
        base_pos=f32(base_pos),
        base_rot=f32(base_rot),
        pre_pos=f32(np.stack(pre_pos)),
        pre_rot=f32(np.stack(pre_rot)),
        anchor=f32(np.stack(anchor)),
        axis=f32(np.stack(axis)),
        qpos0=f32(qpos0),
        site_pos=f32(site_pos),
        lower=f32(lower),
        upper=f32(upper),
    )


def _axis_rotation(axis: np.ndarray, angle: jax.Array, xp=jnp) -> jax.Array:
    """Rodrigues' formula: ``[3, 3]`` rotation by ``angle`` about the unit ``axis`` (NumPy constant), in
    ``xp`` (``jax.numpy``, or NumPy for a constant angle)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]], np.float32)
    return xp.eye(3, dtype=np.float32) + xp.sin(angle) * k + (1.0 - xp.cos(angle)) * (k @ k)


def forward_kinematics(chain: Chain, q: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """World positions of the site, joint anchors and joint axes.

    Args:
      chain: the arm (static).
      q: ``[n]`` joint angles (MuJoCo qpos); a NumPy array is computed in NumPy (an env's constants at
        build time, without dispatching a compiled program per operation).
    Returns:
      ``(site [3], anchors [n, 3], axes [n, 3])``, NumPy arrays for a NumPy ``q``.
    """
    xp = np if isinstance(q, np.ndarray) else jnp
    pos = xp.asarray(chain.base_pos)
    rot = xp.asarray(chain.base_rot)
    anchors, axes = [], []
    for i in range(chain.n):
        pos = pos + rot @ chain.pre_pos[i]
        rot = rot @ chain.pre_rot[i]
        anchor = pos + rot @ chain.anchor[i]
        anchors.append(anchor)
        axes.append(rot @ chain.axis[i])
        rot = rot @ _axis_rotation(chain.axis[i], q[i] - chain.qpos0[i], xp)
        pos = anchor - rot @ chain.anchor[i]
    site = pos + rot @ chain.site_pos
    return site, xp.stack(anchors), xp.stack(axes)


def fk_jac(chain: Chain, q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Site position and its ``[3, n]`` position Jacobian (column i: ``axis_i x (site - anchor_i)``)."""
    site, anchors, axes = forward_kinematics(chain, q)
    jac = jnp.cross(axes, site[None, :] - anchors).T
    return site, jac


def mjx_site_fk_jac(mjx_model, site_id: int) -> FkJac:
    """``fk_jac`` computed by MJX (``mjx.kinematics``, ``mjx.com_pos``, ``mjx.jac``), for comparison.

    Slow on XLA:CPU without ``envs_mjx.xla.cpu_compiler_options()``; fine on GPU.
    """
    from mujoco import mjx

    body = int(mjx_model.site_bodyid[site_id])

    def f(q: jax.Array) -> tuple[jax.Array, jax.Array]:
        d = mjx.make_data(mjx_model).replace(qpos=q)
        d = mjx.com_pos(mjx_model, mjx.kinematics(mjx_model, d))
        site = d.site_xpos[site_id]
        jacp, _ = mjx.jac(mjx_model, d, site, body)
        return site, jacp.T

    return f


def pinv_matrix(jac: jax.Array) -> jax.Array:
    """Moore-Penrose inverse ``J^+``, ``[n, 3]`` of a ``[3, n]`` Jacobian (SVD; singular directions dropped)."""
    return jnp.linalg.pinv(jac)


def _inv3(m: jax.Array) -> jax.Array:
    """Inverse of a ``[3, 3]`` matrix by cofactors (element-wise: fuses on every backend, unlike a
    batched LAPACK/cuSolver call per lane).  Used on ``J J^T + damping^2 I``, which the damping keeps
    positive definite."""
    r0, r1, r2 = m[0], m[1], m[2]
    cof = jnp.stack([jnp.cross(r1, r2), jnp.cross(r2, r0), jnp.cross(r0, r1)], axis=1)
    return cof / jnp.dot(r0, cof[:, 0])


def dls_matrix(jac: jax.Array, damping: float | jax.Array) -> jax.Array:
    """Damped-least-squares inverse ``J^T (J J^T + damping^2 I)^-1``, ``[n, m]`` for a ``[m, n]`` Jacobian."""
    eye = jnp.eye(jac.shape[0], dtype=jac.dtype)
    gram = jac @ jac.T + (damping**2) * eye
    return jac.T @ (_inv3(gram) if jac.shape[0] == 3 else jnp.linalg.solve(gram, eye))


def pinv_step(jac: jax.Array, err: jax.Array) -> jax.Array:
    """Pseudo-inverse update ``dq = J^+ e`` (``jac [3, n]``, ``err [3]`` -> ``[n]``, minimum norm)."""
    return pinv_matrix(jac) @ err


def dls_step(jac: jax.Array, err: jax.Array, damping: float | jax.Array) -> jax.Array:
    """Damped-least-squares update ``dq = J^T (J J^T + damping^2 I)^-1 e`` (``[3, n]``, ``[3]`` -> ``[n]``).

    Bounded near singular configurations, where ``pinv_step`` grows without limit.
    """
    return dls_matrix(jac, damping) @ err


def _inverse(method: str, jac: jax.Array, damping: float) -> jax.Array:
    return pinv_matrix(jac) if method == "pinv" else dls_matrix(jac, damping)


def solve(
    fk: FkJac,
    q0: jax.Array,
    target: jax.Array,
    *,
    method: str = "dls",
    damping: float = 0.05,
    iters: int = 3,
    lower: jax.Array | np.ndarray | None = None,
    upper: jax.Array | np.ndarray | None = None,
    nullspace_gain: float = 0.0,
    max_step: float = 0.5,
) -> jax.Array:
    """Iterative IK from ``q0`` towards the Cartesian ``target``, respecting joint limits.

    Each iteration, with ``e = target - fk(q)`` and ``J^#`` the pseudo-inverse or DLS inverse:

    1. ``dq = J^# e + (I - J^# J) z`` where ``z = nullspace_gain * (q_mid - q)`` pulls the joints
       towards the middle of their range in the arm's null space (the redundant 7th degree of
       freedom), which keeps them away from limits without moving the end-effector to first order;
    2. joints that ``dq`` would push past a limit are set to the limit and the remaining error
       is solved again with their Jacobian columns removed (joint clamping), so a joint at its
       limit does not stall the others;
    3. the update is capped at ``max_step`` radians (infinity norm, direction kept).

    Unreachable targets give the closest joint-limited attempt.

    Args:
      fk: ``q [n] -> (pos [3], J [3, n])``.
      q0: ``[n]`` starting joint angles.  target: ``[3]``.
      method: ``"dls"`` or ``"pinv"`` (static).  damping: DLS lambda.  iters: iterations (static).
      lower, upper: ``[n]`` joint limits (None: unlimited; then no nullspace term).
    Returns:
      ``[n]`` joint angles within the limits.
    """
    if method not in METHODS:
        raise ValueError(f"method={method!r} is not valid; choose one of {', '.join(map(repr, METHODS))}")
    limited = lower is not None

    def iteration(_, q):
        pos, jac = fk(q)
        err = target - pos
        inv = _inverse(method, jac, damping)
        dq = inv @ err
        if limited and nullspace_gain:
            mid = 0.5 * (jnp.asarray(lower) + jnp.asarray(upper))
            z = nullspace_gain * (mid - q)
            dq = dq + z - inv @ (jac @ z)
        if limited:
            blocked = (q + dq < lower) | (q + dq > upper)
            dq_blocked = jnp.clip(q + dq, lower, upper) - q
            err_free = err - jac @ jnp.where(blocked, dq_blocked, 0.0)
            dq_free = _inverse(method, jnp.where(blocked[None, :], 0.0, jac), damping) @ err_free
            dq = jnp.where(blocked, dq_blocked, dq_free)
        dq = jnp.where(jnp.isfinite(dq), dq, 0.0)
        dq = dq * jnp.minimum(1.0, max_step / jnp.maximum(jnp.max(jnp.abs(dq)), 1e-12))
        q = q + dq
        return jnp.clip(q, lower, upper) if limited else q

    return jax.lax.fori_loop(0, int(iters), iteration, jnp.asarray(q0))
