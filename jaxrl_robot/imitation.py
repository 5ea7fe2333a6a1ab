"""Learning from a teacher: the pieces every trainer's pre-training stage shares.

* :func:`imitation_loss` — the squared distance of the policy's action to the teacher's
  (thesis §5.6 Algorithm 9 with a searched action, §6.1.2 with an expert driver).
* :func:`expert_of` — an env's scripted ``expert(state) -> action`` (unbatched), if it has one.
* :func:`teacher_share` — the fraction of steps the teacher drives while the policy learns to
  imitate it (DAgger's β, Ross et al. 2011), falling linearly to 0 over the stage.
* :func:`mix_teacher` — per-lane choice between the policy's action and the teacher's.

Envs that offer ``expert``: ``racecar`` (:func:`envs_mjx.racecar.expert_action`).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from brax.envs.base import State

from jaxrl_robot.acting import per_lane_keys

__all__ = ["expert_of", "imitation_loss", "mix_teacher", "teacher_share"]


def expert_of(env: object) -> Callable[[State], jax.Array] | None:
    """The env's ``expert(state) -> action [A]`` (unbatched, reads ``state.pipeline_state``), or None."""
    return getattr(env, "expert", None)


def imitation_loss(mean: jax.Array, target: jax.Array, mask: jax.Array, count: jax.Array) -> jax.Array:
    """``Σ_i mask_i ‖μ(s_i) − a*_i‖² / count``: ``mean, target [B, A]``, ``mask [B]``, ``count []``.

    ``count`` is the number of examples in the whole mini-batch (over every device, at least 1),
    so that summing this loss's gradients over devices gives the gradient of the global mean.
    """
    return jnp.sum(mask * jnp.sum((mean - target) ** 2, axis=-1)) / jnp.maximum(count, 1.0)


def teacher_share(iteration: jax.Array, stage_iterations: int, start: float) -> jax.Array:
    """``β(i) = start · (1 − i / I)`` for ``i < I`` (the stage's ``I`` iterations), then 0: ``[] float32``."""
    frac = jnp.asarray(iteration, jnp.float32) / max(stage_iterations, 1)
    return jnp.where(frac < 1.0, start * (1.0 - frac), 0.0).astype(jnp.float32)


def mix_teacher(
    key: jax.Array, lane_ids: jax.Array, action: jax.Array, teacher: jax.Array, share: jax.Array
) -> jax.Array:
    """Each lane ``i`` takes ``teacher[i]`` with probability ``share`` (a coin keyed by ``fold_in(key,
    lane_ids[i])``), else ``action[i]``: ``action, teacher [B, A]`` -> ``[B, A]``."""
    coin = jax.vmap(lambda k: jax.random.uniform(k))(per_lane_keys(key, lane_ids))
    return jnp.where((coin < share)[:, None], teacher, action)
