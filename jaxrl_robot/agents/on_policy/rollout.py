"""Acting for the on-policy family: every lane runs the current Gaussian policy (Algorithm 3, line 8;
Algorithm 7) and the iteration's data comes back as :class:`~jaxrl_robot.types.Transition` ``[N, B]``.

* :func:`collect` — ``N`` steps of every lane with a policy that has a per-lane *memory* (an LSTM's
  carries; ``()`` for a feed-forward policy), recording the memory each step started from.  A new
  episode's memory comes from :class:`StartStates`: zeros, or the start-state table's entry for the
  reference step random reference-state initialisation (RSI) starts it at (thesis §5.7,
  :mod:`jaxrl_robot.recurrent`).  :func:`sequence_resets` marks where a training sequence restarts
  from its recorded memory; :func:`update_start_table` moves the table after the rollout.
* :func:`collect_until_done` — A2C / A3C's local buffers, each lane stopping at its episode's end
  (``mask [N, B]`` of the steps taken).
* :func:`episode_sums` — the sums over the episodes that finished in a rollout, for
  :func:`~jaxrl_robot.agents.core.chunk_metrics`.

Randomness per lane is keyed by global lane index (``lane_ids``), so results do not depend on how
the lanes are spread over devices.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from jaxrl_robot.acting import rollout_until_done, rollout_with_memory
from jaxrl_robot.agents.on_policy.actor_critic import sample_lanes
from jaxrl_robot.recurrent import table_lookup, table_update
from jaxrl_robot.types import Transition

__all__ = [
    "Rollout",
    "StartStates",
    "collect",
    "collect_until_done",
    "episode_sums",
    "sequence_resets",
    "update_start_table",
]

Act = Callable[[Any, jax.Array], tuple[Any, tuple[jax.Array, jax.Array]]]
"""``(memory [B, ...], obs [B, D]) -> (memory [B, ...], (mean, log_std) [B, A])``: the acting policy."""


class StartStates(NamedTuple):
    """Where the memory of a new episode comes from.

    Attributes:
      zeros: ``batch_shape -> memory`` of zeros (``()`` for a feed-forward policy).
      use_table: start from the start-state table ``[M + 1, ...]``: an episode that RSI starts at
        reference step ``k`` (``info["k"]``) takes ``table[k]``; False: zeros.
      rate: ρ of the table's update (:func:`update_start_table`).
    """

    zeros: Callable[[tuple[int, ...]], Any]
    use_table: bool = False
    rate: float = 1.0

    def table(self, env: Env) -> Any:
        """The initial table ``[env.max_steps + 1, ...]`` of zeros, or ``()`` without one."""
        return self.zeros((env.max_steps + 1,)) if self.use_table else ()

    def of(self, table: Any, env_state: State) -> Any:
        """The memory ``[B, ...]`` of episodes starting in ``env_state`` ``[B]``."""
        if self.use_table:
            return table_lookup(table, env_state.info["k"])
        return self.zeros(env_state.done.shape)

    def first(self, table: Any) -> Any:
        """The memory one episode starts from at t = 0, unbatched: the table's entry for step 0 (zeros)."""
        return jax.tree.map(lambda x: x[0], table) if self.use_table else self.zeros(())


class Rollout(NamedTuple):
    """What :func:`collect` returns (this device's ``B`` lanes).

    Attributes:
      env_state: ``State [B]`` after the last step.
      memory: ``[B, ...]`` the memory after the last step (a new episode's where one began).
      traj: ``Transition [N, B]``.
      memory_seq: ``[N, B, ...]`` the memory each step started from.
      starts: ``[N, B]`` 1.0 where a step is the first of an episode.
      k: ``[N, B]`` the reference step of each step (``()`` without the start-state table).
      record: ``[N, B, ...]`` what the ``record`` function of :func:`collect` kept per step (``()``: none).
    """

    env_state: State
    memory: Any
    traj: Transition
    memory_seq: Any
    starts: jax.Array
    k: Any
    record: Any


def collect(
    key: jax.Array,
    env: Env,
    env_state: State,
    memory: Any,
    table: Any,
    act: Act,
    lane_ids: jax.Array,
    num_steps: int,
    starts: StartStates,
    record: Callable[[jax.Array, State], Any] | None = None,
) -> Rollout:
    """Run the policy ``act`` for ``num_steps`` (N) steps in every lane, actions drawn by :func:`sample_lanes`.

    Args:
      key: PRNG key; step ``t`` draws with ``split(key, N)[t]`` folded in with each global lane index.
      env: a batched env from ``envs_mjx.wrap_for_training``; ``env_state``: its ``State [B]``.
      memory: ``[B, ...]`` the memory of the lanes' current episodes.
      table: the start-state table (``()`` unless ``starts.use_table``).
      act: the acting policy (see :data:`Act`).
      lane_ids: ``[B]`` global lane indices.
      num_steps: N.
      starts: where a new episode's memory comes from.
      record: ``(key, state [B]) -> [B, ...]`` kept per step (PPO's action search), called with
        ``fold_in(step key, 1)``; None: nothing.
    Returns:
      the :class:`Rollout`.
    """
    first_done = env_state.done.astype(jnp.float32)

    def policy(k: jax.Array, mem: Any, s: State) -> tuple[Any, jax.Array, Any]:
        mem_next, (mean, log_std) = act(mem, s.obs)
        kept = (
            mem,
            s.info["k"] if starts.use_table else (),
            () if record is None else record(jax.random.fold_in(k, 1), s),
        )
        return mem_next, sample_lanes(k, lane_ids, mean, log_std), kept

    env_state, memory, (traj, (memory_seq, k, kept)) = rollout_with_memory(
        key, env, env_state, memory, policy, num_steps, lambda ns: starts.of(table, ns)
    )
    first = jnp.concatenate([first_done[None], traj.done[:-1]])
    return Rollout(env_state, memory, traj, memory_seq, first, k, kept)


def sequence_resets(starts: jax.Array, seq_length: int) -> jax.Array:
    """``[N, B]`` 1.0 where a step restarts from its recorded memory: at an episode start (``starts``)
    and at the start of each training sequence of ``seq_length`` steps."""
    sequence_start = (jnp.arange(starts.shape[0]) % seq_length == 0).astype(jnp.float32)
    return jnp.maximum(starts, sequence_start[:, None])


def update_start_table(starts: StartStates, table: Any, rollout: Rollout) -> Any:
    """The start-state table after ``rollout``: every reference step visited by a step that continues
    an episode moves towards the mean of those steps' memories (``recurrent.table_update``, over all
    devices); unchanged without a table."""
    if not starts.use_table:
        return table
    return table_update(table, rollout.k, rollout.memory_seq, 1.0 - rollout.starts, starts.rate)


def collect_until_done(
    key: jax.Array,
    env: Env,
    env_state: State,
    dist: Callable[[jax.Array], tuple[jax.Array, jax.Array]],
    lane_ids: jax.Array,
    num_steps: int,
) -> tuple[State, Transition, jax.Array]:
    """Fill every lane's local buffer: up to ``num_steps`` (N) steps, the lane idling after its
    episode ends (Algorithm 3, line 8; ``acting.rollout_until_done``).

    ``dist``: ``obs [B, D] -> (mean, log_std) [B, A]`` of the acting policy; ``key``, ``lane_ids``
    as in :func:`collect`.  Returns ``(env_state [B], Transition [N, B], mask [N, B])``, ``mask``
    1.0 on the steps taken (the buffer's filled slots).
    """

    def policy(k: jax.Array, obs: jax.Array) -> jax.Array:
        return sample_lanes(k, lane_ids, *dist(obs))

    return rollout_until_done(key, env, env_state, policy, num_steps)


def episode_sums(traj: Transition) -> dict[str, jax.Array]:
    """Sums over the episodes that finished in ``traj`` ``[T, B]`` (this device's lanes):
    ``episodes`` and every episode metric (a metric shaped like ``done``, its final value)."""
    done = traj.done
    sums = {"episodes": jnp.sum(done)}
    for k, v in traj.metrics.items():
        if v.shape == done.shape:
            sums[k] = jnp.sum(jnp.where(done > 0, v, 0.0))
    return sums
