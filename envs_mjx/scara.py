"""``scara`` — SCARA end-effector trajectory tracking in MJX (thesis §3.5.1, §3.5.3).

Model (``assets/scara.xml``): revolute θ1 (axis +z), revolute θ2 (axis −z), prismatic d3 (axis −z);
the end-effector site sits at Eq. 3.15,
``x = l1 cos θ1 + l2 cos(θ1 − θ2)``, ``y = l1 sin θ1 + l2 sin(θ1 − θ2)``, ``z = D − d3``.
Link lengths, the height ``D``, joint ranges, servo gains and the physics timestep come from
:class:`ScaraConfig` and are written into the MJCF through ``MjSpec`` before compiling.

Reference: sinusoids per joint (``q_r = c + A sin(ω t + φ)``, inside the joint ranges); the
end-effector reference is their forward kinematics.  An episode covers the reference from its
start step (RSI, :mod:`envs_mjx.tracking`) to ``max_steps``; reaching the end of the reference
terminates the episode (the task is over; ``info["ref_end"]`` marks it).

Action ``a ∈ [-1, 1]^3``: ``Δq = C ⊙ a`` with ``C = action_scale``.  The new joint targets
``clip(q + Δq, joint range)`` — measured joint positions plus the increment — drive MJX position
actuators (the low-level PD servos of Fig. 3.11; gains ``kp``, ``kd``) for ``n_substeps`` physics
steps of ``dt / n_substeps`` seconds.

Observation (Eq. 3.21, 10-dim), scaled to similar ranges::

    [sin θ1, cos θ1, sin θ2, cos θ2,
     x / (l1 + l2), y / (l1 + l2), (z − z_mid) / z_half,
     e_x / s_e, e_y / s_e, e_z / s_e]

where ``z_mid``/``z_half`` are the middle and half-span of the reachable heights, ``s_e =
obs_error_scale`` and ``e = p_ref − p`` (thesis §3.5.1).

``observation="extended"`` appends the error to the *next* reference point, ``(p_ref,k+1 − p) /
s_e`` (13-dim): the displacement this control step must produce.  Eq. 3.21 holds the current error
but nothing of the reference's motion, and the end-effector position does not fix the reference's
phase (the joints run at different frequencies), so a policy reading it can only react to an error
once it has appeared — it lags the reference by about a step.

Reward (Eq. 3.22): ``r = exp(−2 (e_x² + e_y² + e_z²))`` in metres (the 2 is ``reward_coef``);
zero from the step that triggers early termination on.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from envs_mjx import backend, tracking
from envs_mjx.base import State, sanitize_action
from envs_mjx.config import ConfigError, check_choice, check_range, check_vector
from envs_mjx.trajectories import JointReference, joint_sinusoids

__all__ = [
    "OBSERVATIONS", "Scara", "ScaraConfig", "build_model", "forward_kinematics", "forward_velocity", "scara_reward",
]  # fmt: skip

ASSET = os.path.join(os.path.dirname(__file__), "assets", "scara.xml")
JOINTS = ("theta1", "theta2", "d3")
OBSERVATIONS = ("thesis", "extended")
"""``thesis``: Eq. 3.21 (10-dim); ``extended``: plus the error to the next reference point (13-dim)."""


@dataclasses.dataclass(frozen=True)
class ScaraConfig:
    """Settings of ``scara``; lengths in m, angles in rad, times in s."""

    l1: float = 1.0
    """First link length (Eq. 3.15)."""
    l2: float = 0.8
    """Second link length (Eq. 3.15)."""
    height: float = 1.0
    """D of Eq. 3.15: height of the tool point at d3 = 0."""
    joint_lo: tuple[float, float, float] = (-2.6, -2.6, 0.0)
    """Lower joint limits (θ1, θ2, d3); servo targets are clipped to them."""
    joint_hi: tuple[float, float, float] = (2.6, 2.6, 0.5)
    """Upper joint limits (θ1, θ2, d3)."""
    ref_center: tuple[float, float, float] = (0.0, 1.2, 0.25)
    """Joint reference q_r = center + amplitude sin(frequency t + phase)."""
    ref_amplitude: tuple[float, float, float] = (0.8, 0.5, 0.15)
    ref_frequency: tuple[float, float, float] = (0.4, 0.8, 1.2)
    """Angular frequencies in rad/s."""
    ref_phase: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dt: float = 0.1
    """Control period."""
    duration: float | None = None
    """Reference length; None: one period of the slowest joint (2π / min frequency), or max_steps·dt."""
    max_steps: int | None = None
    """Control steps of the reference; None: round(duration / dt)."""
    n_substeps: int = 20
    """Physics steps per control step (timestep dt / n_substeps)."""
    action_scale: tuple[float, float, float] = (0.1, 0.1, 0.05)
    """C: largest joint increment per control step (rad, rad, m)."""
    kp: tuple[float, float, float] = (50000.0, 12000.0, 5000.0)
    """Servo stiffness per joint (N·m/rad, N·m/rad, N/m)."""
    kd: tuple[float, float, float] = (900.0, 220.0, 100.0)
    """Servo damping per joint."""
    reward_coef: float = 2.0
    """The 2 of Eq. 3.22."""
    obs_error_scale: float = 0.05
    """Tracking errors are divided by this in the observation (m)."""
    observation: str = "thesis"
    """'thesis': the 10-dim vector of Eq. 3.21; 'extended': plus the error to the next reference
    point, ``(p_ref,k+1 − p) / obs_error_scale`` (13-dim; module docstring)."""
    rsi: tuple[float, float] = (0.0, 1.0)
    """Default RSI window [start_lo, start_hi] (fractions of the reference)."""
    et_threshold: float = 0.1
    """Early termination counts steps whose position error exceeds this (m)."""
    et_limit: float = 20.0
    """Episode terminates when the counter exceeds this."""
    impl: str = "jax"
    """MJX backend: 'jax' (MJX's JAX implementation) or 'warp' (MuJoCo Warp, pip install -e ".[warp]";
    :mod:`envs_mjx.backend`)."""
    jacobian: str = "auto"
    """How MJX factorises the mass matrix: 'auto', 'dense' or 'sparse' (:mod:`envs_mjx.backend`)."""

    def validate(self) -> None:
        check_choice("observation", self.observation, OBSERVATIONS)
        check_range("l1", self.l1, 0.0, lo_open=True)
        check_range("l2", self.l2, 0.0, lo_open=True)
        check_range("height", self.height, 0.0, lo_open=True)
        for name in ("joint_lo", "joint_hi", "ref_center", "ref_amplitude", "ref_frequency", "ref_phase"):
            check_vector(name, getattr(self, name), 3)
        check_vector("ref_amplitude", self.ref_amplitude, 3, lo=0.0)
        check_vector("ref_frequency", self.ref_frequency, 3, lo=0.0)
        for i, joint in enumerate(JOINTS):
            lo, hi = self.joint_lo[i], self.joint_hi[i]
            if not lo < hi:
                raise ConfigError(f"joint_lo[{i}]={lo!r} must be below joint_hi[{i}]={hi!r} ({joint})")
            c, a = self.ref_center[i], self.ref_amplitude[i]
            if c - a < lo or c + a > hi:
                raise ConfigError(
                    f"ref_center[{i}] ± ref_amplitude[{i}] = [{c - a:g}, {c + a:g}] leaves the {joint} range "
                    f"[{lo:g}, {hi:g}]; reduce ref_amplitude or move ref_center"
                )
        tracking.check_timing(self)
        check_vector("action_scale", self.action_scale, 3, lo=0.0)
        if min(self.action_scale) <= 0.0:
            raise ConfigError(f"action_scale={self.action_scale!r} must be positive in every element")
        check_vector("kp", self.kp, 3, lo=0.0)
        check_vector("kd", self.kd, 3, lo=0.0)
        check_range("reward_coef", self.reward_coef, 0.0, lo_open=True)
        check_range("obs_error_scale", self.obs_error_scale, 0.0, lo_open=True)
        tracking.check_episode(self)
        backend.check_impl(self.impl)
        check_choice("jacobian", self.jacobian, backend.JACOBIANS)

    def resolved(self) -> ScaraConfig:
        """This config with ``duration`` and ``max_steps`` filled in (and checked to agree)."""
        return dataclasses.replace(self, **tracking.resolve_length(self, _default_scara_duration(self)))


def _default_scara_duration(cfg: ScaraConfig) -> float:
    freqs = [f for f in cfg.ref_frequency if f > 0.0]
    return 2.0 * math.pi / min(freqs) if freqs else 10.0


def build_model(cfg: ScaraConfig) -> mujoco.MjModel:
    """Compile ``assets/scara.xml`` with the geometry, ranges, gains and timestep of ``cfg``."""
    spec = mujoco.MjSpec.from_file(ASSET)
    l1, l2, d = cfg.l1, cfg.l2, cfg.height
    spec.geom("column").fromto = [0, 0, 0, 0, 0, d]
    spec.body("link1").pos = [0, 0, d]
    spec.geom("link1").fromto = [0, 0, 0, l1, 0, 0]
    spec.body("link2").pos = [l1, 0, 0]
    spec.geom("link2").fromto = [0, 0, 0, l2, 0, 0]
    spec.body("tool").pos = [l2, 0, 0]
    for i, name in enumerate(JOINTS):
        act = spec.actuator(name)
        act.gainprm[0] = cfg.kp[i]
        act.biasprm[1] = -cfg.kp[i]
        act.biasprm[2] = -cfg.kd[i]
        act.ctrlrange = [cfg.joint_lo[i], cfg.joint_hi[i]]
    spec.option.timestep = cfg.dt / cfg.n_substeps
    return spec.compile()


def forward_kinematics(q: jax.Array, l1: float, l2: float, height: float) -> jax.Array:
    """Eq. 3.15: end-effector position ``[..., 3]`` of joints ``q = [θ1, θ2, d3]`` (``[..., 3]``)."""
    t1, t2, d3 = q[..., 0], q[..., 1], q[..., 2]
    return jnp.stack(
        [l1 * jnp.cos(t1) + l2 * jnp.cos(t1 - t2), l1 * jnp.sin(t1) + l2 * jnp.sin(t1 - t2), height - d3], axis=-1
    )


def forward_velocity(q: jax.Array, qd: jax.Array, l1: float, l2: float) -> jax.Array:
    """Time derivative of Eq. 3.15: end-effector velocity ``[..., 3]`` for joint rates ``qd``."""
    t1, t2 = q[..., 0], q[..., 1]
    w1, w12 = qd[..., 0], qd[..., 0] - qd[..., 1]
    return jnp.stack(
        [
            -l1 * jnp.sin(t1) * w1 - l2 * jnp.sin(t1 - t2) * w12,
            l1 * jnp.cos(t1) * w1 + l2 * jnp.cos(t1 - t2) * w12,
            -qd[..., 2],
        ],
        axis=-1,
    )


def scara_reward(err: jax.Array, coef: float = 2.0) -> jax.Array:
    """Eq. 3.22: ``exp(−coef · |e|²)`` for position errors ``err [..., 3]`` (m)."""
    return jnp.exp(-coef * jnp.sum(err**2, axis=-1))


class Scara(tracking.TrackingEnv):
    """SCARA trajectory tracking; see the module docstring for model, action, observation, reward."""

    name = "scara"
    Config = ScaraConfig
    action_size = 3
    axis_names = ("x", "y", "z")
    wrap_axes = (False, False, False)
    build_model = staticmethod(build_model)

    def __init__(self, config: ScaraConfig | None = None, **overrides: Any):
        super().__init__(config, **overrides)
        cfg = self.config
        self._lo = jnp.asarray(cfg.joint_lo, jnp.float32)
        self._hi = jnp.asarray(cfg.joint_hi, jnp.float32)
        self._xy_scale = cfg.l1 + cfg.l2
        self._z_mid = cfg.height - 0.5 * (cfg.joint_lo[2] + cfg.joint_hi[2])
        self._z_half = 0.5 * (cfg.joint_hi[2] - cfg.joint_lo[2])

    @property
    def observation_size(self) -> int:
        return 13 if self.config.observation == "extended" else 10

    # ------------------------------------------------------------- reference
    def joint_reference(self, k: jax.Array) -> JointReference:
        """Joint reference at control step ``k`` (time ``k · dt``): q, qd, qdd ``[3]``."""
        cfg = self.config
        return joint_sinusoids(
            jnp.asarray(k, jnp.float32) * cfg.dt, cfg.ref_center, cfg.ref_amplitude, cfg.ref_frequency, cfg.ref_phase
        )

    def reference(self, k: jax.Array) -> tuple[jax.Array, jax.Array]:
        """End-effector reference ``(ref_pos [3], ref_vel [3])`` at step ``k`` (Eq. 3.15 of the joint reference)."""
        r = self.joint_reference(k)
        cfg = self.config
        return (
            forward_kinematics(r.q, cfg.l1, cfg.l2, cfg.height),
            forward_velocity(r.q, r.qd, cfg.l1, cfg.l2),
        )

    def reference_action(self, k: jax.Array) -> jax.Array:
        """The reference's own command at step ``k``: ``(q_r(k+1) − q_r(k)) / C``, ``[3]`` (unclipped)."""
        return (self.joint_reference(k + 1).q - self.joint_reference(k).q) / self.action_scale

    def forward_kinematics(self, q: jax.Array) -> jax.Array:
        """Eq. 3.15 with this env's l1, l2, D."""
        cfg = self.config
        return forward_kinematics(q, cfg.l1, cfg.l2, cfg.height)

    # ---------------------------------------------------------------- helpers
    def _obs(self, q: jax.Array, ee: jax.Array, err: jax.Array, k: jax.Array) -> jax.Array:
        """Eq. 3.21 with the scaling of the module docstring, ``[10]``; ``extended``: plus
        ``(p_ref(k + 1) − ee) / s_e``, ``[13]`` (``k`` the step ``err`` is scored against)."""
        s = self.config.obs_error_scale
        parts = [
            jnp.stack([jnp.sin(q[0]), jnp.cos(q[0]), jnp.sin(q[1]), jnp.cos(q[1])]),
            ee[:2] / self._xy_scale,
            ((ee[2] - self._z_mid) / self._z_half)[None],
            err / s,
        ]
        if self.config.observation == "extended":
            parts.append((self.reference(k + 1)[0] - ee) / s)
        return jnp.concatenate(parts)

    def _metrics(self, r_track, err, et_count, terminated, invalid) -> dict[str, jax.Array]:
        a = jnp.abs(err)
        return {
            "reward_tracking": r_track,
            "pos_error": jnp.linalg.norm(err),
            "err_x": a[0],
            "err_y": a[1],
            "err_z": a[2],
            "et_count": et_count,
            "early_termination": terminated,
            "invalid_action": invalid,
        }

    # -------------------------------------------------------------------- api
    def reset(self, rng: jax.Array, params: Mapping[str, Any] | None = None) -> State:
        """Start on the reference state (joint positions and rates) of a step drawn by RSI."""
        p, k0 = self._start(rng, params)
        r = self.joint_reference(k0)
        data = self._data0.replace(qpos=r.q, qvel=r.qd, ctrl=r.q)
        ee = self.forward_kinematics(r.q)
        ref_pos, ref_vel = self.reference(k0)
        err = ref_pos - ee
        zero = jnp.zeros((), jnp.float32)
        metrics = self._metrics(zero, err, zero, zero, zero)
        return self._first_state(
            data, self._obs(r.q, ee, err, k0), metrics, p, k0, q=r.q, ee_pos=ee, ref_pos=ref_pos, ref_vel=ref_vel
        )

    def step(self, state: State, action: jax.Array) -> State:
        """Apply ``Δq = C ⊙ a`` as new servo targets, simulate ``n_substeps``, score against step ``k + 1``."""
        self.check_action(action)
        cfg = self.config
        a, invalid = sanitize_action(action)
        data = state.pipeline_state
        target = jnp.clip(data.qpos + self.action_scale * a, self._lo, self._hi)
        data = data.replace(ctrl=target)
        data = jax.lax.fori_loop(0, cfg.n_substeps, lambda _, d: mjx.step(self.mjx_model, d), data)

        k = self._next_k(state)
        q = data.qpos
        ee = self.forward_kinematics(q)
        ref_pos, ref_vel = self.reference(k)
        err = ref_pos - ee
        r_track = scara_reward(err, cfg.reward_coef)
        reward, done, counters = self._end_of_step(state, k, jnp.linalg.norm(err), r_track)
        metrics = self._metrics(r_track, err, counters["et_count"], counters["terminated"], invalid)
        obs = self._obs(q, ee, err, k)
        info = dict(q=q, ee_pos=ee, ref_pos=ref_pos, ref_vel=ref_vel, **counters)
        return self._next_state(state, data, obs, reward, done, metrics, k, **info)
