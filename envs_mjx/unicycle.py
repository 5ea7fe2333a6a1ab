"""``unicycle`` — differential-drive mobile robot trajectory tracking (thesis §3.5.1, §3.5.4).

Action ``a ∈ [-1, 1]^2``: the forward speed and turn rate ``(v, w) = C ⊙ a`` in the robot frame,
``C = action_scale``.

Physics modes (``mode``):

* ``kinematic`` — the thesis's update: Eq. 3.18 gives ``(ẋ, ẏ, θ̇) = (v cos θ, v sin θ, w)`` at the
  current heading and one Euler step of ``dt`` moves the pose (thesis §3.5.4).
* ``dynamic`` (default) — MJX integrates a chassis of mass ``m`` and yaw inertia ``I``
  (``assets/unicycle.xml``) for ``n_substeps`` steps.  At every physics step a low-level velocity
  controller measures the body's ``(v, w)``, asks for the accelerations
  ``v̇_d = k_v (v_cmd − v)``, ``ẇ_d = k_w (w_cmd − w)`` and inverts Eq. 3.20 for the wheel torques
  ``τ1 + τ2 = R m v̇_d``, ``τ1 − τ2 = R I ẇ_d / L`` (each clipped to ``torque_limit``).  The MJCF
  applies those torques through Eq. 3.20 exactly (site actuators with gears ``1/R`` and ``±L/R``).
  **Lateral slip (Eq. 3.17)** is held near zero by the wheels' lateral grip, modelled as a stiff
  viscous force ``−c v_lat`` (``lateral_damping``) integrated implicitly by ``implicitfast``: in a
  steady turn the slip speed is ``m v w / c``, and because the heading advances by ``w h`` after
  each velocity solve (``h`` the physics timestep) the slip measured at the end of a step is about
  ``v w (h + m / c)`` — under 1 cm/s (< 1 % of the speed) at the defaults.
  Wheel speeds follow Eq. 3.19: ``ω1 = (v + wL)/R``, ``ω2 = (v − wL)/R`` (``info["wheel_speed"]``).

Trajectories (``trajectory``): ``sine`` (Eq. 3.24–3.25) and ``ellipse`` (Eq. 3.26–3.27, heading in
``[0, 2π)``), see :mod:`envs_mjx.trajectories`; ``duration`` defaults to one period (10π s, 16 s).
Reaching the end of the reference terminates the episode (``info["ref_end"]``).

Observation (14-dim, thesis §3.5.4), each element scaled to a similar range::

    [x / s_x, y / s_y, sin θ, cos θ, ẋ / C_v, ẏ / C_v, θ̇ / C_w,
     e_x / s_e, e_y / s_e, e_sinθ, e_cosθ, e_ẋ / C_v, e_ẏ / C_v, e_θ̇ / C_w]

with ``s_x, s_y`` the largest ``|x_r|``, ``|y_r|`` of the reference (at least 1; ``obs_pos_scale``
overrides), ``C = (C_v, C_w)`` the action scale, ``s_e = obs_error_scale`` and errors
``e = reference − real`` in the world frame; velocities are the world-frame ``(ẋ, ẏ, θ̇)``.

``observation="extended"`` appends a 5-element preview of the reference in the robot frame, in
action units (19-dim)::

    [d_∥ / (C_v dt), d_⊥ / (C_v dt), wrap(θ_r,k+1 − θ) / (C_w dt), v_r,k+½ / C_v, w_r,k+½ / C_w]

with ``(d_∥, d_⊥)`` the step ``(x_r,k+1 − x, y_r,k+1 − y)`` to the next reference position rotated
into the robot frame (Eq. 3.16) and ``(v_r, w_r)`` the reference's command at the middle of the
step (:meth:`Unicycle.reference_action`).  The thesis's 14 elements carry the same information
(the reference rate is ``vel + e_vel``), but only through products with ``sin θ``/``cos θ`` and an
extrapolation in time; the preview states it as the quantities the action must match.

Reward (Eq. 3.23), unscaled errors: ``r_p = exp(−a_p (e_x² + e_y² + e_sinθ² + e_cosθ²))``,
``r_v = exp(−a_v (e_ẋ² + e_ẏ² + e_θ̇²))``, ``r = ω_p r_p + ω_v r_v`` with ``ω_p = 0.4``, ``ω_v = 0.6``,
``a_p = 1``, ``a_v = 2``; zero from the step that triggers early termination on.

``state.info``: ``pose`` and ``ee_pos`` ``(x, y, θ)`` (θ continuous, not wrapped), ``ref_pos``
``(x_r, y_r, θ_r)``, ``vel``, ``ref_vel`` ``(ẋ, ẏ, θ̇)``, ``k``, ``t``, ``wheel_speed``,
``wheel_torque`` (last physics step; zero in ``kinematic``), ``et_count``, ``terminated``,
``ref_end``, ``params``.  Orientation errors in metrics and test episodes are wrapped to ``[-π, π)``.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from envs_mjx import backend, tracking
from envs_mjx.base import State, sanitize_action
from envs_mjx.config import ConfigError, check_choice, check_range, check_vector
from envs_mjx.trajectories import PLANAR_TRAJECTORIES, PlanarReference, default_duration, planar_reference

__all__ = [
    "MODES",
    "OBSERVATIONS",
    "Unicycle",
    "UnicycleConfig",
    "build_model",
    "unicycle_reward",
    "wheel_speeds",
    "wheel_torques",
]

ASSET = os.path.join(os.path.dirname(__file__), "assets", "unicycle.xml")
MODES = ("dynamic", "kinematic")
OBSERVATIONS = ("thesis", "extended")

# Per-trajectory action scale C = (v_max, w_max): the sine needs v ≈ 1.08 m/s and |w| ≤ 0.08 rad/s,
# the ellipse v ≤ π/4 m/s and w ≤ π/4 rad/s (thesis: only the action scale differs between them).
_DEFAULT_ACTION_SCALE = {"sine": (1.5, 0.5), "ellipse": (1.2, 1.2)}


@dataclasses.dataclass(frozen=True)
class UnicycleConfig:
    """Settings of ``unicycle``; SI units."""

    mode: str = "dynamic"
    """'dynamic' (MJX body + wheel-torque controller) or 'kinematic' (Euler update of Eq. 3.18)."""
    trajectory: str = "sine"
    """'sine' (Eq. 3.24) or 'ellipse' (Eq. 3.26)."""
    dt: float = 0.1
    """Control period."""
    duration: float | None = None
    """Reference length; None: one period (sine 10π s, ellipse 16 s), or max_steps·dt."""
    max_steps: int | None = None
    """Control steps of the reference; None: round(duration / dt)."""
    n_substeps: int = 10
    """Physics steps per control step in 'dynamic' (timestep dt / n_substeps)."""
    action_scale: tuple[float, float] | None = None
    """C = (v_max, w_max); None: (1.5, 0.5) for sine, (1.2, 1.2) for ellipse."""
    mass: float = 5.0
    """m of Eq. 3.20."""
    inertia: float = 0.2
    """I of Eq. 3.20 (yaw)."""
    wheel_radius: float = 0.05
    """R of Eq. 3.19–3.20."""
    half_axle: float = 0.15
    """L of Eq. 3.19–3.20."""
    ctrl_gain: tuple[float, float] = (30.0, 30.0)
    """(k_v, k_w): velocity-controller bandwidths in 1/s."""
    torque_limit: float = 10.0
    """Largest wheel torque (N·m)."""
    lateral_damping: float = 5000.0
    """c: lateral grip of the wheels (N·s/m)."""
    omega_p: float = 0.4
    """ω_p of Eq. 3.23."""
    omega_v: float = 0.6
    """ω_v of Eq. 3.23."""
    a_p: float = 1.0
    """a_p of Eq. 3.23."""
    a_v: float = 2.0
    """a_v of Eq. 3.23."""
    obs_error_scale: float = 0.25
    """Position errors are divided by this in the observation (m)."""
    obs_pos_scale: tuple[float, float] | None = None
    """(s_x, s_y); None: largest |x_r|, |y_r| of the reference, at least 1."""
    observation: str = "thesis"
    """'thesis': the 14-dim vector of §3.5.4; 'extended': those 14 plus 5 reference-preview
    elements in the robot frame (the step to the next reference pose and the reference's own
    command for this step, both in action units; module docstring)."""
    rsi: tuple[float, float] = (0.0, 1.0)
    """Default RSI window [start_lo, start_hi] (fractions of the reference)."""
    et_threshold: float = 0.3
    """Early termination counts steps whose position error exceeds this (m)."""
    et_limit: float = 20.0
    """Episode terminates when the counter exceeds this."""
    impl: str = "jax"
    """MJX backend of 'dynamic': 'jax' (MJX's JAX implementation) or 'warp' (MuJoCo Warp, pip install -e
    ".[warp]"; :mod:`envs_mjx.backend`). 'kinematic' steps no physics and takes only 'jax'."""
    jacobian: str = "auto"
    """How MJX factorises the mass matrix in 'dynamic': 'auto', 'dense' or 'sparse' (:mod:`envs_mjx.backend`)."""

    def validate(self) -> None:
        check_choice("mode", self.mode, MODES)
        check_choice("observation", self.observation, OBSERVATIONS)
        check_choice("trajectory", self.trajectory, PLANAR_TRAJECTORIES)
        tracking.check_timing(self)
        if self.action_scale is not None:
            check_vector("action_scale", self.action_scale, 2)
            if min(self.action_scale) <= 0.0:
                raise ConfigError(f"action_scale={self.action_scale!r} must be positive in every element")
        for name in ("mass", "inertia", "wheel_radius", "half_axle", "torque_limit", "obs_error_scale"):
            check_range(name, getattr(self, name), 0.0, lo_open=True)
        check_vector("ctrl_gain", self.ctrl_gain, 2, lo=0.0)
        check_range("lateral_damping", self.lateral_damping, 0.0)
        for name in ("omega_p", "omega_v", "a_p", "a_v"):
            check_range(name, getattr(self, name), 0.0)
        if self.obs_pos_scale is not None:
            check_vector("obs_pos_scale", self.obs_pos_scale, 2)
            if min(self.obs_pos_scale) <= 0.0:
                raise ConfigError(f"obs_pos_scale={self.obs_pos_scale!r} must be positive in every element")
        tracking.check_episode(self)
        backend.check_impl(self.impl, self.mode, ("dynamic",))
        check_choice("jacobian", self.jacobian, backend.JACOBIANS)

    def resolved(self) -> UnicycleConfig:
        """This config with ``duration``, ``max_steps`` and ``action_scale`` filled in."""
        fields = tracking.resolve_length(self, default_duration(self.trajectory))
        if self.action_scale is None:
            fields["action_scale"] = _DEFAULT_ACTION_SCALE[self.trajectory]
        return dataclasses.replace(self, **fields)


def build_model(cfg: UnicycleConfig) -> mujoco.MjModel:
    """Compile ``assets/unicycle.xml`` with m, I, R, L, the lateral grip and timestep of ``cfg``."""
    spec = mujoco.MjSpec.from_file(ASSET)
    body = spec.body("chassis")
    body.mass = cfg.mass
    body.inertia = [0.5 * cfg.inertia, 0.5 * cfg.inertia, cfg.inertia]
    r, l = cfg.wheel_radius, cfg.half_axle
    spec.actuator("wheel1").gear = [1.0 / r, 0, 0, 0, 0, l / r]
    spec.actuator("wheel2").gear = [1.0 / r, 0, 0, 0, 0, -l / r]
    grip = spec.actuator("lateral_grip")
    grip.gainprm[0] = cfg.lateral_damping
    grip.biasprm[2] = -cfg.lateral_damping
    spec.geom("wheel1").pos = [0, -l, 0]
    spec.geom("wheel2").pos = [0, l, 0]
    spec.option.timestep = cfg.dt / cfg.n_substeps
    return spec.compile()


def wheel_speeds(v: jax.Array, w: jax.Array, wheel_radius: float, half_axle: float) -> jax.Array:
    """Eq. 3.19: ``[ω1, ω2] = [(v + wL)/R, (v − wL)/R]``, ``[..., 2]``."""
    return jnp.stack([(v + w * half_axle) / wheel_radius, (v - w * half_axle) / wheel_radius], axis=-1)


def wheel_torques(cmd: jax.Array, v: jax.Array, w: jax.Array, cfg: UnicycleConfig) -> jax.Array:
    """Low-level velocity controller: wheel torques ``[τ1, τ2]`` from Eq. 3.20 inverted.

    ``v̇_d = k_v (v_cmd − v)``, ``ẇ_d = k_w (w_cmd − w)``; ``τ1 + τ2 = R m v̇_d``,
    ``τ1 − τ2 = R I ẇ_d / L``; each torque clipped to ``±torque_limit``.

    Args:
      cmd: ``[2]`` commanded ``(v, w)``; v, w: measured forward speed and turn rate (scalars).
    """
    kv, kw = cfg.ctrl_gain
    r, l = cfg.wheel_radius, cfg.half_axle
    total = r * cfg.mass * kv * (cmd[0] - v)
    diff = r * cfg.inertia * kw * (cmd[1] - w) / l
    tau = jnp.stack([0.5 * (total + diff), 0.5 * (total - diff)])
    return jnp.clip(tau, -cfg.torque_limit, cfg.torque_limit)


def unicycle_reward(
    pos_err: jax.Array, vel_err: jax.Array, omega_p: float, omega_v: float, a_p: float, a_v: float
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Eq. 3.23.

    Args:
      pos_err: ``[..., 4]`` ``(e_x, e_y, e_sinθ, e_cosθ)``; vel_err: ``[..., 3]`` ``(e_ẋ, e_ẏ, e_θ̇)``.
    Returns:
      ``(r, r_p, r_v)``.
    """
    r_p = jnp.exp(-a_p * jnp.sum(pos_err**2, axis=-1))
    r_v = jnp.exp(-a_v * jnp.sum(vel_err**2, axis=-1))
    return omega_p * r_p + omega_v * r_v, r_p, r_v


def _body_speed(qpos: jax.Array, qvel: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Forward speed v, turn rate w and lateral speed (Eq. 3.16) of the chassis."""
    c, s = jnp.cos(qpos[2]), jnp.sin(qpos[2])
    return qvel[0] * c + qvel[1] * s, qvel[2], -qvel[0] * s + qvel[1] * c


class Unicycle(tracking.TrackingEnv):
    """Mobile robot trajectory tracking; see the module docstring for modes, observation, reward."""

    name = "unicycle"
    Config = UnicycleConfig
    action_size = 2
    axis_names = ("x", "y", "theta")
    wrap_axes = (False, False, True)
    build_model = staticmethod(build_model)

    def __init__(self, config: UnicycleConfig | None = None, **overrides: Any):
        super().__init__(config, **overrides)
        cfg = self.config
        if cfg.obs_pos_scale is None:
            ref = jax.jit(jax.vmap(lambda k: self.reference(k).pos))(jnp.arange(cfg.max_steps + 1))
            extent = np.maximum(np.max(np.abs(np.asarray(ref[:, :2])), axis=0), 1.0)
            self._pos_scale = jnp.asarray(extent, jnp.float32)
        else:
            self._pos_scale = jnp.asarray(cfg.obs_pos_scale, jnp.float32)

    # ----------------------------------------------------------------- sizes
    @property
    def steps_mjx_physics(self) -> bool:
        """``dynamic`` mode steps MJX; ``kinematic`` mode integrates Eq. 3.18 in plain JAX."""
        return self.config.mode != "kinematic"

    @property
    def observation_size(self) -> int:
        return 19 if self.config.observation == "extended" else 14

    # ------------------------------------------------------------- reference
    def reference(self, k: jax.Array) -> PlanarReference:
        """Reference pose, rate and commands at control step ``k`` (time ``k · dt``)."""
        return planar_reference(self.config.trajectory, jnp.asarray(k, jnp.float32) * self.config.dt)

    def reference_action(self, k: jax.Array) -> jax.Array:
        """The reference's own command for step ``k``, ``[2]`` (unclipped).

        ``(v_r, w_r) / C`` at the middle of the step, ``(k + ½) · dt``: held over the step it tracks
        the reference to second order in ``dt``.
        """
        t_mid = (jnp.asarray(k, jnp.float32) + 0.5) * self.config.dt
        return planar_reference(self.config.trajectory, t_mid).cmd / self.action_scale

    # ---------------------------------------------------------------- helpers
    def _errors(self, ref: PlanarReference, pose: jax.Array, vel: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(pos_err [4] = (e_x, e_y, e_sinθ, e_cosθ), vel_err [3])``, reference − real."""
        th_r, th = ref.pos[2], pose[2]
        pos_err = jnp.stack(
            [ref.pos[0] - pose[0], ref.pos[1] - pose[1], jnp.sin(th_r) - jnp.sin(th), jnp.cos(th_r) - jnp.cos(th)]
        )
        return pos_err, ref.vel - vel

    def preview(self, k: jax.Array, pose: jax.Array) -> jax.Array:
        """The 5 reference-preview elements of ``observation="extended"`` at step ``k``, ``[5]``.

        ``[d_∥/(C_v dt), d_⊥/(C_v dt), wrap(θ_r,k+1 − θ)/(C_w dt), v_r/C_v, w_r/C_w]`` (module
        docstring); ``pose`` is the robot's ``(x, y, θ)`` at step ``k``.
        """
        dt, (c_v, c_w) = self.config.dt, self.action_scale
        nxt = self.reference(k + 1).pos
        c, s = jnp.cos(pose[2]), jnp.sin(pose[2])
        dx, dy = nxt[0] - pose[0], nxt[1] - pose[1]
        step = jnp.stack([c * dx + s * dy, -s * dx + c * dy]) / (c_v * dt)  # Eq. 3.16
        turn = tracking.wrap_angle(nxt[2] - pose[2]) / (c_w * dt)
        return jnp.concatenate([step, turn[None], self.reference_action(k)])

    def _obs(self, pose: jax.Array, vel: jax.Array, pos_err: jax.Array, vel_err: jax.Array, k: jax.Array) -> jax.Array:
        """The 14-dim (``thesis``) or 19-dim (``extended``) observation of the module docstring."""
        vscale = self.action_scale[jnp.array([0, 0, 1])]  # C_v, C_v, C_w
        parts = [
            pose[:2] / self._pos_scale,
            jnp.stack([jnp.sin(pose[2]), jnp.cos(pose[2])]),
            vel / vscale,
            pos_err[:2] / self.config.obs_error_scale,
            pos_err[2:],
            vel_err / vscale,
        ]
        if self.config.observation == "extended":
            parts.append(self.preview(k, pose))
        return jnp.concatenate(parts)

    def _metrics(self, r_p, r_v, ref, pose, lateral, et_count, terminated, invalid) -> dict[str, jax.Array]:
        err = tracking.axis_errors(ref.pos, pose, self.wrap_axes)
        return {
            "r_p": r_p,
            "r_v": r_v,
            "pos_error": jnp.linalg.norm(err[:2]),
            "err_x": jnp.abs(err[0]),
            "err_y": jnp.abs(err[1]),
            "err_theta": jnp.abs(err[2]),
            "lateral_velocity": jnp.abs(lateral),
            "et_count": et_count,
            "early_termination": terminated,
            "invalid_action": invalid,
        }

    def _advance(self, data: mjx.Data, cmd: jax.Array) -> tuple[mjx.Data, jax.Array]:
        """One control step in the configured mode; returns the new data and the last wheel torques."""
        cfg = self.config
        if cfg.mode == "kinematic":
            th = data.qpos[2]
            vel = jnp.stack([cmd[0] * jnp.cos(th), cmd[0] * jnp.sin(th), cmd[1]])  # Eq. 3.18
            return data.replace(qpos=data.qpos + vel * cfg.dt, qvel=vel), jnp.zeros(2, jnp.float32)

        def substep(_, carry):
            d, _tau = carry
            v, w, _ = _body_speed(d.qpos, d.qvel)
            tau = wheel_torques(cmd, v, w, cfg)
            d = d.replace(ctrl=jnp.concatenate([tau, jnp.zeros(1, tau.dtype)]))
            return mjx.step(self.mjx_model, d), tau

        return jax.lax.fori_loop(0, cfg.n_substeps, substep, (data, jnp.zeros(2, jnp.float32)))

    def model_reward(self, state: State, action: jax.Array) -> jax.Array:
        """The reward ``action`` would earn by the known kinematics: ``[A] -> []`` (unbatched).

        One Euler step of Eq. 3.18 over ``dt`` from the pose in ``state`` with ``(v, w) = C ⊙ a``
        (``a`` clipped to [-1, 1]), scored by Eq. 3.23 against the reference at step ``k + 1``
        (before early termination zeroes anything).  In ``kinematic`` mode this is the reward
        :meth:`step` returns; in ``dynamic`` mode an estimate that ignores the body's inertia.
        The action search of two-stage training (thesis §5.6, Algorithm 9) ranks candidates by it.
        """
        self.check_action(action, "model_reward")
        cfg = self.config
        cmd = self.action_scale * jnp.clip(action, -1.0, 1.0)
        pose = state.info["pose"]
        vel = jnp.stack([cmd[0] * jnp.cos(pose[2]), cmd[0] * jnp.sin(pose[2]), cmd[1]])
        pos_err, vel_err = self._errors(self.reference(self._next_k(state)), pose + vel * cfg.dt, vel)
        return unicycle_reward(pos_err, vel_err, cfg.omega_p, cfg.omega_v, cfg.a_p, cfg.a_v)[0]

    # -------------------------------------------------------------------- api
    def reset(self, rng: jax.Array, params: Mapping[str, Any] | None = None) -> State:
        """Start on the reference pose and velocity of a step drawn by RSI."""
        cfg = self.config
        p, k0 = self._start(rng, params)
        ref = self.reference(k0)
        data = self._data0.replace(qpos=ref.pos, qvel=ref.vel)
        pose, vel = ref.pos, ref.vel
        pos_err, vel_err = self._errors(ref, pose, vel)
        zero = jnp.zeros((), jnp.float32)
        return self._first_state(
            data,
            self._obs(pose, vel, pos_err, vel_err, k0),
            self._metrics(zero, zero, ref, pose, zero, zero, zero, zero),
            p,
            k0,
            pose=pose,
            ee_pos=pose,
            vel=vel,
            ref_pos=ref.pos,
            ref_vel=ref.vel,
            wheel_speed=wheel_speeds(ref.cmd[0], ref.cmd[1], cfg.wheel_radius, cfg.half_axle),
            wheel_torque=jnp.zeros(2, jnp.float32),
        )

    def step(self, state: State, action: jax.Array) -> State:
        """Command ``(v, w) = C ⊙ a`` for one control step and score against step ``k + 1``."""
        self.check_action(action)
        cfg = self.config
        a, invalid = sanitize_action(action)
        cmd = self.action_scale * a
        data, tau = self._advance(state.pipeline_state, cmd)

        k = self._next_k(state)
        ref = self.reference(k)
        pose, vel = data.qpos, data.qvel
        v, w, lateral = _body_speed(pose, vel)
        if cfg.mode == "kinematic":
            lateral = jnp.zeros_like(lateral)  # the Euler update moves along the heading it used (Eq. 3.17)
        pos_err, vel_err = self._errors(ref, pose, vel)
        r, r_p, r_v = unicycle_reward(pos_err, vel_err, cfg.omega_p, cfg.omega_v, cfg.a_p, cfg.a_v)
        reward, done, counters = self._end_of_step(state, k, jnp.linalg.norm(pos_err[:2]), r)
        return self._next_state(
            state,
            data,
            self._obs(pose, vel, pos_err, vel_err, k),
            reward,
            done,
            self._metrics(r_p, r_v, ref, pose, lateral, counters["et_count"], counters["terminated"], invalid),
            k,
            pose=pose,
            ee_pos=pose,
            vel=vel,
            ref_pos=ref.pos,
            ref_vel=ref.vel,
            wheel_speed=wheel_speeds(v, w, cfg.wheel_radius, cfg.half_axle),
            wheel_torque=tau,
            **counters,
        )
