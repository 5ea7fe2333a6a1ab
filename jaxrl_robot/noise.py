"""Exploration noise for deterministic policies (thesis Eq. 3.7–3.8) as pure ``init`` / ``sample`` functions.

``make_ou_noise(mean, reversion, scale)`` and ``make_gaussian_noise(scale)`` return a
:class:`Noise` bundle.  The noise state is a small pytree carried in the training state,
one per environment lane (vmap ``init``/``sample`` over lanes), and re-initialised when an
episode starts.

Ornstein–Uhlenbeck (Eq. 3.8), per action dimension, with unit time step::

    x_{t+1} = x_t + σ1 (η − x_t) + σ2 W_t,   W_t ~ N(0, 1)

``η`` is the mean the process reverts to, ``σ1`` the reversion rate and ``σ2`` the scale.
It is an AR(1) process with ``E[x_t] = η + (1 − σ1)^t (x_0 − η)`` and, for ``0 < σ1 < 2``,
stationary variance ``σ2² / (σ1 (2 − σ1))``.  Each episode starts at ``x_0 = η``.

Table 6.1 (driving) is printed with the header (η, σ1, σ2), but read that way the steering
noise would have mean 0.8 and the car would always turn.  So its columns are read
as (reversion σ1, mean η, scale σ2): :data:`TABLE_6_1_DRIVING` gives steering
(σ1 0.8, η 0, σ2 0.2), acceleration (1, 0.5, 0.1) and brake (1, −0.1, 0.05).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = [
    "TABLE_6_1_DRIVING",
    "Noise",
    "NoiseState",
    "make_gaussian_noise",
    "make_noise",
    "make_ou_noise",
    "ou_stationary_std",
]

# (reversion σ1, mean η, scale σ2) per action [steering, acceleration, brake]; see module doc.
TABLE_6_1_DRIVING = {
    "reversion": (0.8, 1.0, 1.0),
    "mean": (0.0, 0.5, -0.1),
    "scale": (0.2, 0.1, 0.05),
}


class NoiseState(NamedTuple):
    """``x``: ``[A]`` current noise value (OU) or unused zeros (Gaussian)."""

    x: jax.Array


class Noise(NamedTuple):
    """``init() -> NoiseState``; ``sample(key, state) -> (noise [A], state)``."""

    init: Callable[[], NoiseState]
    sample: Callable[[jax.Array, NoiseState], tuple[jax.Array, NoiseState]]


def _vector(name: str, value: float | Sequence[float], size: int) -> jax.Array:
    v = jnp.asarray(value, jnp.float32)
    if v.ndim == 0 or v.shape == (1,):
        v = jnp.broadcast_to(v.reshape(()), (size,))
    if v.shape != (size,):
        raise ValueError(f"{name}={value!r} must be a scalar, one value or {size} values")
    return v


def make_ou_noise(
    action_size: int,
    mean: float | Sequence[float] = 0.0,
    reversion: float | Sequence[float] = 0.15,
    scale: float | Sequence[float] = 0.2,
) -> Noise:
    """Ornstein–Uhlenbeck noise (Eq. 3.8) with per-dimension ``mean`` η, ``reversion`` σ1, ``scale`` σ2.

    Raises:
      ValueError: a vector of the wrong length, ``reversion`` outside (0, 2) or negative ``scale``.
    """
    eta = _vector("mean", mean, action_size)
    theta = _vector("reversion", reversion, action_size)
    sigma = _vector("scale", scale, action_size)
    if not bool(jnp.all((theta > 0) & (theta < 2))):
        raise ValueError(f"reversion={reversion!r} is out of range; allowed (0, 2) for a stable process")
    if not bool(jnp.all(sigma >= 0)):
        raise ValueError(f"scale={scale!r} is out of range; allowed [0, inf)")

    def init() -> NoiseState:
        return NoiseState(x=eta)

    def sample(key: jax.Array, state: NoiseState) -> tuple[jax.Array, NoiseState]:
        x = state.x + theta * (eta - state.x) + sigma * jax.random.normal(key, state.x.shape)
        return x, NoiseState(x=x)

    return Noise(init=init, sample=sample)


def make_gaussian_noise(action_size: int, scale: float | Sequence[float] = 0.2, mean: float | Sequence[float] = 0.0
                        ) -> Noise:
    """Independent Gaussian noise ``N(mean, scale²)`` per step and dimension."""
    mu = _vector("mean", mean, action_size)
    sigma = _vector("scale", scale, action_size)
    if not bool(jnp.all(sigma >= 0)):
        raise ValueError(f"scale={scale!r} is out of range; allowed [0, inf)")

    def init() -> NoiseState:
        return NoiseState(x=jnp.zeros((action_size,), jnp.float32))

    def sample(key: jax.Array, state: NoiseState) -> tuple[jax.Array, NoiseState]:
        return mu + sigma * jax.random.normal(key, (action_size,)), state

    return Noise(init=init, sample=sample)


def make_noise(kind: str, action_size: int, **kwargs) -> Noise:
    """``kind`` ∈ {"ou", "gaussian"}; keyword arguments go to the factory."""
    factories = {"ou": make_ou_noise, "gaussian": make_gaussian_noise}
    if kind not in factories:
        raise ValueError(f"noise={kind!r} is not valid; choose one of {', '.join(map(repr, factories))}")
    return factories[kind](action_size, **kwargs)


def ou_stationary_std(reversion: jax.Array, scale: jax.Array) -> jax.Array:
    """Stationary standard deviation ``σ2 / sqrt(σ1 (2 − σ1))`` of the discrete OU process."""
    return scale / jnp.sqrt(reversion * (2.0 - reversion))
