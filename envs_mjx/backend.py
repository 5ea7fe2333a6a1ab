"""MJX physics backends of the environments: MJX's JAX implementation or MuJoCo Warp (env setting ``impl``).

``impl="jax"`` (the default) runs MJX's physics as XLA code; ``impl="warp"`` runs the same MuJoCo step as
MuJoCo Warp kernels (``warp-lang``, ``pip install -e ".[warp]"``) called from the jitted program, on an
NVIDIA GPU or the CPU.  XLA compiles MJX's step anew for every program, tens of seconds; Warp compiles its
kernels once per machine and keeps them on disk (``~/.cache/warp``, ``$WARP_CACHE_PATH``), so with them
cached a run starts in seconds.  ``warp`` therefore pays for the start-up of GPU runs; the JAX implementation
steps faster there.  On the 2-core CPU Warp stepped ``arm7`` and ``unicycle`` at 0.01-0.05x the JAX
implementation's steps/s (64 lanes) and compiled its kernels on a fresh cache in 39 s (``arm7``; 23 s more for
``unicycle``'s implicit integrator): no CPU training setting (``benchmarks/results/cpu-env_throughput-jax-warp*``;
``benchmarks/env_throughput.py --impl jax warp`` measures both).

``unicycle``'s implicitly integrated lateral grip differs between the engines: MuJoCo Warp, like MuJoCo's C
engine, keeps only the part of the grip's velocity derivative inside the mass matrix's (diagonal) sparsity,
MJX's JAX implementation all of it, so the two backends' trajectories differ there (``tests/envs/test_warp.py``).

A Warp ``mjx.Data`` batched by ``jax.vmap`` keeps some fields *shared* by all lanes, without a lane axis
(the contact buffers and counters: MuJoCo Warp's ``naconmax`` is across all worlds).  A select between two
states must keep those as they are, as :meth:`mujoco.mjx.Data.where` does: :func:`select` and
:func:`lane_map` are the lane-wise ``jnp.where`` and ``jax.tree.map`` of the training wrappers
(``envs_mjx.base``) that do so; on every other tree they are the plain operations.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from envs_mjx.config import ConfigError, check_choice

__all__ = [
    "IMPLS", "JACOBIANS", "WarpMissingError", "check_impl", "has_shared", "lane_map", "make_data", "put_model",
    "select", "set_jacobian",
]  # fmt: skip

IMPLS = ("jax", "warp")
"""Values of the env setting ``impl``: MJX's JAX implementation (default) or MuJoCo Warp."""

JACOBIANS = ("auto", "dense", "sparse")
"""Values of the env setting ``jacobian`` (MuJoCo's ``opt.jacobian``, which MJX's JAX implementation reads): ``auto``
(MuJoCo's and MJX's default: dense below 60 degrees of freedom off a TPU), ``dense`` (the mass matrix factorised with
``jax.scipy.linalg.cho_factor``, a linear-algebra library call on a GPU) or ``sparse`` (factorised with plain JAX
operations over the kinematic tree)."""


def set_jacobian(mj_model: mujoco.MjModel, jacobian: str) -> None:
    """Set ``mj_model.opt.jacobian`` to the env setting ``jacobian`` (:data:`JACOBIANS`) before :func:`put_model`."""
    check_choice("jacobian", jacobian, JACOBIANS)
    mj_model.opt.jacobian = {"auto": mujoco.mjtJacobian.mjJAC_AUTO, "dense": mujoco.mjtJacobian.mjJAC_DENSE,
                             "sparse": mujoco.mjtJacobian.mjJAC_SPARSE}[jacobian]  # fmt: skip


class WarpMissingError(ConfigError):
    """``impl="warp"`` without the ``warp-lang`` package; the message names the extra that installs it."""


def warp_installed() -> bool:
    """Whether MJX found ``warp-lang`` (its Warp backend is usable)."""
    from mujoco.mjx import warp as mjx_warp

    return bool(mjx_warp.WARP_INSTALLED)


def check_impl(impl: Any, mode: str | None = None, physics_modes: tuple[str, ...] = ()) -> None:
    """Raise :class:`ConfigError` unless ``impl`` is one of :data:`IMPLS` and usable with ``mode``.

    Args:
      impl: the env setting.
      mode: the env's physics mode, or None for an env that always simulates with MJX.
      physics_modes: the modes that step MJX; ``impl="warp"`` with any other mode (a kinematic update
        that steps no physics) is an error rather than silently unused.
    Raises:
      ConfigError: a bad value (naming ``impl`` and ``jax, warp``), ``warp`` with a mode without MJX physics,
        or :class:`WarpMissingError` when ``warp-lang`` is not installed.
    """
    check_choice("impl", impl, IMPLS)
    if impl != "warp":
        return
    if mode is not None and mode not in physics_modes:
        choices = ", ".join(repr(m) for m in physics_modes)
        raise ConfigError(
            f"impl='warp' is not valid with mode={mode!r}, which steps no MJX physics; "
            f"choose impl='jax' or mode {choices}"
        )
    if not warp_installed():
        from envs_mjx.xla import WARP_ENV, warp_skipped

        if warp_skipped():
            raise WarpMissingError(f"impl='warp' needs MuJoCo Warp, which this process left out ({WARP_ENV}=off)")
        raise WarpMissingError('impl=\'warp\' needs warp-lang, which is not installed: pip install -e ".[warp]"')


def put_model(mj_model: mujoco.MjModel, impl: str) -> mjx.Model:
    """The MJX model of ``mj_model`` on backend ``impl`` (:data:`IMPLS`).

    ``"jax"``: ``mjx.put_model(mj_model)``, MJX's default.  ``"warp"``: ``impl="warp"`` on JAX's default
    device (a CUDA GPU or the CPU), Warp's informational lines (its banner, a line per kernel module
    loaded) off: ``warp.config.log_level`` raised to warnings unless set higher.
    """
    if impl == "jax":
        return mjx.put_model(mj_model)
    check_impl(impl)
    import warp

    warp.config.log_level = max(warp.config.log_level, warp.LOG_WARNING)
    return mjx.put_model(mj_model, impl="warp")


def make_data(mj_model: mujoco.MjModel, model: mjx.Model) -> mjx.Data:
    """The initial data of ``model`` (from :func:`put_model` of ``mj_model``) on the model's backend.

    MuJoCo Warp's contact and constraint capacities are its defaults: the environments' models have no
    contacts (every geom's ``contype`` and ``conaffinity`` are 0).
    """
    if model.impl == mjx.Impl.WARP:
        return mjx.make_data(mj_model, impl="warp")
    return mjx.make_data(model)


def _is_data(x: Any) -> bool:
    return isinstance(x, mjx.Data)


def _shared_fields(data: mjx.Data) -> Any:
    """A tree like ``data`` of bools: True for a Warp data's fields shared by all lanes (no lane axis)."""
    if data.impl != mjx.Impl.WARP:
        return jax.tree.map(lambda _: False, data)
    from mujoco.mjx._src.types import tree_path_to_attr_str
    from mujoco.mjx.warp import types as warp_types

    batched = warp_types._BATCH_DIM["Data"]  # the table mjx.Data.where reads
    return jax.tree_util.tree_map_with_path(lambda path, _: not batched.get(tree_path_to_attr_str(path), True), data)


def shared_mask(tree: Any) -> Any:
    """A tree like ``tree`` of bools, True at the leaves of a Warp ``mjx.Data`` that have no lane axis."""
    return jax.tree.map(lambda x: _shared_fields(x) if _is_data(x) else False, tree, is_leaf=_is_data)


def has_shared(tree: Any) -> bool:
    """Whether ``tree`` holds Warp data fields shared by all lanes (see the module docstring)."""
    return any(jax.tree.leaves(shared_mask(tree)))


def lane_map(fn: Callable[..., Any], tree: Any, *rest: Any) -> Any:
    """``jax.tree.map(fn, tree, *rest)`` over the leaves that have a lane axis; a Warp data's shared
    leaves are taken from ``tree`` unchanged."""
    return jax.tree.map(lambda s, x, *r: x if s else fn(x, *r), shared_mask(tree), tree, *rest)


def select(pred: jax.Array, on_true: Any, on_false: Any) -> Any:
    """``jnp.where(pred, on_true, on_false)`` leaf by leaf, ``pred`` broadcast from the left.

    Args:
      pred: ``[]`` (one lane, e.g. inside ``jax.vmap``) or ``[G]`` (``G`` lanes, every leaf ``[G, ...]``).
      on_true, on_false: trees of the same structure (env states or their physics).
    Returns:
      The lane-wise selection; a Warp data's shared leaves are ``on_false``'s (as ``mjx.Data.where``).
    """
    pred = jnp.asarray(pred)

    def pick(a: jax.Array, b: jax.Array) -> jax.Array:
        return jnp.where(jnp.reshape(pred, pred.shape + (1,) * (jnp.ndim(b) - pred.ndim)), a, b)

    return lane_map(lambda b, a: pick(a, b), on_false, on_true)
