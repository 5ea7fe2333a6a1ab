"""Transition type shared by the replay buffers and the off-policy agents."""

from __future__ import annotations

from typing import NamedTuple

import jax

__all__ = ["Transition"]


class Transition(NamedTuple):
    """One environment transition ``(s, a, r, s', d)`` (leading axes are the caller's).

    Attributes:
      obs: ``[..., O]`` observation ``s_t``.
      action: ``[..., A]`` action ``a_t`` in [-1, 1] (before the env's scale C).
      reward: ``[...]`` reward ``r_t``.
      next_obs: ``[..., O]`` next observation ``s_{t+1}`` (the terminal one at an episode end).
      terminated: ``[...]`` 1.0 when ``s_{t+1}`` is terminal (success or failure). A time-limit
        truncation is *not* termination: the critic target still bootstraps there.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    terminated: jax.Array
