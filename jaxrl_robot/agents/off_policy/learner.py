"""The off-policy family's learner loop (Algorithm 1, lines 9–17; Algorithms 4–5): what DDPG, TD3 and
SAC share around their own gradient steps.

One update: sample a mini-batch (uniformly, or prioritised with importance weights ``w``,
Eq. 3.9–3.10), normalise its observations, take the algorithm's critic step (:attr:`Update.critic`),
then — every ``policy_delay`` critic updates — its actor step and the soft target updates
(:attr:`Update.actor`, :attr:`Update.targets`); with PER, new priorities ``|δ| + ε`` (clipped to
``priority_clip``) and β annealing (metric ``per_nonfinite_td``: the non-finite errors per update
that the replay replaced by its largest priority, 0 in a healthy run).  The learner's carry is a
:class:`LearnerState`: the networks, their targets and optimisers, the algorithm's ``extras`` and the
replay, by name.

Who computes the gradient is a :class:`Workers` strategy, so the single learner and the distributed
one (thesis §4.2) run the same update:

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

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from jaxrl_robot import parallel
from jaxrl_robot.acting import per_lane_keys
from jaxrl_robot.agents.off_policy.config import OffPolicyConfig
from jaxrl_robot.agents.off_policy.losses import td_target
from jaxrl_robot.replay import count_nonfinite
from jaxrl_robot.types import RunningStats, Transition

__all__ = ["LOSS_METRICS", "SINGLE", "Learner", "LearnerState", "NetworkState", "Update", "Workers", "critic_target",
           "make_learner", "sample", "worker_shards"]  # fmt: skip

LOSS_METRICS = ("critic_loss", "actor_loss", "q", "td_abs")
PER_METRICS = ("per_nonfinite_td",)


@struct.dataclass
class NetworkState:
    """An off-policy learner's networks, their targets and their optimisers, by name (the fields that both
    :class:`LearnerState` and :class:`~jaxrl_robot.agents.off_policy.trainer.OffPolicyState` have).

    Attributes:
      actor_params, critic_params: online parameters θ^μ, θ^Q (twin critics stacked on a leading axis of 2).
      target_actor_params, target_critic_params: target parameters (``()`` where an algorithm has none:
        SAC's actor).
      actor_opt, critic_opt: optimiser states.
    """

    actor_params: Any
    critic_params: Any
    target_actor_params: Any
    target_critic_params: Any
    actor_opt: Any
    critic_opt: Any


@struct.dataclass
class LearnerState(NetworkState):
    """What one update changes, by name: the fields of the same names of an off-policy train state
    (:class:`~jaxrl_robot.agents.off_policy.trainer.OffPolicyState`): the :class:`NetworkState` and

    Attributes:
      extras: the algorithm's own learned quantities (SAC: the temperature and its optimiser state; ``()``).
      replay: the replay memory's state.
    """

    extras: Any
    replay: Any

    @classmethod
    def of(cls, state: Any) -> LearnerState:
        """The fields of ``state`` (any dataclass having them) as a :class:`LearnerState`."""
        return cls(**{f.name: getattr(state, f.name) for f in dataclasses.fields(cls)})

    def into(self, state: Any) -> Any:
        """``state`` with these fields written back."""
        return state.replace(**{f.name: getattr(self, f.name) for f in dataclasses.fields(self)})


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


def critic_target(config: OffPolicyConfig, tr: Transition, next_v: jax.Array) -> jax.Array:
    """The critic's target ``y = clip(r·reward_scale + reward_shift + γ (1 − d) v')`` (Eq. 3.5): ``[N] -> [N]``,
    ``next_v`` the algorithm's value of ``s'`` (DDPG: ``Q'(s', μ'(s'))``; twin critics: their minimum, Eq. 6.2),
    clipped to ``target_clip`` where given."""
    y = td_target(tr.reward * config.reward_scale + config.reward_shift, tr.termination, next_v, config.gamma)
    if config.target_clip:
        y = jnp.clip(y, config.target_clip[0], config.target_clip[1])
    return y


Anchor = Callable[[jax.Array, Any], jax.Array]
"""``(key, actor params) -> []``: a behaviour-cloning loss the actor loss takes with ``imitation_weight``."""


class Update(NamedTuple):
    """One algorithm's gradient steps on a normalised mini-batch ``tr [N]`` (its observations normalised).

    Attributes:
      sample_key: ``key -> key`` the update's mini-batch is drawn with (from the update's ``key``, which
        every function below also gets).
      critic: ``(ls, tr, weights [N] | None, key, workers) -> (ls, loss [], td)``: the critic step (the loss
        and gradient averaged by ``workers.mean``); ``td`` the TD errors ``[N]``, or ``[K, N]`` of ``K`` critics.
      actor: ``(ls, tr, key, workers, anchor | None) -> (ls, loss [], q [N])``: the actor step (and the
        algorithm's own, e.g. SAC's temperature), not the targets; ``q`` the critic's value of the policy.
      actor_loss: ``(ls, tr, key, workers, anchor | None) -> (loss [], q [N])``: the same loss, no step.
      targets: ``ls -> ls``: the soft updates of the target networks.
      td_error: ``(actor params, critic params, tr) -> td`` under one network copy, no targets (the
        priorities of a collecting worker's rows, Algorithm 6, line 9).
      priority: ``td -> [N]``: the raw priority error of a row (``|δ|`` or the mean over critics; it is
        clipped to ``priority_clip`` here).
      extra_metrics: ``ls -> {name: []}`` reported after every update (averaged over the chunk's updates).
    """

    sample_key: Callable[[jax.Array], jax.Array]
    critic: Callable[..., tuple[LearnerState, jax.Array, jax.Array]]
    actor: Callable[..., tuple[LearnerState, jax.Array, jax.Array]]
    actor_loss: Callable[..., tuple[jax.Array, jax.Array]]
    targets: Callable[[LearnerState], LearnerState]
    td_error: Callable[[Any, Any, Transition], jax.Array]
    priority: Callable[[jax.Array], jax.Array]
    extra_metrics: Callable[[LearnerState], dict[str, jax.Array]] = lambda ls: {}


class Learner(NamedTuple):
    """The update of one off-policy configuration.

    Attributes:
      learn: ``(state, key, n, workers, actor_on=None, anchor=None) -> (state, metric sums, count)``:
        ``n`` updates if the replay holds enough transitions (else none; ``count`` is ``n`` or 0).
        ``state`` has the fields of :class:`LearnerState`, ``obs_stats`` and ``updates``.  ``actor_on``
        (``[] bool``): False keeps the actor as it is while the critic learns and the targets follow (the
        imitation stage).  ``anchor``: a behaviour-cloning loss that the actor loss takes with
        ``config.imitation_weight`` (the reported ``actor_loss`` includes it).
      priorities: ``(actor params, critic params, stats, rows [N]) -> [N]``: the priority of raw rows
        under one network copy (:attr:`Update.td_error`, :attr:`Update.priority`, clipped).
    """

    learn: Callable[..., tuple[Any, dict[str, jax.Array], jax.Array]]
    priorities: Callable[..., jax.Array]


def _actor_phase(
    update: Update, policy_delay: int, move: jax.Array, actor_on: jax.Array | None, batch: tuple, nets: LearnerState
) -> tuple[LearnerState, jax.Array, jax.Array]:
    """The actor step and the target updates of one update where they are due: ``move`` (``[]`` bool, the
    ``policy_delay``-th critic update) and ``actor_on`` (None: always; False: the targets only, the actor
    learning elsewhere).  ``batch = (tr, key, workers, anchor)``.  Returns the networks, the actor loss and
    ``q [N]`` (reported also where no step is taken)."""

    def actor_step(nets: LearnerState) -> tuple[LearnerState, jax.Array, jax.Array]:
        nets, aloss, q = update.actor(nets, *batch)
        return update.targets(nets), aloss, q

    def hold(nets: LearnerState) -> tuple[LearnerState, jax.Array, jax.Array]:
        """No actor or target step (``policy_delay``); the loss is still reported."""
        aloss, q = update.actor_loss(nets, *batch)
        return nets, aloss, q

    def follow(nets: LearnerState) -> tuple[LearnerState, jax.Array, jax.Array]:
        """No actor step, soft target updates (the actor learns elsewhere: imitation)."""
        nets, aloss, q = hold(nets)
        return update.targets(nets), aloss, q

    if actor_on is not None:
        branch = jnp.where(move, jnp.where(actor_on, 1, 2), 0)
        return jax.lax.switch(branch, (hold, actor_step, follow), nets)
    if policy_delay > 1:
        return jax.lax.cond(move, actor_step, hold, nets)
    return actor_step(nets)


def make_learner(
    config: OffPolicyConfig,
    update: Update,
    replay: Any,
    norm: Callable[[RunningStats, jax.Array], jax.Array],
    min_stored: int,
    metric_names: tuple[str, ...] = (),
) -> Learner:
    """The :class:`Learner` of ``config`` around the algorithm's ``update`` (``norm``: the acting's observation
    normaliser; ``metric_names``: the keys of ``update.extra_metrics``)."""

    def clipped(err: jax.Array) -> jax.Array:
        return jnp.minimum(jnp.abs(err), config.priority_clip) if config.priority_clip > 0 else err

    def normalized(stats: RunningStats, tr: Transition) -> Transition:
        return tr._replace(obs=norm(stats, tr.obs), next_obs=norm(stats, tr.next_obs))

    def priorities(actor_p: Any, critic_p: Any, stats: RunningStats, rows: Transition) -> jax.Array:
        return clipped(update.priority(update.td_error(actor_p, critic_p, normalized(stats, rows))))

    def learn_step(
        stats: RunningStats, workers: Workers, actor_on: jax.Array | None, anchor: Anchor | None, ls: LearnerState,
        xs: tuple,
    ) -> tuple[LearnerState, dict]:
        """One update; ``xs = (key, index)`` with ``index`` the run's count of updates before this one
        (the actor and targets move when ``(index + 1) % policy_delay == 0``; where ``actor_on`` is
        False only the targets move)."""
        key, index = xs
        smp = workers.flat(sample(replay, workers, update.sample_key(key), ls.replay))  # [G·b] rows of the workers
        tr = normalized(stats, smp.experience)
        ls, closs, td = update.critic(ls, tr, smp.weights if config.per else None, key, workers)
        move = (index + 1) % config.policy_delay == 0
        nets = ls.replace(replay=())  # the networks only go through the branches, not the memory
        nets, aloss, q = _actor_phase(update, config.policy_delay, move, actor_on, (tr, key, workers, anchor), nets)
        ls = nets.replace(replay=ls.replay)
        if config.per:
            indices, err = workers.gather((smp.indices, clipped(update.priority(td))))
            ls = ls.replace(replay=replay.update_priorities(ls.replay, indices, err))
        out = {"critic_loss": closs, "actor_loss": aloss, "q": workers.mean(jnp.mean(q)),
               "td_abs": workers.mean(jnp.mean(jnp.abs(td)))}
        if config.per:  # every worker's errors (gathered): the same count on every device
            out["per_nonfinite_td"] = count_nonfinite(err).astype(jnp.float32)
        out.update(update.extra_metrics(ls))
        return ls, out

    def learn(
        state: Any, key: jax.Array, n: int, workers: Workers, actor_on: jax.Array | None = None,
        anchor: Anchor | None = None,
    ) -> tuple[Any, dict[str, jax.Array], jax.Array]:
        def run(ls: LearnerState) -> tuple[LearnerState, dict, jax.Array]:
            xs = (jax.random.split(key, n), state.updates + jnp.arange(n, dtype=jnp.int32))
            ls, out = jax.lax.scan(lambda c, x: learn_step(state.obs_stats, workers, actor_on, anchor, c, x), ls, xs)
            return ls, jax.tree.map(jnp.sum, out), jnp.asarray(n, jnp.float32)

        def skip(ls: LearnerState) -> tuple[LearnerState, dict, jax.Array]:
            zero = jnp.zeros((), jnp.float32)
            return ls, dict.fromkeys(LOSS_METRICS + (PER_METRICS if config.per else ()) + metric_names, zero), zero

        ls, sums, count = jax.lax.cond(state.replay.size >= min_stored, run, skip, LearnerState.of(state))
        state = ls.into(state).replace(updates=state.updates + count.astype(jnp.int32))
        return state, sums, count

    return Learner(learn=learn, priorities=priorities)
