"""DDPG learning: networks, optimisers and the update (Algorithm 1, lines 9–17; Algorithm 4–5).

One update: sample a mini-batch (uniformly, or prioritised with importance weights ``w``,
Eq. 3.9–3.10); critic step on ``mean w (Q(s, a) − y)²`` with ``y = r + γ (1 − d) Q'(s', μ'(s'))``
(Eq. 3.4–3.5); actor step on ``−mean Q(s, μ(s))`` (Eq. 3.6); soft target updates with ε; with
PER, new priorities ``|y − Q| + ε`` and β annealing (metric ``per_nonfinite_td``: the non-finite
errors per update that the replay replaced by its largest priority, 0 in a healthy run).  Options:
twin critics with the clipped double-Q target (Eq. 6.2), target smoothing (Eq. 6.3), the actor and
targets moving every ``policy_delay`` critic updates, reward scale and shift, target clipping.

Who computes the gradient is a :class:`Workers` strategy, so the single learner and distributed
DDPG run the same update:

* :data:`SINGLE` — one mini-batch of ``batch_size``; the learner is replicated on every device.
* :func:`worker_shards` — the synchronous workers of distributed DDPG (thesis §4.2, Algorithms
  4–5).  Each of a device's ``G`` workers samples its own prioritised mini-batch from the shared
  replay with the key ``fold_in(key, w)`` of its global index ``w`` (importance weights
  normalised within its batch, Eq. 3.10), and computes its critic gradient ``g_w^Q`` and, after
  the critic step, its actor gradient ``g_w^μ`` on that batch (its own target networks equal the
  global ones, so one replicated set stands for all); the global networks apply the means
  ``(1/m) Σ_w g_w`` (Algorithm 4, lines 4–9).  Every worker's loss is a mean over its ``b``
  rows, so the mean of the workers' gradients is the gradient of the mean of their losses, which
  is the loss of the device's ``G·b`` rows taken together: a device computes one gradient on its
  workers' concatenated batches (one network pass, not ``G``), then the mean over devices.  The
  sampled indices and new priorities of every worker are gathered in worker order and written
  back in one priority update (repeats: the last worker's value wins), so β anneals once per
  global update.  The new priorities are the TD errors of the gradient computation, as in the
  single learner.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from jaxrl_robot import parallel
from jaxrl_robot.acting import per_lane_keys
from jaxrl_robot.agents.common import make_optimizer
from jaxrl_robot.agents.ddpg.config import DDPGConfig
from jaxrl_robot.agents.ddpg.losses import (
    actor_loss,
    anchored_actor_loss,
    clipped_double_q,
    critic_loss,
    smooth_target_action,
    soft_update,
    td_target,
    twin_critic_loss,
)
from jaxrl_robot.agents.ddpg.networks import DDPGActor, DDPGCritic
from jaxrl_robot.replay import Transition, count_nonfinite
from jaxrl_robot.types import RunningStats

__all__ = ["SINGLE", "Learner", "Workers", "make_learner", "make_networks", "make_optimizer", "sample", "worker_shards"]

LOSS_METRICS = ("critic_loss", "actor_loss", "q", "td_abs")
PER_METRICS = ("per_nonfinite_td",)


class Workers(NamedTuple):
    """How the mini-batches of one update are drawn and their gradients combined.

    Attributes:
      keys: ``key -> keys``: one key (single learner) or ``[G]`` keys, one per local worker.
      map: ``fn -> fn`` applied per worker to draw its mini-batch (identity, or ``vmap`` over the
        local worker axis).
      flat: ``[G, b, ...] -> [G·b, ...]``: this device's workers' rows as one batch (identity for
        one learner).
      mean: a pytree (gradient, loss) of this device ``-> its mean over every device``.
      gather: ``[G·b, ...] -> [m · b, ...]``: every worker's rows in global worker order.
    """

    keys: Callable[[jax.Array], jax.Array]
    map: Callable[[Callable], Callable]
    flat: Callable[[Any], Any]
    mean: Callable[[Any], Any]
    gather: Callable[[Any], Any]


def _same(x: Any) -> Any:
    return x


SINGLE = Workers(keys=_same, map=_same, flat=_same, mean=_same, gather=_same)
"""One learner with one mini-batch per update, replicated on every device."""


def worker_shards(worker_ids: jax.Array) -> Workers:
    """The synchronous workers ``worker_ids [G]`` (global indices) of this device (inside ``shard_lanes``)."""

    def flat(tree: Any) -> Any:
        return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), tree)

    return Workers(keys=lambda key: per_lane_keys(key, worker_ids), map=jax.vmap, flat=flat, mean=parallel.pmean,
                   gather=parallel.all_gather)


def sample(replay: Any, workers: Workers, key: jax.Array, buf: Any) -> Any:
    """Each worker's mini-batch of ``batch_size`` from the whole replay ``buf`` (with ``key`` folded
    with its global index): ``[batch_size]`` leaves (:data:`SINGLE`) or ``[G, batch_size]``."""
    return workers.map(lambda k: replay.sample(k, buf))(workers.keys(key))


class Learner(NamedTuple):
    """The update of one DDPG configuration.

    Attributes:
      learn: ``(state, key, n, workers, actor_on=None, anchor=None) -> (state, metric sums, count)``:
        ``n`` updates if the replay holds enough transitions (else none; ``count`` is ``n`` or 0).
        ``state`` has the fields of ``DDPGState``.  ``actor_on`` (``[] bool``): False keeps the
        actor as it is while the critic learns and the targets follow (the imitation stage).
        ``anchor``: ``(key, actor params) -> []``, a behaviour-cloning loss that the actor loss
        takes with ``config.imitation_weight`` (:func:`~jaxrl_robot.agents.ddpg.losses.anchored_actor_loss`;
        the reported ``actor_loss`` includes it).
      priorities: ``(actor params, critic params, stats, rows [N]) -> [N]``: the priority
        ``min(|δ|, priority_clip)`` of raw rows under one network copy, with
        ``δ = y − Q(s, a)`` and ``y = r + γ (1 − d) Q(s', μ(s'))`` from that copy alone (a
        collecting worker has no target networks, Algorithm 6, line 9); twin critics: the mean
        of the two ``|δ_k|`` with the ``min`` target.
    """

    learn: Callable[..., tuple[Any, dict[str, jax.Array], jax.Array]]
    priorities: Callable[..., jax.Array]


def make_networks(config: DDPGConfig, action_size: int) -> tuple[DDPGActor, DDPGCritic]:
    """Actor and critic of the configured widths (thesis §3.4.1, §3.5.2)."""
    return (
        DDPGActor(action_size=action_size, hidden=tuple(config.actor_hidden), output=config.actor_output),
        DDPGCritic(hidden=tuple(config.critic_hidden)),
    )


def make_learner(
    config: DDPGConfig,
    actor: DDPGActor,
    critic: DDPGCritic,
    replay: Any,
    actor_tx: optax.GradientTransformation,
    critic_tx: optax.GradientTransformation,
    norm: Callable[[RunningStats, jax.Array], jax.Array],
    min_stored: int,
) -> Learner:
    """The :class:`Learner` of ``config`` (``norm``: the acting's observation normaliser)."""

    def q_values(params: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
        """Every critic's ``Q_k(s, a)``: ``([N, O], [N, A]) -> [K, N]``."""
        if config.twin_critics:
            return jax.vmap(critic.apply, in_axes=(0, None, None))(params, obs, action)
        return critic.apply(params, obs, action)[None]

    def q_first(params: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
        """``Q1(s, a)``, the critic the actor maximises: ``([N, O], [N, A]) -> [N]``."""
        if config.twin_critics:
            return critic.apply(jax.tree.map(lambda x: x[0], params), obs, action)
        return critic.apply(params, obs, action)

    def target(actor_p: Any, critic_p: Any, tr: Transition, key: jax.Array | None) -> jax.Array:
        """``y [N]`` of normalised rows under the networks ``(actor_p, critic_p)`` (Eq. 3.5, 6.2, 6.3)."""
        next_a = actor.apply(actor_p, tr.next_obs)
        if key is not None:
            next_a = smooth_target_action(key, next_a, config.target_noise, config.target_noise_clip)
        if config.twin_critics:
            next_q = clipped_double_q(q_values(critic_p, tr.next_obs, next_a))
        else:
            next_q = critic.apply(critic_p, tr.next_obs, next_a)
        y = td_target(tr.reward * config.reward_scale + config.reward_shift, tr.terminated, next_q, config.gamma)
        if config.target_clip:
            y = jnp.clip(y, config.target_clip[0], config.target_clip[1])
        return y

    def priority_error(td: jax.Array) -> jax.Array:
        """``|δ|`` (mean over twin critics ``[K, N]``) clipped to ``priority_clip`` (when > 0): ``-> [N]``."""
        err = jnp.mean(jnp.abs(td), axis=0) if config.twin_critics else td
        return jnp.minimum(jnp.abs(err), config.priority_clip) if config.priority_clip > 0 else err

    def normalized(stats: RunningStats, tr: Transition) -> Transition:
        return tr._replace(obs=norm(stats, tr.obs), next_obs=norm(stats, tr.next_obs))

    def priorities(actor_p: Any, critic_p: Any, stats: RunningStats, rows: Transition) -> jax.Array:
        tr = normalized(stats, rows)
        td = target(actor_p, critic_p, tr, None)[None] - q_values(critic_p, tr.obs, tr.action)
        return priority_error(td if config.twin_critics else td[0])

    def learn_step(
        stats: RunningStats, workers: Workers, actor_on: jax.Array | None, anchor: Callable | None, carry: tuple,
        xs: tuple,
    ) -> tuple[tuple, dict]:
        """One update; ``xs = (key, index)`` with ``index`` the run's count of updates before this one
        (the actor and targets move when ``(index + 1) % policy_delay == 0``; where ``actor_on`` is
        False only the targets move; ``anchor`` as in :class:`Learner`)."""
        key, index = xs
        actor_p, critic_p, t_actor, t_critic, a_opt, c_opt, buf = carry
        k_sample, k_smooth = jax.random.split(key) if config.target_noise > 0 else (key, key)
        smp = workers.flat(sample(replay, workers, k_sample, buf))  # [G·b] rows of this device's workers
        tr = normalized(stats, smp.experience)
        weights = smp.weights if config.per else None
        y = target(t_actor, t_critic, tr, k_smooth if config.target_noise > 0 else None)

        def c_loss(p, tr, y, weights):
            if config.twin_critics:
                return twin_critic_loss(q_values(p, tr.obs, tr.action), y, weights)
            return critic_loss(critic.apply(p, tr.obs, tr.action), y, weights)

        (closs, td), grads = jax.value_and_grad(c_loss, has_aux=True)(critic_p, tr, y, weights)
        closs, grads = workers.mean((closs, grads))
        updates, c_opt = critic_tx.update(grads, c_opt, critic_p)
        critic_p = optax.apply_updates(critic_p, updates)

        def a_loss(p, obs):
            q = q_first(critic_p, obs, actor.apply(p, obs))
            if anchor is None:
                return actor_loss(q), q
            return anchored_actor_loss(q, anchor(jax.random.fold_in(key, 1), p), config.imitation_weight), q

        def actor_step(args: tuple) -> tuple[tuple, jax.Array, jax.Array]:
            """Actor step on ``−mean Q1(s, μ(s))`` (with the anchor, where given) and soft target updates."""
            actor_p, t_actor, t_critic, a_opt = args
            (aloss, q), grads = jax.value_and_grad(a_loss, has_aux=True)(actor_p, tr.obs)
            aloss, grads = workers.mean((aloss, grads))
            updates, a_opt = actor_tx.update(grads, a_opt, actor_p)
            actor_p = optax.apply_updates(actor_p, updates)
            t_actor = soft_update(t_actor, actor_p, config.tau)
            t_critic = soft_update(t_critic, critic_p, config.tau)
            return (actor_p, t_actor, t_critic, a_opt), aloss, q

        def hold(args: tuple) -> tuple[tuple, jax.Array, jax.Array]:
            """No actor or target step (``policy_delay``); the loss is still reported."""
            aloss, q = a_loss(args[0], tr.obs)
            return args, workers.mean(aloss), q

        def follow(args: tuple) -> tuple[tuple, jax.Array, jax.Array]:
            """No actor step, soft target updates (the actor learns elsewhere: imitation)."""
            (actor_p, t_actor, t_critic, a_opt), aloss, q = hold(args)
            t_actor = soft_update(t_actor, actor_p, config.tau)
            return (actor_p, t_actor, soft_update(t_critic, critic_p, config.tau), a_opt), aloss, q

        args = (actor_p, t_actor, t_critic, a_opt)
        move = (index + 1) % config.policy_delay == 0
        if actor_on is not None:
            branch = jnp.where(move, jnp.where(actor_on, 1, 2), 0)
            args, aloss, q = jax.lax.switch(branch, (hold, actor_step, follow), args)
        elif config.policy_delay > 1:
            args, aloss, q = jax.lax.cond(move, actor_step, hold, args)
        else:
            args, aloss, q = actor_step(args)
        actor_p, t_actor, t_critic, a_opt = args
        if config.per:
            indices, err = workers.gather((smp.indices, priority_error(td)))
            buf = replay.update_priorities(buf, indices, err)
        out = {"critic_loss": closs, "actor_loss": aloss, "q": workers.mean(jnp.mean(q)),
               "td_abs": workers.mean(jnp.mean(jnp.abs(td)))}
        if config.per:  # every worker's errors (gathered): the same count on every device
            out["per_nonfinite_td"] = count_nonfinite(err).astype(jnp.float32)
        return (actor_p, critic_p, t_actor, t_critic, a_opt, c_opt, buf), out

    def learn(
        state: Any, key: jax.Array, n: int, workers: Workers, actor_on: jax.Array | None = None,
        anchor: Callable | None = None,
    ) -> tuple[Any, dict[str, jax.Array], jax.Array]:
        carry = (state.actor_params, state.critic_params, state.target_actor_params, state.target_critic_params,
                 state.actor_opt, state.critic_opt, state.replay)

        def run(c):
            xs = (jax.random.split(key, n), state.updates + jnp.arange(n, dtype=jnp.int32))
            c, out = jax.lax.scan(lambda c_, x: learn_step(state.obs_stats, workers, actor_on, anchor, c_, x), c, xs)
            return c, jax.tree.map(jnp.sum, out), jnp.asarray(n, jnp.float32)

        def skip(c):
            zero = jnp.zeros((), jnp.float32)
            return c, dict.fromkeys(LOSS_METRICS + (PER_METRICS if config.per else ()), zero), zero

        carry, sums, count = jax.lax.cond(state.replay.size >= min_stored, run, skip, carry)
        a_p, c_p, ta, tc, ao, co, buf = carry
        state = state.replace(actor_params=a_p, critic_params=c_p, target_actor_params=ta, target_critic_params=tc,
                              actor_opt=ao, critic_opt=co, replay=buf, updates=state.updates + count.astype(jnp.int32))
        return state, sums, count

    return Learner(learn=learn, priorities=priorities)
