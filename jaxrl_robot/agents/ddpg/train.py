"""DDPG with prioritised and hindsight replay as a pure, jit-compiled training function.

>>> trainer = make_trainer(DDPGConfig(her="future", her_k=2), env)   # any unbatched brax Env
>>> state = jax.jit(trainer.init)(key)
>>> state, metrics = jax.jit(trainer.update, donate_argnums=0)(state)   # one chunk (an epoch)
>>> train = make_train(config, env)                                  # or the whole run
>>> state, metrics = jax.jit(train)(key)

One iteration of the ``"episodes"`` schedule (thesis §3.4.2, Algorithms 1–2): ``num_envs``
lanes each run one whole episode with ``a = μ(s) + noise`` (Eq. 3.7); every transition is
stored with its real goal and, with HER, again with each additional goal and a recomputed
reward; then ``updates_per_cycle`` updates.  The ``"steps"`` schedule (§3.5, Table 3.3)
steps auto-resetting lanes continuously and updates after every ``unroll_length`` steps.

One update (Algorithm 1, lines 9–17): sample a mini-batch (uniformly, or prioritised with
importance weights w); critic step on ``mean w (Q(s, a) − y)²`` with
``y = r + γ (1 − d) Q'(s', μ'(s'))`` where ``d`` marks termination only (a time-limit
truncation bootstraps); actor step on ``−mean Q(s, μ(s))``; soft target updates with ε;
with PER, new priorities ``|y − Q| + ε`` and β annealing.  Options: twin critics with the
clipped double-Q target ``min(Q1', Q2')`` (``twin_critics``), actor and target updates every
``policy_delay`` critic updates, and a linear decay of the exploration noise
(``noise_end_factor``, ``noise_decay_fraction``) and of the learning rates (``lr_end_factor``),
a reward shift in the target (``reward_shift``) and bootstrapping every episode end but those a
metric marks (``termination_metric``).

A failing step (termination without success; with ``termination_metric``, only the ends that
metric marks) is stored with reward ``r + γ·failure_value`` and ``d = 1``, so its target is that
of an absorbing failure state of value ``failure_value``.

The replay buffer lives in the training state on the device, so a checkpoint of the state
resumes a run exactly.

Devices: the lanes (acting, env steps, exploration noise, episode bookkeeping, HER relabelling)
are split over the device mesh with ``parallel.shard_lanes``; each iteration's transitions are
gathered from every device in global lane order, so the replay memory, the observation
statistics and the learner (sampling, updates, priorities) are replicated and identical on
every device.  Per-lane randomness is keyed by *global* lane index, so a run gives the same
result on any number of devices (up to float summation order of the episode metrics).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env, State
from flax import struct

from envs_mjx.base import EpisodeWrapper, wrap_for_training
from envs_mjx.config import ConfigError
from jaxrl_robot import parallel
from jaxrl_robot.agents.ddpg.config import DDPGConfig
from jaxrl_robot.agents.ddpg.losses import (
    actor_loss,
    clipped_double_q,
    critic_loss,
    linear_noise_factor,
    smooth_target_action,
    soft_update,
    td_target,
    twin_critic_loss,
)
from jaxrl_robot.agents.ddpg.networks import DDPGActor, DDPGCritic
from jaxrl_robot.networks import init_running_stats, normalize, update_running_stats
from jaxrl_robot.noise import Noise, NoiseState, make_noise
from jaxrl_robot.replay import (
    GoalEpisode,
    Transition,
    make_her,
    make_prioritized_replay,
    make_uniform_replay,
)
from jaxrl_robot.types import Metrics, Policy, RunningStats, Trainer

__all__ = ["GOAL_API", "DDPGState", "make_networks", "make_noise_for", "make_train", "make_trainer"]

_LANES = parallel.LANES

GOAL_API = ("achieved_goal", "desired_goal", "compute_reward", "sample_goal", "in_feasible_region", "obs_from")


@struct.dataclass
class DDPGState:
    """Everything a DDPG run needs to continue exactly.

    Attributes:
      actor_params, critic_params: online network parameters θ^μ, θ^Q (with ``twin_critics``
        the two critics' parameters stacked on a leading axis of size 2).
      target_actor_params, target_critic_params: target parameters θ^μ', θ^Q'.
      actor_opt, critic_opt: Adam states.
      replay: uniform or prioritised replay state (stored transitions, sum-tree, β).
      env_state: ``State [B]`` of the lanes ('steps' schedule; the last cycle's for 'episodes'),
        split over devices.
      noise_state: ``NoiseState [B, A]`` of every lane, split over devices.
      obs_stats: running mean and variance of the observations (used only with ``normalize_obs``).
      key: PRNG key of the run.
      iteration: ``[] int32`` iterations (cycles or unroll phases) done.
      updates: ``[] int32`` gradient updates done.
    """

    actor_params: Any
    critic_params: Any
    target_actor_params: Any
    target_critic_params: Any
    actor_opt: Any
    critic_opt: Any
    replay: Any
    env_state: State
    noise_state: NoiseState
    obs_stats: RunningStats
    key: jax.Array
    iteration: jax.Array
    updates: jax.Array


def make_networks(config: DDPGConfig, action_size: int) -> tuple[DDPGActor, DDPGCritic]:
    """Actor and critic of the configured widths (SPEC §A1)."""
    return (
        DDPGActor(action_size=action_size, hidden=tuple(config.actor_hidden), output=config.actor_output),
        DDPGCritic(hidden=tuple(config.critic_hidden)),
    )


def make_noise_for(config: DDPGConfig, action_size: int) -> Noise:
    """The configured exploration noise (``config.noise``) for ``action_size`` dimensions."""
    if config.noise == "ou":
        return make_noise("ou", action_size, mean=config.noise_mean, reversion=config.noise_reversion,
                          scale=config.noise_scale)
    return make_noise("gaussian", action_size, scale=config.noise_scale, mean=config.noise_mean)


def make_optimizer(
    lr: float, max_grad_norm: float, end_factor: float = 1.0, decay_steps: int = 1
) -> optax.GradientTransformation:
    """Adam with step size ``lr`` falling linearly to ``end_factor · lr`` over ``decay_steps`` of its own
    steps and then held (``lr_end_factor``; constant when ``end_factor`` is 1), after clipping the
    gradient to ``max_grad_norm`` (when > 0)."""
    if end_factor < 1.0:
        lr = optax.linear_schedule(lr, lr * end_factor, max(int(decay_steps), 1))
    adam = optax.adam(lr)
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), adam) if max_grad_norm > 0 else adam


def _tree_where(cond: jax.Array, a: Any, b: Any) -> Any:
    """Per-lane select ``cond [B] ? a : b`` over pytrees with leading lane axis."""
    return jax.tree.map(lambda x, y: jnp.where(cond.reshape(cond.shape + (1,) * (x.ndim - 1)), x, y), a, b)


def _per_lane_keys(key: jax.Array, lane_ids: jax.Array) -> jax.Array:
    """One key per lane from its global index: ``lane_ids [b] -> keys [b]`` (independent of the device count)."""
    return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, lane_ids)


def _gather_time_major(tree: Any) -> Any:
    """This device's ``[T, b, ...]`` rows -> every device's ``[T * B, ...]``, time-major in global lane order."""
    lane_major = parallel.all_gather(jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), tree))  # [B, T, ...]
    return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1).reshape((-1,) + x.shape[2:]), lane_major)


def _like(new: Any, old: Any) -> Any:
    """``new`` with the dtypes (and strong typing) of ``old``, so ``update``'s output state has
    exactly its input's types and the jitted ``update`` never recompiles (env steps may return
    weakly typed values where ``reset`` returned strong ones)."""

    def cast(x, y):
        if x.dtype != y.dtype or getattr(x, "weak_type", False) != getattr(y, "weak_type", False):
            return jnp.asarray(x).astype(y.dtype)
        return x

    return jax.tree.map(cast, new, old)


def make_trainer(
    config: DDPGConfig,
    env: Env,
    *,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int | None = None,
) -> Trainer:
    """Build the DDPG :class:`~jaxrl_robot.types.Trainer` for ``env``.

    Args:
      config: hyper-parameters (validated here).
      env: an *unbatched* env; with HER it must provide the goal-conditioned API
        (:data:`GOAL_API`) and ``state.info["ee_pos"]``.
      mesh: device mesh from ``parallel.lane_mesh`` (default: all devices); the ``num_envs``
        lanes are split over it, the replay memory and the learner are replicated.
      iterations_per_update: iterations per ``update`` call (default: one epoch of
        ``cycles_per_epoch`` cycles for 'episodes', 1 for 'steps').
    Raises:
      ConfigError: invalid settings, or HER on an env without the goal API.
      ValueError: ``num_envs`` does not divide over the mesh's devices.
    """
    config.validate()
    chunk = iterations_per_update or (config.cycles_per_epoch if config.schedule == "episodes" else 1)
    if chunk < 1:
        raise ConfigError(f"iterations_per_update={iterations_per_update} must be >= 1")
    if config.her != "none":
        missing = [name for name in GOAL_API if not hasattr(env, name)]
        if missing:
            raise ConfigError(f"her={config.her!r} needs the goal-conditioned env API; env lacks {', '.join(missing)}")
    if config.termination_metric:
        metrics = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).metrics
        if config.termination_metric not in metrics:
            raise ConfigError(
                f"termination_metric={config.termination_metric!r} is not a metric of this env; "
                f"choose from {sorted(metrics)}"
            )
    episode_length = int(config.episode_length or getattr(env, "episode_length", 0) or 0)
    if episode_length < 1:
        raise ConfigError("episode_length=0: this env has no default episode_length; set episode_length >= 1")
    B, T = config.num_envs, episode_length
    mesh = parallel.lane_mesh() if mesh is None else mesh
    b_local = parallel.local_lane_count(B, mesh)  # lanes per device
    obs_size, action_size = int(env.observation_size), int(env.action_size)
    actor, critic = make_networks(config, action_size)
    critic_steps = config.iterations * (config.updates_per_cycle if config.schedule == "episodes"
                                        else config.updates_per_iteration)
    actor_tx = make_optimizer(config.actor_lr, config.max_grad_norm, config.lr_end_factor,
                              critic_steps // config.policy_delay)
    critic_tx = make_optimizer(config.critic_lr, config.max_grad_norm, config.lr_end_factor, critic_steps)
    noise = make_noise_for(config, action_size)
    her = make_her(env, config.her, config.her_k) if config.her != "none" else None
    copies = her.copies if her is not None else 1
    rows_per_iteration = B * T * copies if config.schedule == "episodes" else B * config.unroll_length
    if rows_per_iteration > config.buffer_size:
        raise ConfigError(
            f"buffer_size={config.buffer_size} is out of range; one iteration stores up to {rows_per_iteration} "
            "transitions, so allowed [that, inf)"
        )
    if config.per:
        replay = make_prioritized_replay(
            config.buffer_size, config.batch_size, config.alpha, config.beta0, config.beta_increment,
            priority_eps=config.priority_eps,
        )
    else:
        replay = make_uniform_replay(config.buffer_size, config.batch_size)
    min_stored = max(config.batch_size, config.learning_starts)
    fail_bonus = config.gamma * config.failure_value  # stored into a failing step's reward (terminal: no bootstrap)
    steps_per_iteration = B * (T if config.schedule == "episodes" else config.unroll_length)
    num_updates = -(-config.iterations // chunk)
    if config.schedule == "episodes":
        lane_env = EpisodeWrapper(env, T)
        batched_env = None
    else:
        lane_env = None
        batched_env = wrap_for_training(env, episode_length=T)

    def norm(stats: RunningStats, obs: jax.Array) -> jax.Array:
        """Network input: ``obs [..., O]`` normalised by ``stats`` with ``normalize_obs``, else unchanged."""
        return normalize(stats if config.normalize_obs else None, obs)

    def act(params: Any, obs: jax.Array) -> jax.Array:
        """``μ(x)`` of an already normalised input ``x [..., O]``."""
        return actor.apply(params, obs)

    decay_noise = config.noise_end_factor < 1.0

    def explore(
        key: jax.Array, lane_ids: jax.Array, params: Any, stats: RunningStats, obs: jax.Array, nstate: NoiseState,
        factor: jax.Array,
    ) -> tuple[jax.Array, NoiseState]:
        """``a = clip(μ(s) + f·ω, -1, 1)`` (Eq. 3.7; ``f`` the noise factor, 1 without a schedule)
        for this device's lanes ``lane_ids [b]``: raw ``[b, O] -> [b, A]``."""
        eps, nstate = jax.vmap(noise.sample)(_per_lane_keys(key, lane_ids), nstate)
        if decay_noise:
            eps = factor * eps
        return jnp.clip(act(params, norm(stats, obs)) + eps, -1.0, 1.0), nstate

    def noise_factor(iteration: jax.Array) -> jax.Array:
        """The exploration-noise multiplier at ``iteration`` (:func:`linear_noise_factor`)."""
        return linear_noise_factor(iteration, config.iterations, config.noise_end_factor, config.noise_decay_fraction)

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

    def terminal(ns: State) -> jax.Array:
        """``d [b]``: 1 where the step ended the episode other than by the time limit (and, with
        ``termination_metric``, where that metric is set; other ends bootstrap)."""
        term = ns.done.astype(jnp.float32) * (1.0 - ns.info["truncation"].astype(jnp.float32))
        if config.termination_metric:
            term = term * ns.metrics[config.termination_metric].astype(jnp.float32)
        return term

    def fresh_noise(n: int) -> NoiseState:
        """Noise processes at their start for ``n`` lanes: ``NoiseState [n, A]``."""
        return jax.vmap(lambda _: noise.init())(jnp.arange(n))

    def reset_lanes(keys: jax.Array) -> tuple[State, NoiseState]:
        """Initial env and noise states of this device's lanes from their keys ``[b]``."""
        env_state = jax.vmap(lane_env.reset)(keys) if lane_env is not None else batched_env.reset(keys)
        return env_state, fresh_noise(keys.shape[0])

    # ---- init --------------------------------------------------------------------------
    def init(key: jax.Array) -> DDPGState:
        k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
        dummy_obs = jnp.zeros((1, obs_size), jnp.float32)
        dummy_act = jnp.zeros((1, action_size), jnp.float32)
        actor_params = actor.init(k_actor, dummy_obs)
        if config.twin_critics:
            critic_params = jax.vmap(lambda k: critic.init(k, dummy_obs, dummy_act))(jax.random.split(k_critic, 2))
        else:
            critic_params = critic.init(k_critic, dummy_obs, dummy_act)
        example = Transition(
            obs=jnp.zeros((obs_size,), jnp.float32),
            action=jnp.zeros((action_size,), jnp.float32),
            reward=jnp.zeros((), jnp.float32),
            next_obs=jnp.zeros((obs_size,), jnp.float32),
            terminated=jnp.zeros((), jnp.float32),
        )
        lanes = parallel.P(_LANES)
        env_state, noise_state = parallel.shard_lanes(reset_lanes, mesh, (lanes,), (lanes, lanes))(
            jax.random.split(k_env, B)
        )
        return DDPGState(
            actor_params=actor_params,
            critic_params=critic_params,
            target_actor_params=actor_params,
            target_critic_params=critic_params,
            actor_opt=actor_tx.init(actor_params),
            critic_opt=critic_tx.init(critic_params),
            replay=replay.init(example),
            env_state=env_state,
            noise_state=noise_state,
            obs_stats=init_running_stats(obs_size),
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
            updates=jnp.zeros((), jnp.int32),
        )

    # ---- acting: 'episodes' schedule -----------------------------------------------------
    def run_episodes(
        key: jax.Array, lane_ids: jax.Array, params: Any, stats: RunningStats, factor: jax.Array
    ) -> tuple[State, Transition, jax.Array, dict]:
        """Run one whole episode in each of this device's lanes ``lane_ids [b]``; returns (final state
        ``[b]``, every device's Transition ``[T*B*C]`` and mask ``[T*B*C]`` in global lane order, this
        device's episode sums)."""
        k_reset, k_steps, k_her = jax.random.split(key, 3)
        state0 = jax.vmap(lane_env.reset)(_per_lane_keys(k_reset, lane_ids))
        goal_env = her is not None

        def body(carry, k):
            s, nstate, finished = carry
            a, nstate = explore(k, lane_ids, params, stats, s.obs, nstate, factor)
            ns = jax.vmap(lane_env.step)(s, a)
            done = ns.done.astype(jnp.float32)
            term = terminal(ns)
            success = ns.metrics.get("success", jnp.zeros_like(done)).astype(jnp.float32)
            alive = 1.0 - finished
            row = {
                "obs": s.obs, "action": a, "reward": ns.reward, "next_obs": ns.obs, "terminated": term,
                "failed": term * (1.0 - success), "valid": alive, "ending": alive * done,
                "metrics": {k: v for k, v in ns.metrics.items() if v.shape == (b_local,)},
            }
            if goal_env:
                row["achieved"] = jax.vmap(env.achieved_goal)(ns)
                row["ee_pos"] = ns.info["ee_pos"]
            # lanes keep stepping after their episode ended; those steps are masked out
            return (ns, nstate, jnp.maximum(finished, done)), row

        carry = (state0, fresh_noise(b_local), jnp.zeros((b_local,), jnp.float32))
        (final, _, _), traj = jax.lax.scan(body, carry, jax.random.split(k_steps, T))
        sums = {"episodes": jnp.asarray(b_local, jnp.float32)}
        sums["episode_return"] = jnp.sum(traj["valid"] * traj["reward"])
        sums["episode_length"] = jnp.sum(traj["valid"])
        for name, v in traj["metrics"].items():
            sums[name] = jnp.sum(traj["ending"] * v)
        if not goal_env:
            reward = traj["reward"] + fail_bonus * traj["failed"]
            tr = Transition(traj["obs"], traj["action"], reward, traj["next_obs"], traj["terminated"])
            flat, valid = _gather_time_major((tr, traj["valid"]))
            return final, flat, valid > 0, sums
        lane_major = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), traj)
        achieved0 = jax.vmap(env.achieved_goal)(state0)
        episodes = GoalEpisode(
            obs=lane_major["obs"], action=lane_major["action"], reward=lane_major["reward"],
            next_obs=lane_major["next_obs"], terminated=lane_major["terminated"], failed=lane_major["failed"],
            valid=lane_major["valid"],
            achieved=jnp.concatenate([achieved0[:, None], lane_major["achieved"]], axis=1),
            ee_pos=jnp.concatenate([state0.info["ee_pos"][:, None], lane_major["ee_pos"]], axis=1),
            goal=jax.vmap(env.desired_goal)(state0),
        )
        tr, mask, _ = jax.vmap(her.relabel)(_per_lane_keys(k_her, lane_ids), episodes)  # [b, T, C, ...]
        tr = tr._replace(reward=tr.reward + fail_bonus * episodes.failed[:, :, None])  # failure is goal-independent
        tr, mask = parallel.all_gather((tr, mask))  # [B, T, C, ...], lane-major in global lane order
        flat = jax.tree.map(lambda x: x.reshape(B * T * copies, *x.shape[3:]), tr)
        return final, flat, mask.reshape(-1), sums

    # ---- acting: 'steps' schedule --------------------------------------------------------
    def run_steps(
        key: jax.Array, lane_ids: jax.Array, params: Any, stats: RunningStats, s: State, nstate: NoiseState,
        factor: jax.Array,
    ) -> tuple[State, NoiseState, Transition, dict]:
        """``unroll_length`` steps of this device's auto-resetting lanes ``lane_ids [b]``; returns their
        states ``[b]``, every device's Transition ``[U*B]`` in global lane order and this device's
        episode sums."""

        def body(carry, k):
            s, nstate = carry
            a, nstate = explore(k, lane_ids, params, stats, s.obs, nstate, factor)
            ns = batched_env.step(s, a)
            done = ns.done.astype(jnp.float32)
            term = terminal(ns)
            success = ns.metrics.get("success", jnp.zeros_like(done)).astype(jnp.float32)
            reward = ns.reward + fail_bonus * term * (1.0 - success)
            tr = Transition(s.obs, a, reward, ns.info["final_obs"], term)
            nstate = _tree_where(done > 0, fresh_noise(b_local), nstate)  # new episode, new noise process
            ep = {"episodes": jnp.sum(done), "episode_return": jnp.sum(done * ns.info["episode_return"]),
                  "episode_length": jnp.sum(done * ns.info["episode_length"])}
            for name, v in ns.metrics.items():
                if v.shape == (b_local,):
                    ep[name] = jnp.sum(done * v)
            return (ns, nstate), (tr, ep)

        (s, nstate), (traj, ep) = jax.lax.scan(body, (s, nstate), jax.random.split(key, config.unroll_length))
        return s, nstate, _gather_time_major(traj), jax.tree.map(jnp.sum, ep)

    # ---- learning ------------------------------------------------------------------------
    def priority_error(td: jax.Array) -> jax.Array:
        """``|δ|`` clipped to ``priority_clip`` (when > 0) for the new priorities: ``[N] -> [N]``."""
        return jnp.minimum(jnp.abs(td), config.priority_clip) if config.priority_clip > 0 else td

    def learn_step(stats: RunningStats, carry: tuple, xs: tuple) -> tuple[tuple, dict[str, jax.Array]]:
        """One update (Algorithm 1, lines 9–17); ``xs = (key, index)`` with ``index`` the run's count of
        updates before this one (the actor and targets move when ``(index + 1) % policy_delay == 0``)."""
        key, index = xs
        actor_p, critic_p, t_actor, t_critic, a_opt, c_opt, buf = carry
        k_sample, k_smooth = jax.random.split(key) if config.target_noise > 0 else (key, key)
        smp = replay.sample(k_sample, buf)
        tr: Transition = smp.experience
        tr = tr._replace(obs=norm(stats, tr.obs), next_obs=norm(stats, tr.next_obs))
        weights = smp.weights if config.per else None
        next_a = act(t_actor, tr.next_obs)
        if config.target_noise > 0:
            next_a = smooth_target_action(k_smooth, next_a, config.target_noise, config.target_noise_clip)
        if config.twin_critics:
            next_q = clipped_double_q(q_values(t_critic, tr.next_obs, next_a))
        else:
            next_q = critic.apply(t_critic, tr.next_obs, next_a)
        y = td_target(tr.reward * config.reward_scale + config.reward_shift, tr.terminated, next_q, config.gamma)
        if config.target_clip:
            y = jnp.clip(y, config.target_clip[0], config.target_clip[1])

        def c_loss(p):
            if config.twin_critics:
                return twin_critic_loss(q_values(p, tr.obs, tr.action), y, weights)
            return critic_loss(critic.apply(p, tr.obs, tr.action), y, weights)

        (closs, td), grads = jax.value_and_grad(c_loss, has_aux=True)(critic_p)
        updates, c_opt = critic_tx.update(grads, c_opt, critic_p)
        critic_p = optax.apply_updates(critic_p, updates)

        def a_loss(p):
            q = q_first(critic_p, tr.obs, act(p, tr.obs))
            return actor_loss(q), q

        def actor_step(args: tuple) -> tuple[tuple, jax.Array, jax.Array]:
            """Actor step on ``−mean Q1(s, μ(s))`` and soft target updates."""
            actor_p, t_actor, t_critic, a_opt = args
            (aloss, q), grads = jax.value_and_grad(a_loss, has_aux=True)(actor_p)
            updates, a_opt = actor_tx.update(grads, a_opt, actor_p)
            actor_p = optax.apply_updates(actor_p, updates)
            t_actor = soft_update(t_actor, actor_p, config.tau)
            t_critic = soft_update(t_critic, critic_p, config.tau)
            return (actor_p, t_actor, t_critic, a_opt), aloss, q

        def hold(args: tuple) -> tuple[tuple, jax.Array, jax.Array]:
            """No actor or target step (``policy_delay``); the loss is still reported."""
            aloss, q = a_loss(args[0])
            return args, aloss, q

        args = (actor_p, t_actor, t_critic, a_opt)
        if config.policy_delay > 1:
            args, aloss, q = jax.lax.cond((index + 1) % config.policy_delay == 0, actor_step, hold, args)
        else:
            args, aloss, q = actor_step(args)
        actor_p, t_actor, t_critic, a_opt = args
        if config.per:
            err = jnp.mean(jnp.abs(td), axis=0) if config.twin_critics else td
            buf = replay.update_priorities(buf, smp.indices, priority_error(err))
        out = {"critic_loss": closs, "actor_loss": aloss, "q": jnp.mean(q), "td_abs": jnp.mean(jnp.abs(td))}
        return (actor_p, critic_p, t_actor, t_critic, a_opt, c_opt, buf), out

    def learn(state: DDPGState, key: jax.Array, n: int) -> tuple[DDPGState, dict[str, jax.Array], jax.Array]:
        """``n`` updates if enough transitions are stored; returns (state, metric sums, count)."""
        carry = (state.actor_params, state.critic_params, state.target_actor_params, state.target_critic_params,
                 state.actor_opt, state.critic_opt, state.replay)

        def run(c):
            xs = (jax.random.split(key, n), state.updates + jnp.arange(n, dtype=jnp.int32))
            c, out = jax.lax.scan(lambda c_, x: learn_step(state.obs_stats, c_, x), c, xs)
            return c, jax.tree.map(jnp.sum, out), jnp.asarray(n, jnp.float32)

        def skip(c):
            zero = jnp.zeros((), jnp.float32)
            return c, {"critic_loss": zero, "actor_loss": zero, "q": zero, "td_abs": zero}, zero

        carry, sums, count = jax.lax.cond(state.replay.size >= min_stored, run, skip, carry)
        a_p, c_p, ta, tc, ao, co, buf = carry
        state = state.replace(actor_params=a_p, critic_params=c_p, target_actor_params=ta, target_critic_params=tc,
                              actor_opt=ao, critic_opt=co, replay=buf, updates=state.updates + count.astype(jnp.int32))
        return state, sums, count

    def observe(stats: RunningStats, obs: jax.Array, mask: jax.Array | None) -> RunningStats:
        """Merge the stored rows ``obs [N, O]`` (where ``mask [N]``) into the statistics (``normalize_obs``)."""
        if not config.normalize_obs:
            return stats
        return update_running_stats(stats, obs, mask=mask)

    # ---- one iteration, one chunk (inside shard_lanes: this device's b_local lanes) ---------
    def iteration(state: DDPGState, lane_ids: jax.Array) -> tuple[DDPGState, tuple]:
        key, k_act, k_learn = jax.random.split(state.key, 3)
        if config.schedule == "episodes":
            env_state, flat, mask, ep = run_episodes(k_act, lane_ids, state.actor_params, state.obs_stats,
                                                     noise_factor(state.iteration))
            buf = replay.add(state.replay, flat, mask=mask)
            state = state.replace(env_state=env_state, replay=buf, obs_stats=observe(state.obs_stats, flat.obs, mask))
            n_updates = config.updates_per_cycle
        else:
            env_state, nstate, flat, ep = run_steps(k_act, lane_ids, state.actor_params, state.obs_stats,
                                                    state.env_state, state.noise_state, noise_factor(state.iteration))
            state = state.replace(env_state=env_state, noise_state=nstate, replay=replay.add(state.replay, flat),
                                  obs_stats=observe(state.obs_stats, flat.obs, None))
            n_updates = config.updates_per_iteration
        state, sums, count = learn(state, k_learn, n_updates)
        state = state.replace(key=key, iteration=state.iteration + 1)
        return state, (sums, count, ep)

    def chunk_fn(state: DDPGState) -> tuple[DDPGState, Metrics]:
        start = state
        lane_ids = parallel.global_lane_ids(b_local)
        state, (sums, count, ep) = jax.lax.scan(lambda s, _: iteration(s, lane_ids), state, None, length=chunk)
        state = _like(state, start)
        n = jnp.sum(count)
        # means over the chunk's updates; 0 before learning starts (``updates`` says how many ran)
        out: dict[str, jax.Array] = {k: jnp.sum(v) / jnp.maximum(n, 1.0) for k, v in sums.items()}
        ep = parallel.psum(jax.tree.map(jnp.sum, ep))  # every device's lanes
        episodes = ep.pop("episodes")
        out["episodes"] = episodes
        for k, v in ep.items():
            out[k] = jnp.where(episodes > 0, v / jnp.maximum(episodes, 1.0), jnp.nan)
        out["replay_size"] = state.replay.size.astype(jnp.float32)
        out["updates"] = state.updates.astype(jnp.float32)
        if config.per:
            out["beta"] = state.replay.beta
        return state, out

    lanes, same = parallel.P(_LANES), parallel.P()
    state_specs = DDPGState(
        actor_params=same,
        critic_params=same,
        target_actor_params=same,
        target_critic_params=same,
        actor_opt=same,
        critic_opt=same,
        replay=same,
        env_state=lanes,
        noise_state=lanes,
        obs_stats=same,
        key=same,
        iteration=same,
        updates=same,
    )
    update = parallel.shard_lanes(chunk_fn, mesh, in_specs=(state_specs,), out_specs=(state_specs, same))

    def policy(state: DDPGState) -> Policy:
        def greedy(obs: jax.Array) -> jax.Array:
            return act(state.actor_params, norm(state.obs_stats, obs))

        return greedy

    return Trainer(
        init=init,
        update=update,
        policy=policy,
        num_updates=num_updates,
        env_steps_per_update=steps_per_iteration * chunk,
    )


def make_train(
    config: DDPGConfig,
    env: Env,
    *,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int | None = None,
) -> Callable[[jax.Array], tuple[DDPGState, Metrics]]:
    """``train(key) -> (final state, metrics [num_updates])``: the whole run, pure and jittable.

    ``mesh``: as :func:`make_trainer` (default: all devices).
    """
    trainer = make_trainer(config, env, mesh=mesh, iterations_per_update=iterations_per_update)

    def train(key: jax.Array) -> tuple[DDPGState, Metrics]:
        state = trainer.init(key)
        return jax.lax.scan(lambda s, _: trainer.update(s), state, None, length=trainer.num_updates)

    return train
