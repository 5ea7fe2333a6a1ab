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

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from envs_mjx.base import EpisodeWrapper, wrap_for_training
from jaxrl_robot import parallel
from jaxrl_robot.acting import lane_select, per_lane_keys
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
    T = episode_length
    fail_bonus = config.gamma * config.failure_value  # stored into a failing step's reward (terminal: no bootstrap)
    if config.schedule == "episodes":
        lane_env, batched_env = EpisodeWrapper(env, T), None
    else:
        lane_env, batched_env = None, batched_env or wrap_for_training(env, episode_length=T)

    def norm(stats: RunningStats, obs: jax.Array) -> jax.Array:
        return normalize(stats if config.normalize_obs else None, obs)

    def explore(
        key: jax.Array, lane_ids: jax.Array, params: Any, stats: RunningStats, obs: jax.Array, nstate: NoiseState,
        factor: jax.Array | None, uniform: jax.Array | None = None,
    ) -> tuple[jax.Array, NoiseState]:
        """``a = clip(μ(s) + f·ω, -1, 1)`` (or ``sample``'s draw) for the lanes ``lane_ids [b]``: raw
        ``[b, O] -> [b, A]``; where ``uniform`` (a ``[]`` bool) is set, ``a ~ U[-1, 1]`` instead (the noise
        still advances)."""
        if sample is not None:
            a = sample(per_lane_keys(jax.random.fold_in(key, 2), lane_ids), params, norm(stats, obs))
        else:
            eps, nstate = jax.vmap(noise.sample)(per_lane_keys(key, lane_ids), nstate)
            if factor is not None:
                eps = factor * eps
            a = jnp.clip(act(params, norm(stats, obs)) + eps, -1.0, 1.0)
        if uniform is not None:
            keys = per_lane_keys(jax.random.fold_in(key, 1), lane_ids)
            u = jax.vmap(lambda k: jax.random.uniform(k, a.shape[1:], a.dtype, -1.0, 1.0))(keys)
            a = jnp.where(uniform, u, a)
        return a, nstate

    def policy(
        lane_ids: jax.Array, params: Any, stats: RunningStats, factor: jax.Array | None,
        uniform: jax.Array | None = None,
    ) -> LanePolicy:
        return lambda key, obs, nstate: explore(key, lane_ids, params, stats, obs, nstate, factor, uniform)

    def terminal(ns: State) -> jax.Array:
        """``d [b]``: 1 where the step ended the episode other than by the time limit (and, with
        ``termination_metric``, where that metric is set; other ends bootstrap)."""
        term = ns.done.astype(jnp.float32) * (1.0 - ns.info["truncation"].astype(jnp.float32))
        if config.termination_metric:
            term = term * ns.metrics[config.termination_metric].astype(jnp.float32)
        return term

    def failed(ns: State, term: jax.Array) -> jax.Array:
        """``[b]`` 1 where the step terminated without success."""
        return term * (1.0 - ns.metrics.get("success", jnp.zeros_like(term)).astype(jnp.float32))

    def lane_metrics(ns: State, b: int) -> dict[str, jax.Array]:
        return {k: v for k, v in ns.metrics.items() if v.shape == (b,)}

    def fresh_noise(n: int) -> NoiseState:
        return jax.vmap(lambda _: noise.init())(jnp.arange(n))

    def reset(keys: jax.Array) -> tuple[State, NoiseState]:
        env_state = jax.vmap(lane_env.reset)(keys) if lane_env is not None else batched_env.reset(keys)
        return env_state, fresh_noise(keys.shape[0])

    def lane_sum(split: int | None) -> Callable[[jax.Array], jax.Array]:
        """Sum over lanes (the last axis): ``[..., b] -> [...]``, or ``[..., 2]``: lanes ``[:split]``, ``[split:]``."""
        if split is None:
            return lambda x: jnp.sum(x, axis=-1)
        return lambda x: jnp.stack([jnp.sum(x[..., :split], axis=-1), jnp.sum(x[..., split:], axis=-1)], axis=-1)

    def run_episodes(
        key: jax.Array, lane_ids: jax.Array, policy: LanePolicy, nstate: NoiseState, split: int | None = None
    ) -> Collected:
        """One whole episode in each lane ``lane_ids [b]``."""
        b = lane_ids.shape[0]
        red = lane_sum(split)
        k_reset, k_steps, k_her = jax.random.split(key, 3)
        state0 = jax.vmap(lane_env.reset)(per_lane_keys(k_reset, lane_ids))

        def body(carry, k):
            s, ns_noise, finished = carry
            a, ns_noise = policy(k, s.obs, ns_noise)
            ns = jax.vmap(lane_env.step)(s, a)
            done = ns.done.astype(jnp.float32)
            term = terminal(ns)
            alive = 1.0 - finished
            row = {"obs": s.obs, "action": a, "reward": ns.reward, "next_obs": ns.obs, "termination": term,
                   "failed": failed(ns, term), "valid": alive, "ending": alive * done, "metrics": lane_metrics(ns, b)}
            if her is not None:
                row["achieved"] = jax.vmap(env.achieved_goal)(ns)
                row["ee_pos"] = ns.info["ee_pos"]
            # lanes keep stepping after their episode ended; those steps are masked out
            return (ns, ns_noise, jnp.maximum(finished, done)), row

        carry = (state0, fresh_noise(b), jnp.zeros((b,), jnp.float32))
        (final, _, _), traj = jax.lax.scan(body, carry, jax.random.split(k_steps, T))
        sums = {"episodes": red(jnp.ones((b,), jnp.float32))}
        sums["episode_return"] = red(jnp.sum(traj["valid"] * traj["reward"], axis=0))
        sums["episode_length"] = red(jnp.sum(traj["valid"], axis=0))
        for name, v in traj["metrics"].items():
            sums[name] = red(jnp.sum(traj["ending"] * v, axis=0))
        lanes = _lane_major(traj)  # [b, T, ...]
        if her is None:
            reward = lanes["reward"] + fail_bonus * lanes["failed"]
            rows = Transition(lanes["obs"], lanes["action"], reward, lanes["next_obs"], lanes["termination"])
            return Collected(final, nstate, rows, lanes["valid"] > 0, sums)
        achieved0 = jax.vmap(env.achieved_goal)(state0)
        episodes = GoalEpisode(
            obs=lanes["obs"], action=lanes["action"], reward=lanes["reward"], next_obs=lanes["next_obs"],
            termination=lanes["termination"], failed=lanes["failed"], valid=lanes["valid"],
            achieved=jnp.concatenate([achieved0[:, None], lanes["achieved"]], axis=1),
            ee_pos=jnp.concatenate([state0.info["ee_pos"][:, None], lanes["ee_pos"]], axis=1),
            goal=jax.vmap(env.desired_goal)(state0),
        )
        tr, mask, _ = jax.vmap(her.relabel)(per_lane_keys(k_her, lane_ids), episodes)  # [b, T, C, ...]
        tr = tr._replace(reward=tr.reward + fail_bonus * episodes.failed[:, :, None])  # failure is goal-independent
        rows, mask = jax.tree.map(lambda x: x.reshape((b, -1) + x.shape[3:]), (tr, mask))
        return Collected(final, nstate, rows, mask, sums)

    def run_steps(
        key: jax.Array, lane_ids: jax.Array, policy: LanePolicy, s: State, nstate: NoiseState, teacher: Any = None,
        split: int | None = None,
    ) -> Collected:
        """``unroll_length`` steps of the auto-resetting lanes ``lane_ids [b]`` (labelled by ``teacher``)."""
        b = lane_ids.shape[0]
        red = lane_sum(split)

        def body(carry, k):
            s, nstate = carry
            a, nstate = policy(k, s.obs, nstate)
            label = ()
            if teacher is not None:
                a, label = teacher(jax.random.fold_in(k, 1), s, a)
            ns = batched_env.step(s, a)
            done = ns.done.astype(jnp.float32)
            term = terminal(ns)
            tr = Transition(s.obs, a, ns.reward + fail_bonus * failed(ns, term), ns.info["final_obs"], term)
            nstate = lane_select(done > 0, fresh_noise(b), nstate)  # new episode, new noise process
            ep = {"episodes": red(done), "episode_return": red(done * ns.info["episode_return"]),
                  "episode_length": red(done * ns.info["episode_length"])}
            for name, v in lane_metrics(ns, b).items():
                ep[name] = red(done * v)
            return (ns, nstate), (tr, ep, label)

        (s, nstate), (traj, ep, labels) = jax.lax.scan(body, (s, nstate), jax.random.split(key, config.unroll_length))
        labels = _lane_major(labels) if teacher is not None else None
        sums = jax.tree.map(lambda x: jnp.sum(x, axis=0), ep)
        return Collected(s, nstate, _lane_major(traj), None, sums, labels)

    def collect(
        key: jax.Array, lane_ids: jax.Array, policy: LanePolicy, s: State, nstate: NoiseState, teacher: Any = None,
        split: int | None = None,
    ) -> Collected:
        if config.schedule == "episodes":
            if teacher is not None:
                raise ValueError("a teacher needs schedule='steps'")
            return run_episodes(key, lane_ids, policy, nstate, split)
        return run_steps(key, lane_ids, policy, s, nstate, teacher, split)

    time_major = her is None

    def gather(rows: Any, mask: jax.Array | None) -> tuple[Any, jax.Array | None]:
        lanes = parallel.all_gather((rows, mask))  # [B, N, ...] in global lane order
        if time_major:
            lanes = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), lanes)
        return jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), lanes)

    return Acting(reset=reset, policy=policy, explore=explore, collect=collect, gather=gather, norm=norm, act=act,
                  fresh_noise=fresh_noise)
