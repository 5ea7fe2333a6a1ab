"""Several seeds in one run (``--seeds N``, ``--seed-map``): how their states are initialised, trained and
told apart (:class:`SeedProgram`)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp

from jaxrl_robot import parallel
from jaxrl_robot.compilation import CachedJit, ProgramCache
from jaxrl_robot.types import Trainer

__all__ = ["SEED_MAPS", "SeedProgram", "resolve_seed_map"]

SEED_MAPS = ("auto", "vmap", "loop")
"""How ``--seeds`` > 1 runs (:class:`SeedProgram`)."""


def resolve_seed_map(seed_map: str) -> str:
    """``'vmap'`` or ``'loop'``: ``seed_map``, with ``'auto'`` → ``'loop'`` on the CPU backend, else ``'vmap'``.

    Raises:
      ValueError: ``seed_map`` is not one of :data:`SEED_MAPS`.
    """
    if seed_map not in SEED_MAPS:
        raise ValueError(f"--seed-map {seed_map!r} is not a seed map; valid: {', '.join(SEED_MAPS)}")
    if seed_map == "auto":
        return "vmap" if parallel.on_accelerator() else "loop"
    return seed_map


def _floats(metrics: Any) -> dict[str, float]:
    return {k: float(v) for k, v in metrics.items()}


@dataclasses.dataclass(frozen=True)
class SeedProgram:
    """How the seeds of a run are trained: ``init(seeds) -> state``, ``update(state) -> (state,
    metrics)`` (jitted), ``view(tree, i)`` (seed ``i``'s part of a state) and ``per_seed(host
    metrics) -> [dict of floats]`` (one per seed).

    One seed: the trainer's own functions.  ``vmap``: one program over a leading seed axis of every
    leaf.  ``loop``: a tuple of the seeds' states, each chunk the same compiled ``update`` once per
    seed (XLA:CPU of jax 0.10 hangs running some vmapped-seed programs, e.g. PPO on arm7).  ``auto``:
    ``loop`` on the CPU backend, else ``vmap``.  Seed ``k``'s keys are those of a run with ``--seed k``
    in every mode.
    """

    init: Callable[[Sequence[int]], Any]
    update: Callable[[Any], tuple[Any, Any]]
    view: Callable[[Any, int], Any]
    per_seed: Callable[[Any], list[dict[str, float]]]
    compile_ahead: Callable[[Sequence[int]], bool] = lambda seeds: False
    """``compile_ahead(seeds)``: before ``init(seeds)``, start building ``update``'s program in a thread when
    the programs are not kept yet (:func:`_ahead`); whether it started."""

    @staticmethod
    def of(trainer: Trainer, n: int, seed_map: str = "auto", cache: ProgramCache | None = None) -> SeedProgram:
        """The program of ``n`` seeds of ``trainer`` under ``seed_map`` (one of :data:`SEED_MAPS`); its
        initialisation and chunk taken from ``cache`` when there (None: ``jax.jit``)."""
        mapping = resolve_seed_map(seed_map)
        jit = jax.jit if cache is None else (lambda fn: cache.jit(getattr(fn, "__name__", "program"), fn))  # noqa: E731
        update = jit(trainer.update)
        if n == 1 or mapping == "loop":
            init_one = jit(trainer.init)
            first_key = lambda seeds: jax.random.PRNGKey(seeds[0])  # noqa: E731
            ahead = functools.partial(_ahead, init_one, trainer.init, update, first_key)
        if n == 1:
            init = lambda seeds: init_one(jax.random.PRNGKey(seeds[0]))  # noqa: E731
            return SeedProgram(init, update, lambda tree, i: tree, lambda m: [_floats(m)], ahead)
        if mapping == "loop":

            def update_all(states: tuple) -> tuple[tuple, tuple]:
                out = [update(s) for s in states]
                return tuple(o[0] for o in out), tuple(o[1] for o in out)

            return SeedProgram(lambda seeds: tuple(init_one(jax.random.PRNGKey(k)) for k in seeds), update_all,
                               lambda tree, i: tree[i], lambda ms: [_floats(m) for m in ms], ahead)  # fmt: skip

        init_vmapped, update_vmapped = jit(jax.vmap(trainer.init)), jit(jax.vmap(trainer.update))
        stacked = lambda seeds: jnp.stack([jax.random.PRNGKey(k) for k in seeds])  # noqa: E731
        ahead = functools.partial(_ahead, init_vmapped, jax.vmap(trainer.init), update_vmapped, stacked)
        return SeedProgram(lambda seeds: init_vmapped(stacked(seeds)), update_vmapped,
                           lambda tree, i: jax.tree.map(lambda x: x[i], tree),
                           lambda m: [{k: float(v[i]) for k, v in m.items()} for i in range(n)], ahead)  # fmt: skip


def _ahead(init: Callable, init_fn: Callable, update: Callable, keys: Callable, seeds: Sequence[int]) -> bool:
    """Start compiling ``update`` (a :class:`CachedJit`) in a thread, for the state ``init_fn(keys(seeds))``
    will give, while ``init`` (the :class:`CachedJit` of ``init_fn``) is built: XLA compiles each program
    on one core, so on a first run the chunk's compilation overlaps the initialisation's instead of
    following it. Only when ``init``'s program is not kept yet (a later run loads both at once, and
    describing the state would cost a trace of ``init_fn``) and on a single device (the state's sharding
    is then the keys'; on several, the trainer's own). Returns whether it started."""
    if not isinstance(update, CachedJit) or jax.device_count() > 1:
        return False
    k = keys(seeds)
    if init.cache.has(init.name, k):
        return False
    place = lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=k.sharding)  # noqa: E731
    update.compile_ahead(jax.tree.map(place, jax.eval_shape(init_fn, k)))
    return True
