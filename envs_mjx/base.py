"""Brax-compatible environment base class and training wrappers.

``RobotEnv`` subclasses :class:`brax.envs.base.Env` and returns
:class:`brax.envs.base.State`, so brax's own wrappers and trainers accept every
environment here.  ``reset(key)`` and ``step(state, action)`` are pure and unbatched.

Conventions shared by all environments:

* Actions arrive in ``[-1, 1]``; non-finite components are replaced by 0 and counted in
  ``metrics["invalid_action"]``, then the action is clipped and multiplied by the
  environment's scale vector ``C`` (``env.action_scale``).  See :func:`sanitize_action`.
* ``step`` checks the action's static shape, ``(action_size,)``, and the training wrappers
  check theirs, ``state.done.shape + (action_size,)`` (``[B, A]`` batched), while tracing: a
  wrong shape raises :class:`ActionShapeError` instead of broadcasting; nothing is checked at
  run time.  Any real dtype (float or int) is accepted and converted to float32; bool and
  complex actions raise the same error.  See :func:`check_action`.
* ``state.info`` keeps every key it came in with (brax wrappers add their own), so an
  environment's ``step`` updates ``info`` rather than rebuilding it.
* A state's physics is brax's ``pipeline_state`` or, for a state of MuJoCo Playground's kind,
  ``data``: the wrappers read and replace it through :func:`physics_of` / :func:`with_physics`, so they
  also take such states (``envs_mjx.playground`` presents Playground's envs as brax ``Env`` s).
* ``state.info["params"]`` holds *episode parameters*: traced values that a trainer may
  change during training without recompiling (for example the reference-state window
  of the tracking environments).  ``reset(key, params)`` takes them and they survive
  auto-resets.

Wrappers (:func:`wrap_for_training` composes them):

* :class:`EpisodeWrapper` — time limit; marks ``info["truncation"]`` (1 only when the
  limit ends an episode that did not terminate), counts ``info["steps"]`` and keeps
  running ``info["episode_return"]`` / ``info["episode_length"]``.
* :class:`AutoResetWrapper` — on ``done`` calls ``reset`` with a fresh key per lane
  (every episode gets a new goal and start), keeping the finished step's ``reward``,
  ``done``, ``metrics``, ``truncation`` and the episode totals, and the terminal
  observation in ``info["final_obs"]`` for bootstrapping.
* :class:`VmapWrapper` — maps the unbatched env over a leading lane axis.
* :class:`PoolResetWrapper` — a batched alternative to the two above: finished lanes take
  a pre-drawn episode from a pool that is refreshed by a fixed number of resets per step
  (``refresh`` × lanes), so every step costs ``refresh`` resets per lane; the auto-reset costs
  one per lane at the steps where some lane finished (with Warp physics at every step).
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State, Wrapper

from envs_mjx import backend
from envs_mjx.config import apply_overrides

__all__ = [
    "DEFAULT_EPISODE_LENGTH",
    "ActionRepeatWrapper",
    "ActionShapeError",
    "AutoResetWrapper",
    "ClipActionWrapper",
    "EpisodeWrapper",
    "PoolResetWrapper",
    "RobotEnv",
    "State",
    "TanhActionWrapper",
    "VmapWrapper",
    "check_action",
    "default_episode_length",
    "map_lanes",
    "physics_of",
    "sanitize_action",
    "steps_mjx_physics",
    "with_physics",
    "wrap_for_training",
]


class ActionShapeError(ValueError):
    """An action whose static shape (or dtype) does not fit the env or wrapper stepping it.

    The message is one line naming the env or wrapper, the expected shape and the given one, e.g.
    ``arm7.step: action has shape (1,), expected (3,) (action_size=3)``."""


def check_action(owner: str, action: Any, expected: tuple[int, ...], detail: str) -> None:
    """Raise :class:`ActionShapeError` unless ``action`` has shape ``expected`` and a real dtype.

    A Python check of static properties, so under ``jit`` / ``vmap`` / ``eval_shape`` it runs once
    while tracing and costs nothing at run time.  Integer and floating dtypes pass (envs convert
    them to float32, :func:`sanitize_action`); bool and complex raise.

    Args:
      owner: who steps, for the message (``"arm7.step"``, ``"VmapWrapper.step (arm7)"``).
      action: the action (array, tracer or nested list).
      expected: its required shape.
      detail: where ``expected`` comes from (``"action_size=3"``), for the message.
    """
    shape = tuple(np.shape(action))
    expected = tuple(int(n) for n in expected)
    if shape != expected:
        raise ActionShapeError(f"{owner}: action has shape {shape}, expected {expected} ({detail})")
    dtype = getattr(action, "dtype", None)
    dtype = np.asarray(action).dtype if dtype is None else np.dtype(dtype)
    if not (jnp.issubdtype(dtype, jnp.floating) or jnp.issubdtype(dtype, jnp.integer)):
        raise ActionShapeError(f"{owner}: action has dtype {dtype}, expected a real number type (float or int)")


def sanitize_action(action: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Convert to float32, replace non-finite components by 0 and clip to [-1, 1].

    Args:
      action: ``[A]`` raw action, any real dtype (unbatched; works batched too).
    Returns:
      ``(clean [A] float32, invalid [])`` where ``invalid`` is 1.0 if any component was non-finite.
    """
    action = jnp.asarray(action, jnp.float32)
    finite = jnp.isfinite(action)
    clean = jnp.clip(jnp.where(finite, action, 0.0), -1.0, 1.0)
    invalid = jnp.any(~finite, axis=-1).astype(jnp.float32)
    return clean, invalid


class RobotEnv(Env, abc.ABC):
    """Base class of the project's environments.

    Subclasses define ``Config`` (a frozen dataclass with the thesis's defaults and a
    ``validate()`` method), ``name``, ``observation_size`` and ``action_size`` (class attributes,
    or properties where the config decides them) and the pure ``reset`` / ``step``; the config's
    ``action_scale`` is the scale vector C unless ``action_scale`` is overridden.
    """

    name: ClassVar[str] = "robot"
    Config: ClassVar[type]

    def __init__(self, config: Any | None = None, **overrides: Any):
        cfg = self.default_config() if config is None else config
        cfg = apply_overrides(cfg, overrides, owner=self.name)
        validate = getattr(cfg, "validate", None)
        if validate is not None:
            validate()
        self.config = cfg

    @classmethod
    def default_config(cls) -> Any:
        """The thesis's settings for this environment (a frozen dataclass)."""
        return cls.Config()

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def steps_mjx_physics(self) -> bool:
        """Whether ``reset`` / ``step`` run MuJoCo MJX physics (True here; an env stepping plain JAX, such as
        ``arm7`` in ``kinematic`` mode, says False): where it is False the trainers map the lanes over several
        GPUs with ``shard_map`` (``jaxrl_robot.parallel.lane_map_impl``)."""
        return True

    @property
    def action_scale(self) -> jax.Array:
        """The scale vector C, ``[action_size]`` float32: env action = C * clip(a, -1, 1).

        By default ``config.action_scale`` (one number for every action, or one per action); an env
        whose config has no such field overrides this property."""
        return jnp.broadcast_to(jnp.asarray(self.config.action_scale, jnp.float32), (self.action_size,))

    @property
    def episode_length(self) -> int:
        """Default time limit in control steps (``config.max_steps``)."""
        return int(self.config.max_steps)

    def check_action(self, action: jax.Array, method: str = "step") -> None:
        """Raise :class:`ActionShapeError` unless ``action`` is ``[action_size]`` (unbatched) of a real
        dtype; a trace-time check (:func:`check_action`), which every env's ``step`` makes first."""
        check_action(f"{self.name}.{method}", action, (self.action_size,), f"action_size={self.action_size}")

    def default_params(self) -> dict[str, jax.Array]:
        """Episode parameters (traced, schedulable) used when ``reset`` gets none."""
        return {}

    @abc.abstractmethod
    def reset(self, rng: jax.Array, params: Mapping[str, jax.Array] | None = None) -> State:
        """Start an episode. ``rng``: a PRNG key (unbatched)."""

    @abc.abstractmethod
    def step(self, state: State, action: jax.Array) -> State:
        """Advance one control step with ``action [A]`` in [-1, 1]^A; first :meth:`check_action`."""


def steps_mjx_physics(env: Any) -> bool:
    """``env.steps_mjx_physics`` through any wrappers; True for an env that does not say (brax's, Playground's,
    a user's env): the lane map that compiles MJX physics on several GPUs is then chosen."""
    return bool(getattr(env, "steps_mjx_physics", True))


def _physics_field(state: Any) -> str:
    """The field holding a state's physics: ``pipeline_state`` (brax) or ``data`` (MuJoCo Playground)."""
    return "pipeline_state" if hasattr(state, "pipeline_state") else "data"


def physics_of(state: Any) -> Any:
    """The physics of an env state (unbatched or batched): brax's ``pipeline_state`` or Playground's ``data``."""
    return getattr(state, _physics_field(state))


def with_physics(state: Any, physics: Any) -> Any:
    """``state`` with its physics (:func:`physics_of`) replaced by ``physics``."""
    return state.replace(**{_physics_field(state): physics})


def _reset(env: Env, key: jax.Array, params: Any) -> State:
    """Call ``env.reset`` with episode parameters if the env takes them."""
    if params is None:
        return env.reset(key)
    return env.reset(key, params)


class _ParamWrapper(Wrapper):
    """A wrapper whose ``reset`` forwards optional episode parameters and whose ``step`` checks the
    action's static shape first (:meth:`_check_action`)."""

    def reset(self, rng: jax.Array, params: Any = None) -> State:  # noqa: D102
        return _reset(self.env, rng, params)

    def _check_action(self, state: State, action: jax.Array) -> None:
        """Raise :class:`ActionShapeError` unless ``action`` is ``state.done.shape + (action_size,)``:
        ``[A]`` for an unbatched state, ``[B, A]`` for ``B`` lanes (checked while tracing).  An env
        object that declares no ``action_size`` (not a brax ``Env``) is not checked."""
        size = getattr(self, "action_size", None)
        if size is None:
            return
        size = int(size)
        inner = getattr(self, "unwrapped", self.env)
        owner = f"{type(self).__name__}.step ({getattr(inner, 'name', type(inner).__name__)})"
        batch = tuple(np.shape(state.done))
        lanes = "" if not batch else f"lanes={batch[0]}, " if len(batch) == 1 else f"batch={batch}, "
        check_action(owner, action, batch + (size,), f"{lanes}action_size={size}")


class ClipActionWrapper(_ParamWrapper):
    """Actions clipped to ``[low, high]`` before the env steps (unbatched or batched).

    For envs that take the action as given, e.g. brax's, whose control cost squares the raw action:
    a Gaussian policy's sample then costs what it would move the robot, not more. The policy keeps its
    unclipped sample for its log-probability (as Stable-Baselines3 clips a Gaussian's actions)."""

    def __init__(self, env: Env, low: float = -1.0, high: float = 1.0):
        super().__init__(env)
        if not float(low) < float(high):
            raise ValueError(f"ClipActionWrapper: low={low!r} must be below high={high!r}")
        self.low, self.high = float(low), float(high)

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(state, action)
        return self.env.step(state, jnp.clip(action, self.low, self.high))


class TanhActionWrapper(_ParamWrapper):
    """Actions squashed by ``tanh`` into ``(-1, 1)`` before the env steps (unbatched or batched):
    the env side of a tanh-squashed Gaussian policy, which keeps its unsquashed sample."""

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(state, action)
        return self.env.step(state, jnp.tanh(action))


class ActionRepeatWrapper(_ParamWrapper):
    """Each action held for ``repeat`` steps of the env, their rewards summed (unbatched).

    The agent decides every ``repeat`` env steps (brax's ``action_repeat``); a time limit outside it
    counts decisions. Once a step ends the episode (``done``), the later steps of the repeat leave the
    state as it is and add no reward; the metrics are the last step's."""

    def __init__(self, env: Env, repeat: int):
        super().__init__(env)
        if int(repeat) < 1:
            raise ValueError(f"ActionRepeatWrapper: repeat={repeat!r} must be >= 1")
        self.repeat = int(repeat)

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(state, action)

        def one(carry: tuple[State, jax.Array], _: None) -> tuple[tuple[State, jax.Array], None]:
            s, total = carry
            ended = s.done > 0
            ns = backend.select(ended, s, self.env.step(s, action))
            return (ns, total + jnp.where(ended, 0.0, ns.reward)), None

        zero = jnp.zeros_like(state.reward)
        (nstate, total), _ = jax.lax.scan(one, (state, zero), None, length=self.repeat)
        return nstate.replace(reward=total)


class EpisodeWrapper(_ParamWrapper):
    """Time limit with truncation marked apart from termination (unbatched)."""

    def __init__(self, env: Env, episode_length: int):
        super().__init__(env)
        if int(episode_length) < 1:
            raise ValueError(f"episode_length={episode_length!r} must be >= 1")
        self.episode_length = int(episode_length)

    def reset(self, rng: jax.Array, params: Any = None) -> State:
        state = _reset(self.env, rng, params)
        zero = jnp.zeros((), jnp.float32)
        info = dict(state.info)
        info.update(
            steps=jnp.zeros((), jnp.int32),
            truncation=zero,
            episode_return=zero,
            episode_length=zero,
        )
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(state, action)
        prev_done = state.done.astype(jnp.float32)
        # The inner env steps from done = 0: an env that never writes ``done`` (brax's halfcheetah,
        # reacher) would otherwise carry the time limit's done into every later step.
        nstate = self.env.step(state.replace(done=jnp.zeros_like(state.done)), action)
        info = dict(nstate.info)
        steps = state.info["steps"] + 1
        at_limit = steps >= self.episode_length
        terminated = nstate.done.astype(jnp.float32)
        info["truncation"] = jnp.where(at_limit, 1.0 - terminated, 0.0)
        info["steps"] = steps
        info["episode_return"] = state.info["episode_return"] * (1.0 - prev_done) + nstate.reward
        info["episode_length"] = state.info["episode_length"] * (1.0 - prev_done) + 1.0
        done = jnp.maximum(terminated, at_limit.astype(jnp.float32))
        return nstate.replace(done=done, info=info)


class AutoResetWrapper(_ParamWrapper):
    """Resets finished episodes with a fresh key per lane (unbatched; vmap outside).

    Per-lane reset keys live in ``info["reset_key"]``.  Keys kept from the finished
    step (not from the fresh episode) are listed in ``keep_keys``.  The reset is computed only
    at steps where some lane is done (:func:`run_if`; with Warp physics at every step), so an env
    whose ``reset`` costs many steps (MuJoCo Playground's ``CheetahRun`` settles 200 physics steps)
    steps as fast as its ``step`` between episode ends.
    """

    keep_keys = ("truncation", "episode_return", "episode_length", "params")

    def reset(self, rng: jax.Array, params: Any = None) -> State:
        rng, sub = jax.random.split(rng)
        state = _reset(self.env, sub, params)
        info = dict(state.info)
        info["reset_key"] = rng
        info["final_obs"] = state.obs
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(state, action)
        nstate = self.env.step(state, action)
        key, sub = jax.random.split(nstate.info["reset_key"])
        done = nstate.done > 0
        if backend.has_shared(physics_of(nstate)):  # Warp data: its shared fields cannot ride a batched loop
            out = self._restart(nstate, sub, done)
        else:
            out = run_if(done, lambda s, k: self._restart(s, k, done), nstate, sub)
        info = dict(out.info)
        info["final_obs"] = nstate.obs
        info["reset_key"] = key
        return out.replace(info=info)

    def _restart(self, nstate: State, key: jax.Array, done: jax.Array) -> State:
        """``nstate``, or where ``done`` the fresh episode of ``reset(key)`` (with ``nstate``'s ``keep_keys``)."""
        fresh = _reset(self.env, key, nstate.info.get("params"))

        def pick(a, b):
            return jnp.where(done, a, b)

        fresh_info = {k: v for k, v in fresh.info.items() if k in nstate.info}
        info = dict(nstate.info)
        merged = jax.tree.map(pick, fresh_info, {k: nstate.info[k] for k in fresh_info})
        info.update(merged)
        for k in self.keep_keys:
            if k in nstate.info:
                info[k] = nstate.info[k]
        physics = backend.select(done, physics_of(fresh), physics_of(nstate))  # a Warp data's shared fields kept
        return with_physics(nstate, physics).replace(obs=pick(fresh.obs, nstate.obs), info=info)


def run_if(pred: jax.Array, fn: Callable[[Any, Any], Any], x: Any, operand: Any) -> Any:
    """``fn(x, operand)`` if ``pred`` else ``x``, computing ``fn`` only when ``pred`` holds, under ``jax.vmap`` too.

    A ``while_loop`` of one trip or none: vmapped, it runs ``fn`` once for the whole batch when ``pred`` holds
    in some lane and not at all otherwise, keeping ``x`` in the other lanes (``lax.cond`` vmapped with a
    batched ``pred`` computes ``fn`` in every lane at every call). ``x`` and ``operand`` enter the loop's body
    through an optimization barrier, so that XLA does not hoist the part of ``fn`` that depends on
    ``operand`` alone (a reset from a key) out of the loop, where it would run at every call. ``fn(x, operand)``
    has ``x``'s structure and types; ``pred`` is ``[]`` (a bool).
    """

    def body(carry: tuple[jax.Array, Any]) -> tuple[jax.Array, Any]:
        return jnp.zeros_like(carry[0]), fn(*jax.lax.optimization_barrier((carry[1], operand)))

    return jax.lax.while_loop(lambda c: c[0], body, (jnp.asarray(pred), x))[1]


def map_lanes(fn: Callable[..., Any], lane_group: int, *args: Any) -> Any:
    """``jax.vmap(fn)(*args)`` over the leading lane axis ``[B, ...]`` of every leaf of ``args``.

    With ``0 < lane_group < B`` the lanes are stepped as a ``lax.map`` (a loop) over ``B /
    lane_group`` groups, each vmapped: the same per-lane arithmetic, a smaller working set per
    kernel. On one H100, stepping ``arm7`` in ``pd`` mode at 131 072 lanes ran 2.39 M steps/s as
    one vmap and 2.74 M as 4 groups of 32 768 (the MJX data of more lanes outgrows the GPU's
    cache; ``benchmarks/results/gpu-nvidia_h100_80gb_hbm3x1-scaling.md``).
    """
    lanes = jax.tree.leaves(args)[0].shape[0]
    if lane_group <= 0 or lane_group >= lanes:
        return jax.vmap(fn)(*args)
    if lanes % lane_group:
        raise ValueError(f"lane_group={lane_group} must divide the lanes per device ({lanes})")
    if backend.has_shared(args):
        raise ValueError(f"lane_group={lane_group} is not supported with MuJoCo Warp physics (impl='warp'); use 0")
    groups = jax.tree.map(lambda x: x.reshape((lanes // lane_group, lane_group) + x.shape[1:]), args)
    out = jax.lax.map(lambda a: jax.vmap(fn)(*a), groups)
    return jax.tree.map(lambda x: x.reshape((lanes,) + x.shape[2:]), out)


class VmapWrapper(_ParamWrapper):
    """Vectorises an unbatched env over a leading lane axis.

    ``reset(keys)`` takes ``[B, 2]``-shaped keys (``jax.random.split(key, B)``), or a
    single key when ``batch_size`` is given. ``lane_group``: see :func:`map_lanes`.
    """

    def __init__(self, env: Env, batch_size: int | None = None, lane_group: int = 0):
        super().__init__(env)
        self.batch_size = batch_size
        self.lane_group = lane_group

    def reset(self, rng: jax.Array, params: Any = None) -> State:
        if self.batch_size is not None:
            rng = jax.random.split(rng, self.batch_size)
        if params is None:
            return jax.vmap(self.env.reset)(rng)
        return jax.vmap(lambda k: _reset(self.env, k, params))(rng)

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(state, action)
        return map_lanes(self.env.step, self.lane_group, state, action)


class PoolResetWrapper(_ParamWrapper):
    """Batched auto-reset from a pool of pre-drawn episodes (wraps an *unbatched* env).

    Every lane ``i`` owns a pool entry: a complete reset state drawn in advance.  At each
    step, ``R = round(refresh * G)`` entries of every group of ``G`` lanes are redrawn with
    ``env.reset`` (vmapped over the ``R`` entries only), chosen in this order: entries of
    lanes that finished *this* step, then entries already consumed (stale), then the oldest.
    A finished lane then starts its new episode from its entry.  So while at most ``R`` lanes
    of a group finish per step, every new episode is a fresh draw made at that step, exactly
    as with :class:`AutoResetWrapper`, at ``refresh`` of its cost.  When more finish at once
    (for example all lanes reaching the time limit together), the extra lanes start from
    entries drawn up to ``G / R`` steps earlier, or, if their entry was consumed and not yet
    redrawn, repeat it; ``info["pool_reused"]`` marks those repeats.

    Entries are drawn with the lane's episode parameters of the step that draws them, so a
    schedule change reaches new episodes within ``G / R`` steps.  Groups never span devices
    when ``G`` divides the lanes per device, and a run's result depends on ``G`` and ``R``,
    not on the number of devices.  ``info`` keeps what :class:`AutoResetWrapper` keeps
    (``final_obs``, the finished step's ``truncation`` and episode totals, ``params``), plus
    ``reset_pool``, ``pool_stale``, ``pool_age`` and ``pool_reused``, all ``[B, ...]``.

    Args:
      env: an unbatched env (usually an :class:`EpisodeWrapper`).
      batch_size: if given, ``reset`` takes one key and splits it into this many lanes;
        otherwise ``reset`` takes ``[B, 2]`` keys.
      refresh: fraction of each group redrawn per step, in ``(0, 1]``.
      group: lanes per group ``G`` (the effective group is ``gcd(B, group)``).
    """

    keep_keys = AutoResetWrapper.keep_keys

    def __init__(
        self, env: Env, batch_size: int | None = None, refresh: float = 0.125, group: int = 256, lane_group: int = 0
    ):
        super().__init__(env)
        self.lane_group = int(lane_group)
        if not 0.0 < float(refresh) <= 1.0:
            raise ValueError(f"refresh={refresh!r} must be in (0, 1] (fraction of lanes redrawn per step)")
        if int(group) < 1:
            raise ValueError(f"group={group!r} must be >= 1")
        self.batch_size = batch_size
        self.refresh = float(refresh)
        self.group = int(group)

    def group_sizes(self, num_lanes: int) -> tuple[int, int]:
        """``(G, R)``: lanes per group and entries redrawn per group and step."""
        g = math.gcd(int(num_lanes), self.group)
        return g, max(1, min(g, round(self.refresh * g)))

    def _draw(self, keys: jax.Array, params: Any, lane_params: bool) -> State:
        """``[n, 2]`` keys -> ``n`` reset states (``params`` per lane when ``lane_params``)."""
        if params is None:
            return jax.vmap(self.env.reset)(keys)
        return jax.vmap(lambda k, p: _reset(self.env, k, p), in_axes=(0, 0 if lane_params else None))(keys, params)

    def _entry(self, state: State) -> dict[str, Any]:
        info = {k: v for k, v in state.info.items() if k not in self.keep_keys}
        return {"pipeline_state": physics_of(state), "obs": state.obs, "info": info}

    def reset(self, rng: jax.Array, params: Any = None) -> State:
        keys = jax.random.split(rng, self.batch_size) if self.batch_size is not None else rng
        split = jax.vmap(lambda k: jax.random.split(k, 3))(keys)
        state = self._draw(split[:, 0], params, False)
        pool = self._draw(split[:, 1], params, False)
        lanes = state.obs.shape[0]
        info = dict(state.info)
        info.update(
            reset_key=split[:, 2],
            final_obs=state.obs,
            reset_pool=self._entry(pool),
            pool_stale=jnp.zeros((lanes,), jnp.float32),
            pool_age=jnp.zeros((lanes,), jnp.int32),
            pool_reused=jnp.zeros((lanes,), jnp.float32),
        )
        return state.replace(info=info)

    def step(self, state: State, action: jax.Array) -> State:
        self._check_action(state, action)
        nstate = map_lanes(self.env.step, self.lane_group, state, action)
        lanes = nstate.obs.shape[0]
        g, r = self.group_sizes(lanes)
        # backend.lane_map: a Warp data's fields shared by all lanes have no lane axis to split
        grouped = backend.lane_map(lambda x: x.reshape((lanes // g, g) + x.shape[1:]), nstate)
        out = jax.vmap(lambda s: self._group_step(s, r))(grouped)
        return backend.lane_map(lambda x: x.reshape((lanes,) + x.shape[2:]), out)

    def _group_step(self, nstate: State, r: int) -> State:
        """One group's redraw and restart; every leaf is ``[G, ...]``."""
        info = nstate.info
        done = nstate.done > 0
        stale = info["pool_stale"] > 0
        big = 1 << 21
        prio = done.astype(jnp.int32) * (2 * big) + stale.astype(jnp.int32) * big
        prio = prio + jnp.minimum(info["pool_age"], big - 1)
        idx = top_indices(prio, r)
        pairs = jax.vmap(jax.random.split)(info["reset_key"][idx])
        params = info.get("params")
        lane_params = None if params is None else jax.tree.map(lambda x: x[idx], params)
        drawn = self._entry(self._draw(pairs[:, 1], lane_params, True))
        pool = backend.lane_map(lambda old, new: old.at[idx].set(new), info["reset_pool"], drawn)
        stale = stale.at[idx].set(False)
        age = (info["pool_age"] + 1).at[idx].set(0)

        def pick(a, b):
            return jnp.where(done.reshape(done.shape + (1,) * (b.ndim - 1)), a, b)

        new_info = dict(info)
        new_info.update(jax.tree.map(pick, pool["info"], {k: info[k] for k in pool["info"]}))
        new_info.update(
            final_obs=nstate.obs,
            reset_key=info["reset_key"].at[idx].set(pairs[:, 0]),
            reset_pool=pool,
            pool_stale=(stale | done).astype(jnp.float32),
            pool_age=age,
            pool_reused=(done & stale).astype(jnp.float32),
        )
        physics = backend.select(done, pool["pipeline_state"], physics_of(nstate))
        return with_physics(nstate, physics).replace(obs=pick(pool["obs"], nstate.obs), info=new_info)


def top_indices(prio: jax.Array, r: int) -> jax.Array:
    """``[r]`` indices of the ``r`` largest of ``prio`` (``[G]`` ints), ties to the lower index: ``lax.top_k``'s.

    A stable sort rather than ``lax.top_k``: under the vmap lane map (``jaxrl_robot.parallel``) XLA's SPMD
    partitioner gathered a ``top_k``'s operand from every device at every env step (XLA:CPU's program over two
    devices); a sort along the lane axis stays on its device. On two H200s the speed did not change
    (``benchmarks/results/gpu-nvidia_h200x2-scaling-pool-{topk,sort}.md``).
    """
    order = jnp.argsort(-prio, stable=True)
    return order[:r]


DEFAULT_EPISODE_LENGTH = 1000
"""The time limit of an env that sets none (brax's: ``brax.envs.create`` and its training wrapper)."""


def default_episode_length(env: Env) -> int:
    """``env.episode_length`` (ours, a MuJoCo Playground env's config), else :data:`DEFAULT_EPISODE_LENGTH`."""
    return int(getattr(env, "episode_length", None) or DEFAULT_EPISODE_LENGTH)


def wrap_for_training(
    env: Env,
    episode_length: int | None = None,
    num_envs: int | None = None,
    *,
    reset_refresh: float = 1.0,
    reset_group: int = 256,
    lane_group: int = 0,
) -> Env:
    """The batched training env: time limit, auto-reset, lanes.

    ``reset_refresh = 1`` (default): ``VmapWrapper(AutoResetWrapper(EpisodeWrapper(env)))``, a
    fresh reset for every finished lane.  ``reset_refresh < 1``:
    ``PoolResetWrapper(EpisodeWrapper(env))``, which redraws that fraction of the lanes'
    pool entries at every step (cheaper when lanes finish at most steps and a reset costs several:
    the auto-reset computes every lane's reset at each step where some lane finished).

    Args:
      env: an unbatched env.
      episode_length: time limit; defaults to :func:`default_episode_length` of ``env``.
      num_envs: if given, ``reset`` takes one key and splits it into ``num_envs`` lanes.
      reset_refresh: fraction of lanes redrawn per step, in ``(0, 1]``.
      reset_group: lanes per pool group (see :class:`PoolResetWrapper`).
      lane_group: step the lanes in groups of this many (0: all at once; see :func:`map_lanes`).
    """
    if episode_length is None:
        episode_length = default_episode_length(env)
    if not 0.0 < float(reset_refresh) <= 1.0:
        raise ValueError(f"reset_refresh={reset_refresh!r} must be in (0, 1]")
    timed = EpisodeWrapper(env, episode_length)
    if float(reset_refresh) >= 1.0:
        return VmapWrapper(AutoResetWrapper(timed), batch_size=num_envs, lane_group=lane_group)
    return PoolResetWrapper(
        timed, batch_size=num_envs, refresh=reset_refresh, group=reset_group, lane_group=lane_group
    )
