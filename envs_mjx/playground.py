"""MuJoCo Playground environments (``pip install -e ".[playground]"``) as environments of this library.

MuJoCo Playground (package ``mujoco_playground``) envs are not :class:`brax.envs.base.Env` s: their
``reset(key)`` / ``step(state, action)`` return Playground's own ``State``, whose physics is ``data``
(an ``mjx.Data``; brax's is ``pipeline_state``), and whose ``obs`` is an array ``[D]`` or a dict of
arrays. :class:`PlaygroundEnv` presents such an env as a brax ``Env``: its states are brax
``State`` s (``pipeline_state`` = Playground's ``data``) with ``obs`` the policy's observation
``[D]`` — for a dict observation its ``obs_key`` entry (``"state"``, the key brax's networks read
by default, as Playground's brax training does; the whole dict rides in ``info`` for the env's own
``step``) — so every trainer, wrapper and evaluation of this library takes it as it takes brax's envs.

* :func:`load` — ``load("CartpoleBalance", impl="warp")``: Playground's ``registry.load`` with
  ``config_overrides`` (``impl`` defaults to ``"jax"``, MJX's JAX backend, which runs on any device;
  ``"warp"`` is MuJoCo Warp, NVIDIA GPUs only), wrapped in :class:`PlaygroundEnv`.
* :func:`adapt` — any env the trainers take: a brax ``Env`` (ours included) as it is, anything else
  with ``reset`` / ``step`` / ``action_size`` (a Playground env, a user's env of that shape) in a
  :class:`PlaygroundEnv`. The trainers' ``make_trainer`` call it first.
* :func:`names`, :func:`require` — Playground's registered names; the package or a one-line
  :class:`PlaygroundMissingError` naming the extra.

``mujoco_playground`` is imported only by :func:`require` (and so by :func:`load`, :func:`names`):
this module, and the library, import without it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from envs_mjx.base import check_action

__all__ = [
    "DEFAULT_IMPL",
    "EXTRA",
    "FULL_OBS_KEY",
    "OBS_KEY",
    "PREFIX",
    "PlaygroundEnv",
    "PlaygroundMissingError",
    "adapt",
    "default_config",
    "load",
    "names",
    "require",
    "suite_of",
]

PREFIX = "playground:"
"""The ``--env`` prefix of Playground's envs (``--env playground:CartpoleBalance``)."""

EXTRA = 'pip install -e ".[playground]"'
"""How to install MuJoCo Playground with this project (the ``playground`` extra)."""

DEFAULT_IMPL = "jax"
"""The MJX backend :func:`load` asks for unless ``impl`` is given (Playground's own default is ``warp``)."""

OBS_KEY = "state"
"""The entry of a dict observation the policy sees (brax's ``policy_obs_key`` default)."""

FULL_OBS_KEY = "playground_obs"
"""``info`` key of the whole dict observation of a :class:`PlaygroundEnv` with dict observations."""

SUITES = ("dm_control_suite", "locomotion", "manipulation")
"""Playground's suites, in the order its registry searches them."""


class PlaygroundMissingError(ImportError, ValueError):
    """MuJoCo Playground is not installed. The message is one line naming what needs it and the extra,
    e.g. ``--env playground:CartpoleBalance needs MuJoCo Playground: pip install -e ".[playground]"``.
    Also a ``ValueError``: a command line reports it as bad input (exit 2, no traceback)."""


def require(what: str = "MuJoCo Playground environments") -> Any:
    """The ``mujoco_playground`` package, imported on first use.

    Raises:
      PlaygroundMissingError: it is not installed (``what`` names what needed it).
    """
    try:
        import mujoco_playground
    except ImportError:
        raise PlaygroundMissingError(f"{what} needs MuJoCo Playground: {EXTRA}") from None
    return mujoco_playground


def names(suite: str | None = None) -> tuple[str, ...]:
    """Playground's registered env names (of one of :data:`SUITES` if given), in its registry's order."""
    pg = require()
    if suite is None:
        return tuple(pg.registry.ALL_ENVS)
    return tuple(getattr(pg, suite).ALL_ENVS)


def suite_of(name: str) -> str | None:
    """The suite of :data:`SUITES` that registers ``name``, or None."""
    pg = require(f"{PREFIX}{name}")
    return next((s for s in SUITES if name in getattr(pg, s).ALL_ENVS), None)


def _check_name(name: str) -> None:
    """Raise ``ValueError`` (one line listing the valid names by suite) unless Playground registers ``name``."""
    if suite_of(name) is None:
        listed = "; ".join(f"{s}: {', '.join(names(s))}" for s in SUITES)
        raise ValueError(f"unknown MuJoCo Playground environment {name!r}; valid names ({PREFIX}<name>): {listed}")


def _flat_keys(config: Any, prefix: str = "") -> list[str]:
    """The dotted keys of a (nested) ``ml_collections.ConfigDict``, as ``config_overrides`` names them."""
    out = []
    for k, v in config.items():
        out += _flat_keys(v, f"{prefix}{k}.") if hasattr(v, "items") else [f"{prefix}{k}"]
    return out


def default_config(name: str) -> Any:
    """Playground's default config (an ``ml_collections.ConfigDict``) of env ``name``."""
    _check_name(name)
    return require(f"{PREFIX}{name}").registry.get_default_config(name)


def load(name: str, obs_key: str = OBS_KEY, **config_overrides: Any) -> PlaygroundEnv:
    """Playground's env ``name`` (``"CartpoleBalance"``; a ``playground:`` prefix is dropped) as a
    :class:`PlaygroundEnv`.

    Args:
      name: a name of :func:`names`.
      obs_key: the policy's entry of a dict observation (:data:`OBS_KEY`).
      config_overrides: Playground's ``config_overrides`` (dotted keys of its env config, e.g.
        ``impl="warp"``, ``episode_length=500``); ``impl`` defaults to :data:`DEFAULT_IMPL`.
    Raises:
      PlaygroundMissingError: ``mujoco_playground`` is not installed.
      ValueError: an unknown name (the message lists the valid ones), an override that is not a key of
        the env's config (the message lists them) or that the config rejects (one line).
    """
    name = name.removeprefix(PREFIX)
    pg = require(f"{PREFIX}{name}")
    valid = _flat_keys(default_config(name))
    unknown = [k for k in config_overrides if k not in valid]
    if unknown:
        raise ValueError(f"{PREFIX}{name}: {unknown[0]!r} is not a setting of its config; valid: {', '.join(valid)}")
    overrides = {"impl": DEFAULT_IMPL, **config_overrides}
    try:
        env = pg.registry.load(name, config_overrides=overrides)
    except (TypeError, ValueError, KeyError) as e:
        raise ValueError(f"{PREFIX}{name} with {overrides}: {' '.join(str(e).split())}") from None
    return PlaygroundEnv(env, obs_key=obs_key, name=f"{PREFIX}{name}")


def adapt(env: Any, obs_key: str = OBS_KEY) -> Env:
    """``env`` as the trainers take it: a brax ``Env`` (brax's, ours, a :class:`PlaygroundEnv`, any
    wrapper of them) unchanged; any other env with ``reset(key)`` / ``step(state, action)`` /
    ``action_size`` (a Playground ``MjxEnv``, a user's env whose state holds ``data`` or a dict
    observation) in a :class:`PlaygroundEnv` picking ``obs_key``."""
    if isinstance(env, Env):
        return env
    return PlaygroundEnv(env, obs_key=obs_key)


class PlaygroundEnv(Env):
    """A Playground-style env presented as an unbatched brax ``Env``.

    The wrapped env's ``reset(key)`` / ``step(state, action)`` return a state with ``obs``, ``reward``,
    ``done``, ``metrics``, ``info`` and its physics in ``data`` (Playground) or ``pipeline_state``
    (brax); ``obs`` is ``[D]`` or a dict whose ``obs_key`` entry is ``[D]``. This env's states are brax
    ``State`` s: ``pipeline_state`` the physics, ``obs`` ``[D]`` (the ``obs_key`` entry; the whole dict in
    ``info[FULL_OBS_KEY]``), the rest as the env gives them. ``step`` checks the action's static shape
    (``[action_size]``, :func:`~envs_mjx.base.check_action`), converts it to float32 and hands the env
    a state of its own kind with every ``info`` key (wrappers' included, as Playground's brax wrappers
    do); keys the env drops are kept. Actions go to the env as given (Playground's envs write them to
    ``data.ctrl``; MuJoCo clamps them to the actuators' ranges, rewards may see them unclamped).

    Other attributes (``dt``, ``mj_model``, ``mjx_model``, ``render``, …) are the wrapped env's.

    Args:
      env: the Playground-style env (unbatched).
      obs_key: the policy's entry of a dict observation.
      name: for messages and reports (default: the env's class name).
      episode_length: the time limit (default: the env config's ``episode_length``, else none).
    Raises:
      ValueError: a dict observation without ``obs_key`` or whose entry is not one vector ``[D]``.
    """

    def __init__(self, env: Any, obs_key: str = OBS_KEY, name: str | None = None, episode_length: int | None = None):
        self.env = env
        self.obs_key = obs_key
        self.name = name or type(env).__name__
        shape = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
        self._state_type = type(shape)
        self._physics = "data" if hasattr(shape, "data") else "pipeline_state"
        self.dict_obs = isinstance(shape.obs, Mapping)
        obs = shape.obs
        if self.dict_obs:
            if obs_key not in obs:
                raise ValueError(f"{self.name}: obs_key={obs_key!r} is not a key of its observation; "
                                 f"valid: {', '.join(map(str, obs))}")  # fmt: skip
            obs = obs[obs_key]
        if len(obs.shape) != 1:
            raise ValueError(f"{self.name}: the policy's observation has shape {tuple(obs.shape)}; expected one "
                             "vector [D]" + (f" (obs_key={obs_key!r})" if self.dict_obs else ""))  # fmt: skip
        self._obs_size = int(obs.shape[0])
        config = getattr(env, "_config", None)
        self._episode_length = episode_length or getattr(config, "episode_length", None)

    def __getattr__(self, name: str) -> Any:
        if name in ("env", "__setstate__") or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.env, name)

    @property
    def observation_size(self) -> int:
        """D: the size of the policy's observation."""
        return self._obs_size

    @property
    def action_size(self) -> int:
        return int(self.env.action_size)

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def unwrapped(self) -> PlaygroundEnv:
        return self

    @property
    def episode_length(self) -> int | None:
        """The env config's ``episode_length`` (None if it has none): the default time limit."""
        return None if self._episode_length is None else int(self._episode_length)

    def _to_brax(self, state: Any, info: dict[str, Any]) -> State:
        """The brax ``State`` of the env's ``state`` with ``info`` (unbatched)."""
        obs = state.obs
        if self.dict_obs:
            info = {**info, FULL_OBS_KEY: obs}
            obs = obs[self.obs_key]
        physics = getattr(state, self._physics)
        return State(pipeline_state=physics, obs=obs, reward=state.reward, done=state.done,
                     metrics=dict(state.metrics), info=info)  # fmt: skip

    def reset(self, rng: jax.Array) -> State:
        """Start an episode from the PRNG key ``rng`` (unbatched)."""
        state = self.env.reset(rng)
        return self._to_brax(state, dict(state.info))

    def step(self, state: State, action: jax.Array) -> State:
        """One step of the env with ``action [A]``."""
        check_action(f"{self.name}.step", action, (self.action_size,), f"action_size={self.action_size}")
        info = dict(state.info)
        obs = info.pop(FULL_OBS_KEY) if self.dict_obs else state.obs
        inner = self._state_type(**{self._physics: state.pipeline_state}, obs=obs, reward=state.reward,
                                 done=state.done, metrics=dict(state.metrics), info=dict(info))  # fmt: skip
        nxt = self.env.step(inner, jnp.asarray(action, jnp.float32))
        return self._to_brax(nxt, {**info, **nxt.info})
