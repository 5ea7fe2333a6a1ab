"""Run directories for the tests of ``load_policy`` and ``python -m train.eval``, made cheaply.

A run here is ``train.common.run`` of the algorithm's own env, trainer and ``config.json``, built from its
command line (``CLI.parse`` and ``CLI.build``, as ``python -m train.<algo>`` builds them), with one change:
the trainer's ``update`` is :func:`shift`, which moves every floating-point leaf of the state.  So the run
directory, its checkpoints and its final evaluation are the real ones, the state after ``n`` chunks is
``shift`` applied ``n`` times to ``init(PRNGKey(seed))`` (an oracle that needs no checkpoint), and no
learning step is compiled.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from train import common


def shift(state: Any) -> tuple[Any, dict[str, jax.Array]]:
    """A chunk that moves every float leaf (``x ↦ 1.05 x + 0.01``; variances stay positive), loss 0."""
    moved = jax.tree.map(lambda x: x * 1.05 + 0.01 if jnp.issubdtype(x.dtype, jnp.floating) else x, state)
    return moved, {"loss": jnp.zeros(())}


def make_run(out: str, cli: common.AlgorithmCLI, argv: list[str], **settings: Any) -> tuple[str, Any, Any, Any]:
    """Run ``cli``'s command line ``argv`` into ``out`` with :func:`shift` as its update.

    ``settings`` override the run settings (``stop_after_steps``, ``checkpoint_every``, …).
    Returns ``(run directory, args, env, trainer)`` (the trainer with its own ``update``).
    """
    args = cli.parse([*argv, "--out", out])
    env, trainer, config = cli.build(args)
    spec = common.RunSpec(
        algo=cli.name, env_name=args.env, env=env, trainer=trainer._replace(update=shift), config=config,
        episode_length=int(config[cli.name]["episode_length"]), **{**common.settings_of(args), "progress": False,
                                                                   **settings},
    )  # fmt: skip
    return common.run(spec)["run_dir"], args, env, trainer


def state_after(trainer: Any, seed: int, chunks: int) -> Any:
    """The state of a :func:`make_run` run of ``--seed seed`` after ``chunks`` chunks."""
    state = jax.jit(trainer.init)(jax.random.PRNGKey(seed))
    for _ in range(chunks):
        state = jax.jit(shift)(state)[0]
    return state
