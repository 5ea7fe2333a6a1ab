"""Reference trajectories of the tracking environments (thesis §3.5.3–3.5.4).

All functions are pure and take a time ``t`` in seconds (a scalar; vmap for many times).

Planar references (mobile robot, thesis §3.5.4):

* ``sine`` (Eq. 3.24–3.25): ``x_r = t``, ``y_r = 2 sin(0.2 t)``; heading ``θ_r = arctan(ẏ_r / ẋ_r)``
  in ``(-π/2, π/2)``.
* ``ellipse`` (Eq. 3.26–3.27): ``x_r = sin(πt/8)``, ``y_r = -2 cos(πt/8)``; heading by the quadrant
  rule of Eq. 3.27, in ``[0, 2π)``.

Each gives the reference pose ``[x_r, y_r, θ_r]``, its rate ``[ẋ_r, ẏ_r, θ̇_r]`` and the reference
commands ``[v_r, w_r]`` of the unicycle model (Eq. 3.18): ``v_r = |(ẋ_r, ẏ_r)|`` (the heading is the
direction of motion, so ``v_r >= 0``) and ``w_r = θ̇_r = (ẋ_r ÿ_r − ẏ_r ẍ_r) / (ẋ_r² + ẏ_r²)``.

Joint references (SCARA, thesis §3.5.3): sinusoids ``q_r = c + A sin(ω t + φ)`` per joint.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "PLANAR_TRAJECTORIES",
    "JointReference",
    "PlanarReference",
    "default_duration",
    "ellipse_xy",
    "heading_arctan",
    "heading_quadrant",
    "joint_sinusoids",
    "planar_reference",
    "sine_xy",
]

PLANAR_TRAJECTORIES = ("sine", "ellipse")

# One period of each curve: y_r = 2 sin(0.2 t) repeats after 10π s; the ellipse closes after 16 s.
_DEFAULT_DURATION = {"sine": 10.0 * math.pi, "ellipse": 16.0}


def default_duration(name: str) -> float:
    """One period of the planar reference ``name`` in seconds (``sine``: 10π, ``ellipse``: 16)."""
    return _DEFAULT_DURATION[name]


class PlanarReference(NamedTuple):
    """Reference state of a planar trajectory at one time.

    pos: ``[3]`` ``(x_r, y_r, θ_r)``; vel: ``[3]`` ``(ẋ_r, ẏ_r, θ̇_r)``; cmd: ``[2]`` ``(v_r, w_r)``.
    """

    pos: jax.Array
    vel: jax.Array
    cmd: jax.Array


class JointReference(NamedTuple):
    """Joint reference at one time: q, qd, qdd, each ``[J]``."""

    q: jax.Array
    qd: jax.Array
    qdd: jax.Array


def sine_xy(t: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Eq. 3.24: position, velocity and acceleration of ``(t, 2 sin(0.2 t))``, each ``[2]``."""
    t = jnp.asarray(t, jnp.float32)
    s, c = jnp.sin(0.2 * t), jnp.cos(0.2 * t)
    pos = jnp.stack([t, 2.0 * s])
    vel = jnp.stack([jnp.ones_like(t), 0.4 * c])
    acc = jnp.stack([jnp.zeros_like(t), -0.08 * s])
    return pos, vel, acc


def ellipse_xy(t: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Eq. 3.26: position, velocity and acceleration of ``(sin(πt/8), −2 cos(πt/8))``, each ``[2]``."""
    t = jnp.asarray(t, jnp.float32)
    w = math.pi / 8.0
    s, c = jnp.sin(w * t), jnp.cos(w * t)
    pos = jnp.stack([s, -2.0 * c])
    vel = jnp.stack([w * c, 2.0 * w * s])
    acc = jnp.stack([-w * w * s, 2.0 * w * w * c])
    return pos, vel, acc


def heading_arctan(xd: jax.Array, yd: jax.Array) -> jax.Array:
    """Eq. 3.25: ``θ_r = arctan(ẏ / ẋ)`` in ``(-π/2, π/2)`` (the sine reference has ``ẋ = 1``)."""
    return jnp.arctan(yd / xd)


def heading_quadrant(xd: jax.Array, yd: jax.Array) -> jax.Array:
    """Eq. 3.27: the heading of the velocity ``(ẋ, ẏ)`` in ``[0, 2π)`` by the quadrant rule.

    ``ẋ > 0, ẏ >= 0``: arctan(ẏ/ẋ); ``ẋ > 0, ẏ < 0``: arctan(ẏ/ẋ) + 2π; ``ẋ < 0``: arctan(ẏ/ẋ) + π;
    ``ẋ = 0``: π/2 if ``ẏ >= 0`` else 3π/2.
    """
    xd = jnp.asarray(xd, jnp.float32)
    yd = jnp.asarray(yd, jnp.float32)
    base = jnp.arctan(yd / jnp.where(xd == 0.0, 1.0, xd))
    two_pi = jnp.float32(2.0 * math.pi)
    pi = jnp.float32(math.pi)
    on_axis = jnp.where(yd >= 0.0, 0.5 * pi, 1.5 * pi)
    right = jnp.where(yd >= 0.0, base, base + two_pi)
    theta = jnp.where(xd > 0.0, right, jnp.where(xd < 0.0, base + pi, on_axis))
    # arctan(ẏ/ẋ) + 2π rounds to exactly 2π in float32 when ẏ/ẋ is a tiny negative number.
    return jnp.where(theta >= two_pi, theta - two_pi, theta)


def _planar(xy_fn, heading_fn, t: jax.Array) -> PlanarReference:
    pos, vel, acc = xy_fn(t)
    speed_sq = vel[0] ** 2 + vel[1] ** 2
    theta = heading_fn(vel[0], vel[1])
    theta_dot = (vel[0] * acc[1] - vel[1] * acc[0]) / speed_sq
    return PlanarReference(
        pos=jnp.stack([pos[0], pos[1], theta]),
        vel=jnp.stack([vel[0], vel[1], theta_dot]),
        cmd=jnp.stack([jnp.sqrt(speed_sq), theta_dot]),
    )


def planar_reference(name: str, t: jax.Array) -> PlanarReference:
    """The reference state of trajectory ``name`` (``'sine'`` or ``'ellipse'``) at time ``t`` (scalar)."""
    if name == "sine":
        return _planar(sine_xy, heading_arctan, t)
    if name == "ellipse":
        return _planar(ellipse_xy, heading_quadrant, t)
    raise ValueError(f"trajectory={name!r} is not valid; choose one of {', '.join(map(repr, PLANAR_TRAJECTORIES))}")


def joint_sinusoids(
    t: jax.Array, center: jax.Array, amplitude: jax.Array, frequency: jax.Array, phase: jax.Array
) -> JointReference:
    """``q_r = c + A sin(ω t + φ)`` per joint with its first two time derivatives.

    Args:
      t: scalar time in seconds.
      center, amplitude, frequency (rad/s), phase (rad): ``[J]`` each.
    Returns:
      ``JointReference`` with ``q``, ``qd``, ``qdd`` of shape ``[J]``.
    """
    center, amplitude, frequency, phase = (jnp.asarray(v, jnp.float32) for v in (center, amplitude, frequency, phase))
    arg = frequency * jnp.asarray(t, jnp.float32) + phase
    s, c = jnp.sin(arg), jnp.cos(arg)
    return JointReference(
        q=center + amplitude * s,
        qd=amplitude * frequency * c,
        qdd=-amplitude * frequency**2 * s,
    )
