"""Shared machinery of the trajectory-tracking environments (thesis §3.5.2, §5.5).

* **Random reference-state initialisation (RSI)** — :func:`rsi_index` draws the start step of an
  episode uniformly from the window ``[start_lo, start_hi]`` (fractions of the reference).
* **Early termination** — :func:`early_termination` counts the steps whose position error exceeds
  a threshold; when the count exceeds ``et_limit`` the episode terminates (``done``, not a
  truncation), and that step and any later one earn zero reward.
* **Episode parameters** — ``{"start_lo", "start_hi", "et_limit"}`` live in
  ``state.info["params"]`` as float32 scalars.  They are traced values, so a trainer moves the
  piecewise curriculum (whole reference → ¼–½ → first quarter → t = 0, limit 20 → 15 → 10) by
  writing new values into the state (:func:`with_params`; keep them float32 of the same shape — a
  weakly typed value would retrace a jitted step); the wrappers of :mod:`envs_mjx.base` carry them
  across auto-resets and nothing recompiles.
* **Test episode** — :func:`rollout` (pure, jittable) runs one episode from ``t = 0`` with a
  deterministic policy; :func:`test_episode` jit-compiles it and returns the per-axis **sum of
  |error|** over all steps (Tables 4.3–4.5, 5.4–5.7, 7.2–7.3), the mean per step, the number of
  steps and the reference and real paths.

A tracking environment provides ``max_steps`` (control steps of the reference), ``axis_names``
(three tracked axes), ``wrap_axes`` (which axes are angles) and, in ``state.info``, ``ee_pos`` and
``ref_pos`` (``[3]`` each, on those axes) and the step index ``k``.  :class:`TrackingEnv` holds
what ``scara`` and ``unicycle`` share: the MJX model built from the resolved config, the start of
an episode (parameters, RSI step, the info every tracking state carries) and the end of a step
(early-termination counter, reference end, zeroed reward, ``done``); :func:`check_timing` and
:func:`check_episode` validate the config fields they share.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs_mjx import backend
from envs_mjx.base import RobotEnv, State
from envs_mjx.config import ConfigError, check_range, check_vector

__all__ = [
    "TrackingEnv",
    "PARAM_KEYS",
    "axis_errors",
    "check_episode",
    "check_timing",
    "early_termination",
    "make_params",
    "resolve_length",
    "rollout",
    "rsi_index",
    "test_episode",
    "eval_params",
    "with_params",
    "wrap_angle",
]

PARAM_KEYS = ("start_lo", "start_hi", "et_limit")


class TrackingEnv(RobotEnv):
    """Shared part of the trajectory-tracking environments (``scara``, ``unicycle``).

    Subclasses set ``build_model`` (``config -> mujoco.MjModel``, a staticmethod); their config
    has ``impl`` (the MJX backend, :mod:`envs_mjx.backend`), ``dt``, ``duration``, ``max_steps``,
    ``n_substeps``, ``action_scale`` (the scale vector C),
    ``rsi`` (default RSI window), ``et_threshold``, ``et_limit`` and a ``resolved()`` that fills in
    the derived lengths (and any default C).

    ``state.info`` of every tracking env holds ``params``, ``k`` (control step of the reference),
    ``t = k · dt``, the env's own entries, then ``et_count``, ``terminated`` and ``ref_end``
    (float32 0/1): :meth:`_first_state` and :meth:`_next_state` write them in that order.
    """

    build_model: Callable[[Any], Any]
    evaluation_kind = "tracking"
    """How a policy is evaluated on this env: the test episode from ``t = 0`` (:func:`test_episode`)."""

    def __init__(self, config: Any | None = None, **overrides: Any):
        super().__init__(config, **overrides)
        self.config = self.config.resolved()
        self.mj_model = self.build_model(self.config)
        backend.set_jacobian(self.mj_model, self.config.jacobian)
        self.mjx_model = backend.put_model(self.mj_model, self.config.impl)
        self._data0 = backend.make_data(self.mj_model, self.mjx_model)

    @property
    def max_steps(self) -> int:
        """Control steps of the reference (``config.max_steps``)."""
        return int(self.config.max_steps)

    @property
    def dt(self) -> float:
        return float(self.config.dt)

    def default_params(self) -> dict[str, jax.Array]:
        """RSI window and early-termination limit from the config (schedulable per episode)."""
        cfg = self.config
        return make_params({"start_lo": cfg.rsi[0], "start_hi": cfg.rsi[1], "et_limit": cfg.et_limit})

    def _start(self, rng: jax.Array, params: Mapping[str, Any] | None) -> tuple[dict[str, jax.Array], jax.Array]:
        """Episode parameters (the defaults updated by ``params``) and the start step ``k0`` drawn by RSI."""
        p = make_params(self.default_params(), params)
        return p, rsi_index(rng, p, self.max_steps)

    def _first_state(
        self, data: Any, obs: jax.Array, metrics: dict, params: dict, k0: jax.Array, **info: jax.Array
    ) -> State:
        """The state at reset: zero reward and ``done``, counters at zero, ``info`` as in the class docstring."""
        zero = jnp.zeros((), jnp.float32)
        info = {
            "params": params,
            "k": k0,
            "t": k0.astype(jnp.float32) * self.config.dt,
            **info,
            "et_count": zero,
            "terminated": zero,
            "ref_end": zero,
        }
        return State(pipeline_state=data, obs=obs, reward=zero, done=zero, metrics=metrics, info=info)

    def _next_k(self, state: State) -> jax.Array:
        """The step scored by this control step, ``min(k + 1, max_steps)``."""
        return jnp.minimum(state.info["k"] + 1, self.max_steps)

    def _end_of_step(
        self, state: State, k: jax.Array, pos_error: jax.Array, reward: jax.Array
    ) -> tuple[jax.Array, jax.Array, dict[str, jax.Array]]:
        """Early termination and the end of the reference after a step to ``k`` (thesis §3.5.2).

        Args:
          state: the state before the step; k: from :meth:`_next_k`; pos_error: Euclidean
            position error after the step; reward: the step's tracking reward.
        Returns:
          ``(reward, done, counters)``: the reward, zero from the step that triggers early
          termination on and after the reference's end; ``done = max(terminated, ref_end)``;
          ``counters = {"et_count", "terminated", "ref_end"}`` for ``info``.
        """
        info = state.info
        finished = jnp.maximum(info["terminated"], (info["k"] >= self.max_steps).astype(jnp.float32))
        et_count, terminated = early_termination(
            info["et_count"], info["terminated"], pos_error, self.config.et_threshold, info["params"]["et_limit"]
        )
        ref_end = (k >= self.max_steps).astype(jnp.float32)
        reward = jnp.where((terminated > 0) | (finished > 0), 0.0, reward)
        counters = {"et_count": et_count, "terminated": terminated, "ref_end": ref_end}
        return reward, jnp.maximum(terminated, ref_end), counters

    def _next_state(
        self,
        state: State,
        data: Any,
        obs: jax.Array,
        reward: jax.Array,
        done: jax.Array,
        metrics: dict,
        k: jax.Array,
        **info: jax.Array,
    ) -> State:
        """``state`` after a step to ``k``; ``info`` entries (and ``k``, ``t``) replaced by the keywords."""
        info = {**state.info, "k": k, "t": k.astype(jnp.float32) * self.config.dt, **info}
        return state.replace(pipeline_state=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info)


def check_timing(cfg: Any) -> None:
    """Validate the shared timing fields ``dt``, ``duration``, ``max_steps`` and ``n_substeps``."""
    check_range("dt", cfg.dt, 0.0, lo_open=True)
    if cfg.duration is not None:
        check_range("duration", cfg.duration, 0.0, lo_open=True)
    if cfg.max_steps is not None:
        check_range("max_steps", cfg.max_steps, 1)
    check_range("n_substeps", cfg.n_substeps, 1)


def check_episode(cfg: Any) -> None:
    """Validate the default RSI window ``rsi`` and the early-termination ``et_threshold`` and ``et_limit``."""
    check_vector("rsi", cfg.rsi, 2, lo=0.0, hi=1.0)
    if cfg.rsi[0] > cfg.rsi[1]:
        raise ConfigError(f"rsi={cfg.rsi!r} must satisfy start_lo <= start_hi")
    check_range("et_threshold", cfg.et_threshold, 0.0)
    check_range("et_limit", cfg.et_limit, 0.0)


def make_params(defaults: Mapping[str, Any], params: Mapping[str, Any] | None = None) -> dict[str, jax.Array]:
    """Episode parameters as float32 arrays: ``defaults`` updated by ``params``.

    Raises ``ValueError`` naming unknown keys and the valid ones.
    """
    params = {} if params is None else dict(params)
    unknown = sorted(set(params) - set(PARAM_KEYS))
    if unknown:
        raise ValueError(f"unknown episode parameter(s) {unknown}; valid: {', '.join(PARAM_KEYS)}")
    merged = {**defaults, **params}
    return {k: jnp.asarray(merged[k], jnp.float32) for k in PARAM_KEYS}


def resolve_length(cfg: Any, default_duration: float) -> dict[str, Any]:
    """``duration`` and ``max_steps`` of a tracking config: derived from each other, or checked."""
    dt, duration, max_steps = cfg.dt, cfg.duration, cfg.max_steps
    if max_steps is None:
        duration = default_duration if duration is None else duration
        max_steps = max(1, int(round(duration / dt)))
    elif duration is None:
        duration = max_steps * dt
    elif int(round(duration / dt)) != int(max_steps):
        raise ConfigError(
            f"max_steps={max_steps!r} disagrees with duration={duration!r} / dt={dt!r} "
            f"(= {duration / dt:g} steps); give one of them"
        )
    return {"duration": float(duration), "max_steps": int(max_steps)}


def with_params(state: Any, **values: Any) -> Any:
    """``state`` with ``info["params"][name] = value`` for each keyword, shaped and typed as before.

    Values are broadcast to the stored shape (one per lane in a batched state) as float32, so a
    jitted step does not recompile.  Example: ``with_params(state, start_lo=0.25, start_hi=0.5)``.
    """
    old = state.info["params"]
    unknown = sorted(set(values) - set(old))
    if unknown:
        raise ValueError(f"unknown episode parameter(s) {unknown}; valid: {', '.join(sorted(old))}")
    new = dict(old)
    for name, value in values.items():
        new[name] = jnp.broadcast_to(jnp.asarray(value, jnp.float32), jnp.shape(old[name]))
    return state.replace(info={**state.info, "params": new})


def eval_params() -> dict[str, jax.Array]:
    """Parameters of a test episode: start at ``t = 0``, no early termination (limit = +inf)."""
    return make_params({"start_lo": 0.0, "start_hi": 0.0, "et_limit": math.inf})


def rsi_index(key: jax.Array, params: Mapping[str, jax.Array], n_steps: int) -> jax.Array:
    """Start step ``k0`` drawn uniformly from the window ``[start_lo, start_hi]`` of the reference.

    ``k0 = floor((lo + u (hi − lo)) · n_steps)``, ``u ~ U[0, 1)``, clipped to ``[0, n_steps − 1]`` so
    that at least one step is left.  ``lo`` and ``hi`` are fractions of the reference (clipped to
    ``[0, 1]``; reversed bounds are swapped).  ``lo = hi = 0`` gives ``k0 = 0``.

    Returns an int32 scalar.
    """
    a = jnp.clip(params["start_lo"], 0.0, 1.0)
    b = jnp.clip(params["start_hi"], 0.0, 1.0)
    lo, hi = jnp.minimum(a, b), jnp.maximum(a, b)
    u = jax.random.uniform(key, (), jnp.float32)
    k0 = jnp.floor((lo + u * (hi - lo)) * n_steps).astype(jnp.int32)
    return jnp.clip(k0, 0, n_steps - 1)


def early_termination(
    count: jax.Array, terminated: jax.Array, pos_error: jax.Array, threshold: float, limit: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """One step of the early-termination counter (thesis §3.5.2).

    The counter adds 1 for every step whose position error exceeds ``threshold`` (steps need
    not be consecutive); the episode terminates once the counter exceeds ``limit``, i.e. on the
    ``limit + 1``-th over-threshold step, and stays terminated.

    Args:
      count: float32 counter before this step; terminated: float32 0/1 before this step.
      pos_error: Euclidean position error after this step; limit: float32 (``inf`` disables).
    Returns:
      ``(count, terminated)`` after this step.
    """
    over = (pos_error > threshold).astype(jnp.float32)
    count = count + over * (1.0 - terminated)
    terminated = jnp.maximum(terminated, (count > limit).astype(jnp.float32))
    return count, terminated


def wrap_angle(a: jax.Array) -> jax.Array:
    """Wrap angles to ``[-π, π)`` (so a reference of 2π − ε against 0 + ε gives an error of −2ε)."""
    return jnp.mod(a + jnp.pi, 2.0 * jnp.pi) - jnp.pi


def axis_errors(ref: jax.Array, real: jax.Array, wrap_axes: tuple[bool, ...]) -> jax.Array:
    """Signed tracking errors ``ref − real`` per axis, ``[..., 3]``; angle axes wrapped to ``[-π, π)``."""
    err = ref - real
    mask = jnp.asarray(wrap_axes, bool)
    return jnp.where(mask, wrap_angle(err), err)


def rollout(env: Any, policy_fn: Callable, params: Mapping[str, Any] | None = None, carry: Any = None) -> dict:
    """One episode from the reference's start with a deterministic policy (pure; jit it).

    Steps the unbatched ``env`` for ``env.max_steps`` control steps under ``lax.scan``; steps after
    the episode ends (early termination, if ``params`` enables it) are masked out.

    Args:
      env: a tracking environment (``scara`` or ``unicycle``).
      policy_fn: ``obs [O] -> action [A]`` in ``[-1, 1]``; with ``carry``, a policy with memory
        ``(carry, obs [O]) -> (carry, action [A])``.
      params: episode parameters; default :func:`eval_params` (start at ``t = 0``, no early
        termination).  Given ones are completed with the test defaults.
      carry: the memory the episode starts from (a recurrent policy's carry), or None.
    Returns:
      dict of arrays: ``sum_abs_error [3]``, ``mean_abs_error [3]`` (per step), ``abs_error [N, 3]``
      (masked steps 0), ``steps`` (int32), ``episode_return``, ``valid [N]`` (bool), ``ref_path
      [N+1, 3]`` and ``real_path [N+1, 3]`` (row 0 is the start; rows after the end are NaN), where
      ``N = env.max_steps``.
    """
    p = make_params(eval_params(), params)
    state = env.reset(jax.random.PRNGKey(0), p)
    wrap = tuple(env.wrap_axes)

    step = (lambda m, obs: (m, policy_fn(obs))) if carry is None else policy_fn

    def body(loop, _):
        st, memory, alive = loop
        memory, action = step(memory, st.obs)
        nst = env.step(st, action)
        err = jnp.abs(axis_errors(nst.info["ref_pos"], nst.info["ee_pos"], wrap))
        out = (
            jnp.where(alive, err, 0.0),
            alive,
            nst.info["ref_pos"],
            jnp.where(alive, nst.info["ee_pos"], jnp.nan),
            jnp.where(alive, nst.reward, 0.0),
        )
        return (nst, memory, alive & (nst.done == 0)), out

    _, (abs_err, valid, ref, real, rew) = jax.lax.scan(
        body, (state, () if carry is None else carry, jnp.asarray(True)), None, length=env.max_steps
    )
    steps = jnp.sum(valid.astype(jnp.int32))
    total = jnp.sum(abs_err, axis=0)
    ref = jnp.where(valid[:, None], ref, jnp.nan)
    return {
        "sum_abs_error": total,
        "mean_abs_error": total / jnp.maximum(steps, 1),
        "abs_error": abs_err,
        "steps": steps,
        "episode_return": jnp.sum(rew),
        "valid": valid,
        "ref_path": jnp.concatenate([state.info["ref_pos"][None], ref]),
        "real_path": jnp.concatenate([state.info["ee_pos"][None], real]),
    }


@functools.lru_cache(maxsize=32)
def _jitted_rollout(env: Any, policy_fn: Callable) -> Callable:
    return jax.jit(functools.partial(rollout, env, policy_fn))


def test_episode(env: Any, policy_fn: Callable, params: Mapping[str, Any] | None = None, carry: Any = None) -> dict:
    """Run :func:`rollout` jitted and return host values for tables and plots.

    The compiled rollout is cached per ``(env, policy_fn)`` object pair.  Inside a jitted training
    loop call :func:`rollout` directly instead.  ``carry``: as :func:`rollout` (a recurrent policy's
    initial memory; then ``policy_fn`` is ``(carry, obs) -> (carry, action)``).

    Returns the keys of :func:`rollout` as NumPy arrays (``steps`` an ``int``) plus ``axis_names``
    (e.g. ``('x', 'y', 'z')`` or ``('x', 'y', 'theta')``).
    """
    out = _jitted_rollout(env, policy_fn)(make_params(eval_params(), params), carry)
    host = {k: np.asarray(v) for k, v in out.items()}
    host["steps"] = int(host["steps"])
    host["episode_return"] = float(host["episode_return"])
    host["axis_names"] = tuple(env.axis_names)
    return host
