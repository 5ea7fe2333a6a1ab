"""PPO's actor and critic behind one interface: feed-forward (``policy='mlp'``) or recurrent
(``policy='lstm'``, thesis §5.7), so that one trainer runs both.

The trainer keeps per lane a *memory* — ``{"actor": (c, h), "critic": (c, h)}`` for the LSTM, ``()``
for the MLP — advances it while acting, records the memory every step started from, and
trains on sequences of :attr:`PPONets.seq_length` steps that restart from those records
(``jaxrl_robot.recurrent.unroll``).  For the MLP a sequence is one step and every memory is empty,
so each function below reduces to the plain network call.

Shapes: ``T`` steps × ``B`` lanes; ``memory`` leaves ``[T, B, H]``; ``reset [T, B]`` is 1.0 where a
step restarts from its recorded memory (a sequence's or an episode's first step).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

from jaxrl_robot.agents import on_policy
from jaxrl_robot.agents.ppo.config import PPOConfig
from jaxrl_robot.networks import apply_actor
from jaxrl_robot.recurrent import LSTMActor, LSTMCritic, unroll, zero_carry

__all__ = ["PPONets", "make_ppo_nets"]


class PPONets(NamedTuple):
    """The functions PPO calls its networks through (see the module docstring for shapes).

    Attributes:
      seq_length: steps per training sequence (1 for the MLP).
      actor, critic: the flax modules.
      init: ``(key_actor, key_critic, obs_size) -> (actor params, actor batch_stats, critic params)``.
      memory: ``batch_shape -> memory`` of zeros (``()`` for the MLP).
      act: ``(actor params, actor stats, critic params, memory [B], obs [B, D]) -> (memory [B],
        (mean, log_std) [B, A])``, acting mode.
      actor_forward: ``(params, stats, memory [T, B], reset [T, B], obs [T, B, D], train) ->
        ((mean, log_std) [T, B, A], new stats)``.
      critic_forward: ``(params, memory [T, B], reset [T, B], obs [T, B, D]) -> (V [T, B],
        critic carries after each step [T, B, ...])``.
      next_values: ``(params, carries after [T, B, ...], next_obs [T, B, D]) -> V(s') [T, B]``:
        the successor's value, continuing each step's critic memory.
    """

    seq_length: int
    actor: Any
    critic: Any
    init: Callable
    memory: Callable[[tuple[int, ...]], Any]
    act: Callable
    actor_forward: Callable
    critic_forward: Callable
    next_values: Callable


def make_ppo_nets(config: PPOConfig, action_size: int, bn_axis_name: str | None = None) -> PPONets:
    """The :class:`PPONets` of ``config.policy`` (``bn_axis_name``: see ``on_policy.make_actor_critic``)."""
    if config.policy == "lstm":
        return _lstm_nets(config, action_size)
    actor, critic = on_policy.make_actor_critic(
        config, action_size, bn_axis_name=bn_axis_name, squash=not config.tanh_actions
    )

    def act(actor_params, actor_stats, critic_params, memory, obs):
        return memory, apply_actor(actor, actor_params, actor_stats, obs)[0]

    def actor_forward(params, stats, memory, reset, obs, train):
        if not train:
            return apply_actor(actor, params, stats, obs)
        (mean, log_std), stats = apply_actor(actor, params, stats, obs.reshape((-1, obs.shape[-1])), train=True)
        shape = obs.shape[:-1] + mean.shape[-1:]
        return (mean.reshape(shape), log_std.reshape(shape)), stats

    def critic_forward(params, memory, reset, obs):
        return critic.apply({"params": params}, obs), ()

    def next_values(params, after, next_obs):
        return critic.apply({"params": params}, next_obs)

    def init(key_actor, key_critic, obs_size):
        return on_policy.init_actor_critic(key_actor, key_critic, actor, critic, obs_size)

    return PPONets(1, actor, critic, init, lambda shape: (), act, actor_forward, critic_forward, next_values)


def _lstm_nets(config: PPOConfig, action_size: int) -> PPONets:
    sigma = on_policy.action_sigma(config, action_size)
    actor = LSTMActor(action_size, tuple(config.actor_hidden), config.lstm_size, sigma, config.learn_std)
    critic = LSTMCritic(tuple(config.critic_hidden), config.lstm_size)
    size = config.lstm_size

    def memory(shape):
        return {"actor": zero_carry(shape, size), "critic": zero_carry(shape, size)}

    def init(key_actor, key_critic, obs_size):
        obs, carry = jax.numpy.zeros((1, obs_size)), zero_carry((1,), size)
        return actor.init(key_actor, carry, obs)["params"], {}, critic.init(key_critic, carry, obs)["params"]

    def act(actor_params, actor_stats, critic_params, mem, obs):
        a_carry, out = actor.apply({"params": actor_params}, mem["actor"], obs)
        c_carry, _ = critic.apply({"params": critic_params}, mem["critic"], obs)
        return {"actor": a_carry, "critic": c_carry}, out

    def actor_forward(params, stats, mem, reset, obs, train):
        step = lambda c, x: actor.apply({"params": params}, c, x)  # noqa: E731
        return unroll(step, mem["actor"], reset, obs)[0], stats

    def critic_forward(params, mem, reset, obs):
        return unroll(lambda c, x: critic.apply({"params": params}, c, x), mem["critic"], reset, obs)

    def next_values(params, after, next_obs):
        return critic.apply({"params": params}, after, next_obs)[1]

    return PPONets(config.seq_length, actor, critic, init, memory, act, actor_forward, critic_forward, next_values)
