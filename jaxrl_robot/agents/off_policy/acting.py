"""Off-policy acting: lanes that explore with ``a = μ(s) + ω`` (or a stochastic policy's draw) and record
transitions (Algorithm 1, lines 5–8).

>>> acting = make_acting(config, env, act, noise, her, episode_length)
>>> policy = acting.policy(lane_ids, params, obs_stats, factor)        # this device's lanes [b]
>>> got = acting.collect(key, lane_ids, policy, env_state, noise_state)
>>> flat, mask = acting.gather(got.rows, got.mask)                     # every device's rows

Two schedules (``config.schedule``):

* ``"episodes"`` (§3.4.2, Algorithms 1–2): each lane runs one whole episode; every transition
  is kept with its real goal and, with HER, again with each additional goal and a recomputed
  reward (``C`` copies per step).  Rows per lane: ``N = T · C``.
* ``"steps"`` (§3.5, Table 3.3): auto-resetting lanes step ``U = unroll_length`` times; a lane's
  noise process restarts with its next episode.  Rows per lane: ``N = U``.

A failing step (termination without success) is stored with reward ``r + γ·failure_value`` and
``d = 1`` (an absorbing failure state); ``d`` marks terminations only, never a time limit.

Everything here runs on one device's lanes inside ``parallel.shard_lanes`` and returns that
device's rows lane-major ``[b, N, ...]``; :attr:`Acting.gather` puts every device's rows in the
replay's global order.  Randomness per lane is keyed by its *global* lane index, so a run does
not depend on the number of devices.  The policy is a closure, so the same rollout serves lanes
acting with the global parameters and collecting workers acting with their own copies (thesis
Algorithm 6).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from envs_mjx.base import EpisodeWrapper, wrap_for_training
from jaxrl_robot import parallel
from jaxrl_robot.acting import lane_select, per_lane_keys
from jaxrl_robot.agents import core
from jaxrl_robot.agents.off_policy.config import OffPolicyConfig
from jaxrl_robot.networks import normalize
from jaxrl_robot.noise import Noise, NoiseState, make_noise
from jaxrl_robot.replay import GoalEpisode, Her
from jaxrl_robot.types import RunningStats, Transition

__all__ = ["Acting", "Collected", "LanePolicy", "make_acting", "make_noise_for"]

LanePolicy = Callable[[jax.Array, jax.Array, NoiseState], tuple[jax.Array, NoiseState]]
"""``(key, obs [b, O], noise [b, A]) -> (action [b, A], noise)`` for one device's lanes."""


class Collected(NamedTuple):
    """What one iteration of acting leaves on a device.

    Attributes:
      env_state: ``State [b]`` after acting (the final step of the episodes for 'episodes').
      noise_state: ``NoiseState [b, A]`` after acting (unchanged for 'episodes': each episode
        starts its own process).
      rows: ``Transition [b, N]`` with raw (not normalised) observations.
      mask: ``[b, N]`` bool, the rows to store ('episodes': steps before the episode ended and
        the HER copies kept); None where every row is stored ('steps').
      sums: ``[]`` sums over this device's finished episodes: ``episodes``, ``episode_return``,
        ``episode_length`` and every per-lane env metric (``[2]`` with ``split``).
      labels: ``[b, N, A]`` a teacher's actions for the rows' states ('steps' with a teacher), else None.
    """

    env_state: State
    noise_state: NoiseState
    rows: Transition
    mask: jax.Array | None
    sums: dict[str, jax.Array]
    labels: jax.Array | None = None


class Acting(NamedTuple):
    """Acting functions of one off-policy configuration (see the module docstring).

    Attributes:
      reset: ``keys [b] -> (State [b], NoiseState [b, A])`` initial lanes.
      policy: ``(lane_ids [b], actor params, obs stats, factor or None, uniform=None) -> LanePolicy``:
        ``clip(μ(x) + f·ω, −1, 1)`` (Eq. 3.7) with ``x`` the normalised observation, or the stochastic
        policy's draw (``sample``); uniform random actions in [−1, 1] while ``uniform`` (``[]`` bool,
        :func:`~jaxrl_robot.agents.off_policy.trainer.warming_up`) holds.
      explore: the same as a function ``(key, lane_ids, params, stats, obs, noise, factor, uniform=None)``.
      collect: ``(key, lane_ids [b], policy, State [b], NoiseState [b], teacher=None, split=None)
        -> Collected``; ``teacher(key, State [b], action [b, A]) -> (executed action, label)``
        ('steps' only, the imitation stage of :mod:`~jaxrl_robot.agents.off_policy.imitation`) labels
        every visited state.  ``split``: the episode sums come as ``[2]``, lanes ``[:split]`` and
        ``[split:]`` apart (two kinds of worker stepped as one batch: one env step, not two).
      gather: ``(rows [b, N], mask [b, N] | None) -> (rows [R], mask [R] | None)`` with
        ``R = B · N`` over every device: time-major in global lane order (rows of one time step
        together), or lane-major with HER (an episode's rows and their copies together).
      norm: ``(stats, obs [..., O]) -> network input`` (``normalize_obs``, else unchanged).
      act: ``(actor params, x [..., O]) -> μ(x) [..., A]``.
      fresh_noise: ``n -> NoiseState [n, A]`` processes at their start.
    """

    reset: Callable[..., tuple[State, NoiseState]]
    policy: Callable[..., LanePolicy]
    explore: Callable[..., tuple[jax.Array, NoiseState]]
    collect: Callable[..., Collected]
    gather: Callable[..., tuple[Any, jax.Array | None]]
    norm: Callable[[RunningStats, jax.Array], jax.Array]
    act: Callable[[Any, jax.Array], jax.Array]
    fresh_noise: Callable[[int], NoiseState]


def make_noise_for(config: OffPolicyConfig, action_size: int) -> Noise:
    """The configured exploration noise (``config.noise``) for ``action_size`` dimensions (``ConfigError``
    naming a noise field with neither 1 nor ``action_size`` values)."""
    config.check_action_size(action_size)
    if config.noise == "ou":
        return make_noise("ou", action_size, mean=config.noise_mean, reversion=config.noise_reversion,
                          scale=config.noise_scale)
    return make_noise("gaussian", action_size, scale=config.noise_scale, mean=config.noise_mean)


def _lane_major(tree: Any) -> Any:
    """``[T, b, ...] -> [b, T, ...]``."""
    return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), tree)


class _Lanes(NamedTuple):
    """What the acting functions of one configuration share (see :func:`make_acting`'s arguments).

    Attributes:
      lane_env: ``env`` with the time limit, stepped per lane ('episodes'; else None).
      batched_env: ``env`` wrapped by ``wrap_for_training`` ('steps'; else None).
      fail_bonus: ``γ·failure_value``, added to a failing step's reward (terminal: no bootstrap).
    """

    config: OffPolicyConfig
    env: Env
    act: Callable[[Any, jax.Array], jax.Array]
    noise: Noise
    her: Her | None
    sample: Callable[[jax.Array, Any, jax.Array], jax.Array] | None
    lane_env: Env | None
    batched_env: Env | None
    episode_length: int
    fail_bonus: float


def make_acting(
    config: OffPolicyConfig, env: Env, act: Callable[[Any, jax.Array], jax.Array], noise: Noise, her: Her | None,
    episode_length: int, sample: Callable[[jax.Array, Any, jax.Array], jax.Array] | None = None,
    batched_env: Env | None = None,
) -> Acting:
    """The :class:`Acting` of ``config`` for the unbatched ``env``.

    ``act(params, x) -> μ(x)``: the deterministic policy.  ``sample(keys [b], params, x [b, O]) -> a [b, A]``:
    a stochastic policy that explores by itself (no noise added; the noise processes are left as they are),
    or None.  ``batched_env``: the env wrapped by ``wrap_for_training`` with the time limit ``episode_length``
    for the 'steps' schedule (built here if None).
    """
    if config.schedule == "episodes":
        lane_env, batched_env = EpisodeWrapper(env, episode_length), None
    else:
        lane_env, batched_env = None, batched_env or wrap_for_training(env, episode_length=episode_length)
    lanes = _Lanes(config, env, act, noise, her, sample, lane_env, batched_env, episode_length,
                   config.gamma * config.failure_value)  # fmt: skip
    return Acting(
        reset=functools.partial(_reset, lanes),
        policy=functools.partial(_policy, lanes),
        explore=functools.partial(_explore, lanes),
        collect=functools.partial(_collect, lanes),
        gather=functools.partial(_gather, her is None),
        norm=functools.partial(_norm, config.normalize_obs),
        act=act,
        fresh_noise=functools.partial(_fresh_noise, noise),
    )


def _norm(normalize_obs: bool, stats: RunningStats, obs: jax.Array) -> jax.Array:
    """The network input of raw ``obs [..., O]``: normalised by ``stats`` where ``normalize_obs``."""
    return normalize(stats if normalize_obs else None, obs)


def _explore(
    lanes: _Lanes, key: jax.Array, lane_ids: jax.Array, params: Any, stats: RunningStats, obs: jax.Array,
    nstate: NoiseState, factor: jax.Array | None, uniform: jax.Array | None = None,
) -> tuple[jax.Array, NoiseState]:
    """``a = clip(μ(s) + f·ω, -1, 1)`` (or ``sample``'s draw) for the lanes ``lane_ids [b]``: raw
    ``[b, O] -> [b, A]``; where ``uniform`` (a ``[]`` bool) is set, ``a ~ U[-1, 1]`` instead (the noise
    still advances)."""
    x = _norm(lanes.config.normalize_obs, stats, obs)
    if lanes.sample is not None:
        a = lanes.sample(per_lane_keys(jax.random.fold_in(key, 2), lane_ids), params, x)
    else:
        eps, nstate = jax.vmap(lanes.noise.sample)(per_lane_keys(key, lane_ids), nstate)
        if factor is not None:
            eps = factor * eps
        a = jnp.clip(lanes.act(params, x) + eps, -1.0, 1.0)
    if uniform is not None:
        keys = per_lane_keys(jax.random.fold_in(key, 1), lane_ids)
        u = jax.vmap(lambda k: jax.random.uniform(k, a.shape[1:], a.dtype, -1.0, 1.0))(keys)
        a = jnp.where(uniform, u, a)
    return a, nstate


def _policy(
    lanes: _Lanes, lane_ids: jax.Array, params: Any, stats: RunningStats, factor: jax.Array | None,
    uniform: jax.Array | None = None,
) -> LanePolicy:
    """:func:`_explore` of these lanes and parameters as a :data:`LanePolicy`."""
    return lambda key, obs, nstate: _explore(lanes, key, lane_ids, params, stats, obs, nstate, factor, uniform)


def _terminal(config: OffPolicyConfig, ns: State) -> jax.Array:
    """``d [b]``: 1 where the step ended the episode other than by the time limit (and, with
    ``termination_metric``, where that metric is set; other ends bootstrap)."""
    term = ns.done.astype(jnp.float32) * (1.0 - ns.info["truncation"].astype(jnp.float32))
    if config.termination_metric:
        term = term * ns.metrics[config.termination_metric].astype(jnp.float32)
    return term


def _failed(ns: State, term: jax.Array) -> jax.Array:
    """``[b]`` 1 where the step terminated without success."""
    return term * (1.0 - ns.metrics.get("success", jnp.zeros_like(term)).astype(jnp.float32))


def _lane_metrics(ns: State, b: int) -> dict[str, jax.Array]:
    """The env's per-lane metrics ``[b]`` of a step."""
    return {k: v for k, v in ns.metrics.items() if v.shape == (b,)}


def _fresh_noise(noise: Noise, n: int) -> NoiseState:
    """``NoiseState [n, A]``: ``n`` processes at their start."""
    return jax.vmap(lambda _: noise.init())(jnp.arange(n))


def _reset(lanes: _Lanes, keys: jax.Array) -> tuple[State, NoiseState]:
    """Initial lanes: ``keys [b] -> (State [b], NoiseState [b, A])``."""
    if lanes.lane_env is not None:
        env_state = jax.vmap(lanes.lane_env.reset)(keys)
    else:
        env_state = lanes.batched_env.reset(keys)
    # plain arrays where an env's reset gives weakly typed ones (brax's reward and done), as a chunk returns
    # them: a jitted chunk's second call then reuses its first program
    return core.cast_like(env_state, env_state), _fresh_noise(lanes.noise, keys.shape[0])


def _lane_sum(split: int | None) -> Callable[[jax.Array], jax.Array]:
    """Sum over lanes (the last axis): ``[..., b] -> [...]``, or ``[..., 2]``: lanes ``[:split]``, ``[split:]``."""
    if split is None:
        return lambda x: jnp.sum(x, axis=-1)
    return lambda x: jnp.stack([jnp.sum(x[..., :split], axis=-1), jnp.sum(x[..., split:], axis=-1)], axis=-1)


def _episode_step(
    lanes: _Lanes, policy: LanePolicy, carry: tuple, k: jax.Array
) -> tuple[tuple, dict[str, Any]]:
    """One step of every lane of :func:`_run_episodes`: ``carry = (State [b], NoiseState [b], finished [b])``
    and the step's row (lanes keep stepping after their episode ended; those steps are masked out)."""
    s, ns_noise, finished = carry
    a, ns_noise = policy(k, s.obs, ns_noise)
    ns = jax.vmap(lanes.lane_env.step)(s, a)
    done = ns.done.astype(jnp.float32)
    term = _terminal(lanes.config, ns)
    alive = 1.0 - finished
    row = {"obs": s.obs, "action": a, "reward": ns.reward, "next_obs": ns.obs, "termination": term,
           "failed": _failed(ns, term), "valid": alive, "ending": alive * done,
           "metrics": _lane_metrics(ns, finished.shape[0])}  # fmt: skip
    if lanes.her is not None:
        row["achieved"] = jax.vmap(lanes.env.achieved_goal)(ns)
        row["ee_pos"] = ns.info["ee_pos"]
    return (ns, ns_noise, jnp.maximum(finished, done)), row


def _run_episodes(
    lanes: _Lanes, key: jax.Array, lane_ids: jax.Array, policy: LanePolicy, nstate: NoiseState,
    split: int | None = None,
) -> Collected:
    """One whole episode in each lane ``lane_ids [b]``."""
    b = lane_ids.shape[0]
    red = _lane_sum(split)
    k_reset, k_steps, k_her = jax.random.split(key, 3)
    state0 = jax.vmap(lanes.lane_env.reset)(per_lane_keys(k_reset, lane_ids))
    carry = (state0, _fresh_noise(lanes.noise, b), jnp.zeros((b,), jnp.float32))
    (final, _, _), traj = jax.lax.scan(functools.partial(_episode_step, lanes, policy), carry,
                                       jax.random.split(k_steps, lanes.episode_length))  # fmt: skip
    sums = {"episodes": red(jnp.ones((b,), jnp.float32))}
    sums["episode_return"] = red(jnp.sum(traj["valid"] * traj["reward"], axis=0))
    sums["episode_length"] = red(jnp.sum(traj["valid"], axis=0))
    for name, v in traj["metrics"].items():
        sums[name] = red(jnp.sum(traj["ending"] * v, axis=0))
    rows = _lane_major(traj)  # [b, T, ...]
    if lanes.her is None:
        reward = rows["reward"] + lanes.fail_bonus * rows["failed"]
        tr = Transition(rows["obs"], rows["action"], reward, rows["next_obs"], rows["termination"])
        return Collected(final, nstate, tr, rows["valid"] > 0, sums)
    tr, mask = _relabel(lanes, k_her, lane_ids, state0, rows)
    return Collected(final, nstate, tr, mask, sums)


def _relabel(
    lanes: _Lanes, key: jax.Array, lane_ids: jax.Array, state0: State, rows: dict[str, Any]
) -> tuple[Transition, jax.Array]:
    """HER's rows of the episodes ``rows`` (``[b, T, ...]``, from ``state0 [b]``): ``(Transition [b, T·C],
    mask [b, T·C])``, each step's real goal and its ``C − 1`` additional goals."""
    env, b = lanes.env, lane_ids.shape[0]
    achieved0 = jax.vmap(env.achieved_goal)(state0)
    episodes = GoalEpisode(
        obs=rows["obs"], action=rows["action"], reward=rows["reward"], next_obs=rows["next_obs"],
        termination=rows["termination"], failed=rows["failed"], valid=rows["valid"],
        achieved=jnp.concatenate([achieved0[:, None], rows["achieved"]], axis=1),
        ee_pos=jnp.concatenate([state0.info["ee_pos"][:, None], rows["ee_pos"]], axis=1),
        goal=jax.vmap(env.desired_goal)(state0),
    )
    tr, mask, _ = jax.vmap(lanes.her.relabel)(per_lane_keys(key, lane_ids), episodes)  # [b, T, C, ...]
    tr = tr._replace(reward=tr.reward + lanes.fail_bonus * episodes.failed[:, :, None])  # failure is goal-independent
    return jax.tree.map(lambda x: x.reshape((b, -1) + x.shape[3:]), (tr, mask))


def _unroll_step(
    lanes: _Lanes, policy: LanePolicy, teacher: Any, split: int | None, b: int, carry: tuple, k: jax.Array
) -> tuple[tuple, tuple]:
    """One step of the ``b`` auto-resetting lanes of :func:`_run_steps`: ``carry = (State [b], NoiseState [b])``,
    and the step's ``(Transition [b], episode sums, teacher's label [b, A] or ())``."""
    s, nstate = carry
    red = _lane_sum(split)
    a, nstate = policy(k, s.obs, nstate)
    label = ()
    if teacher is not None:
        a, label = teacher(jax.random.fold_in(k, 1), s, a)
    ns = lanes.batched_env.step(s, a)
    done = ns.done.astype(jnp.float32)
    term = _terminal(lanes.config, ns)
    tr = Transition(s.obs, a, ns.reward + lanes.fail_bonus * _failed(ns, term), ns.info["final_obs"], term)
    nstate = lane_select(done > 0, _fresh_noise(lanes.noise, b), nstate)  # new episode, new noise process
    ep = {"episodes": red(done), "episode_return": red(done * ns.info["episode_return"]),
          "episode_length": red(done * ns.info["episode_length"])}
    for name, v in _lane_metrics(ns, b).items():
        ep[name] = red(done * v)
    return (ns, nstate), (tr, ep, label)


def _run_steps(
    lanes: _Lanes, key: jax.Array, lane_ids: jax.Array, policy: LanePolicy, s: State, nstate: NoiseState,
    teacher: Any = None, split: int | None = None,
) -> Collected:
    """``unroll_length`` steps of the auto-resetting lanes ``lane_ids [b]`` (labelled by ``teacher``)."""
    step = functools.partial(_unroll_step, lanes, policy, teacher, split, lane_ids.shape[0])
    keys = jax.random.split(key, lanes.config.unroll_length)
    (s, nstate), (traj, ep, labels) = jax.lax.scan(step, (s, nstate), keys)
    labels = _lane_major(labels) if teacher is not None else None
    sums = jax.tree.map(lambda x: jnp.sum(x, axis=0), ep)
    return Collected(s, nstate, _lane_major(traj), None, sums, labels)


def _collect(
    lanes: _Lanes, key: jax.Array, lane_ids: jax.Array, policy: LanePolicy, s: State, nstate: NoiseState,
    teacher: Any = None, split: int | None = None,
) -> Collected:
    """One iteration's acting of the lanes ``lane_ids [b]`` under the configured schedule (:attr:`Acting.collect`)."""
    if lanes.config.schedule == "episodes":
        if teacher is not None:
            raise ValueError("a teacher needs schedule='steps'")
        return _run_episodes(lanes, key, lane_ids, policy, nstate, split)
    return _run_steps(lanes, key, lane_ids, policy, s, nstate, teacher, split)


def _gather(time_major: bool, rows: Any, mask: jax.Array | None) -> tuple[Any, jax.Array | None]:
    """Every device's rows ``[b, N]`` as ``[B·N]`` in global lane order, time-major (no HER) or lane-major."""
    lanes = parallel.all_gather((rows, mask))  # [B, N, ...] in global lane order
    if time_major:
        lanes = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), lanes)
    return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), lanes)
