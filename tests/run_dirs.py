"""Run directories for the tests of ``load_policy`` and ``python -m train.eval``, made cheaply.

A run here is ``train.run.run`` of the algorithm's own env, trainer and ``config.json``, built from its
command line (``CLI.parse`` and ``CLI.build``, as ``python -m train.<algo>`` builds them), with one change:
the trainer's ``update`` is :func:`shift_by`'s, which moves every floating-point leaf of the state.  So the
run directory, its checkpoints and its final evaluation are the real ones, the state after ``n`` chunks is
that shift applied ``n`` times to ``init(PRNGKey(seed))`` (an oracle that needs no checkpoint), and no
learning step is compiled.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from train.cli import AlgorithmCLI
from train.options import RunSpec, settings_of
from train.run import run


@functools.cache
def shift_by(offset: float) -> Callable[[Any], tuple[Any, dict[str, jax.Array]]]:
    """A chunk that moves every float leaf, ``x ↦ 1.05 x + offset`` (variances stay positive), loss 0; the same
    function for the same ``offset``, so that its program compiles once."""

    def shift(state: Any) -> tuple[Any, dict[str, jax.Array]]:
        moved = jax.tree.map(lambda x: x * 1.05 + offset if jnp.issubdtype(x.dtype, jnp.floating) else x, state)
        return moved, {"loss": jnp.zeros(())}

    return shift


def make_run(
    out: str, cli: AlgorithmCLI, argv: list[str], offset: float = 0.01, **settings: Any
) -> tuple[str, Any, Any, Any]:
    """Run ``cli``'s command line ``argv`` into ``out`` with ``shift_by(offset)`` as its update.

    ``settings`` override the run settings (``stop_after_steps``, ``checkpoint_every``, …).
    Returns ``(run directory, args, env, trainer)`` (the trainer with its own ``update``).
    """
    args = cli.parse([*argv, "--out", out])
    env, trainer, config = cli.build(args)
    spec = RunSpec(
        algo=cli.name, env_name=args.env, env=env, trainer=trainer._replace(update=shift_by(offset)), config=config,
        episode_length=int(config[cli.name]["episode_length"]), **{**settings_of(args), "progress": False,
                                                                   **settings},
    )  # fmt: skip
    return run(spec)["run_dir"], args, env, trainer


def state_after(trainer: Any, seed: int, chunks: int, offset: float = 0.01) -> Any:
    """The state of a :func:`make_run` run of ``--seed seed`` (and ``offset``) after ``chunks`` chunks."""
    state = jax.jit(trainer.init)(jax.random.PRNGKey(seed))
    for _ in range(chunks):
        state = jax.jit(shift_by(offset))(state)[0]
    return state
