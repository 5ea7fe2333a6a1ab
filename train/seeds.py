"""Several seeds in one run (``--seeds N``, ``--seed-map``): how their states are initialised, trained and
told apart (:class:`SeedProgram`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp

from jaxrl_robot import parallel
from jaxrl_robot.compilation import ProgramCache
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

    @staticmethod
    def of(trainer: Trainer, n: int, seed_map: str = "auto", cache: ProgramCache | None = None) -> SeedProgram:
        """The program of ``n`` seeds of ``trainer`` under ``seed_map`` (one of :data:`SEED_MAPS`); its
        initialisation and chunk taken from ``cache`` when there (None: ``jax.jit``)."""
        mapping = resolve_seed_map(seed_map)
        jit = jax.jit if cache is None else (lambda fn: cache.jit(getattr(fn, "__name__", "program"), fn))  # noqa: E731
        update = jit(trainer.update)
        if n == 1:
            init_one = jit(trainer.init)
            init = lambda seeds: init_one(jax.random.PRNGKey(seeds[0]))  # noqa: E731
            return SeedProgram(init, update, lambda tree, i: tree, lambda m: [_floats(m)])
        if mapping == "loop":
            init_one = jit(trainer.init)

            def update_all(states: tuple) -> tuple[tuple, tuple]:
                out = [update(s) for s in states]
                return tuple(o[0] for o in out), tuple(o[1] for o in out)

            return SeedProgram(lambda seeds: tuple(init_one(jax.random.PRNGKey(k)) for k in seeds), update_all,
                               lambda tree, i: tree[i], lambda ms: [_floats(m) for m in ms])  # fmt: skip

        init_vmapped = jit(jax.vmap(trainer.init))

        def init_all(seeds: Sequence[int]) -> Any:
            return init_vmapped(jnp.stack([jax.random.PRNGKey(k) for k in seeds]))

        return SeedProgram(init_all, jit(jax.vmap(trainer.update)),
                           lambda tree, i: jax.tree.map(lambda x: x[i], tree),
                           lambda m: [{k: float(v[i]) for k, v in m.items()} for i in range(n)])  # fmt: skip
