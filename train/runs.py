"""Rebuild a training run from its directory: the run loader of every ``python -m train.<algo>`` run.

``pyproject.toml`` registers :func:`load_run` under the ``jaxrl_robot.runs`` entry points, one per algorithm,
so ``jaxrl_robot.load_policy`` finds it without importing ``train``; ``python -m train.eval`` calls it through
``jaxrl_robot.runs.load_run``.  A run of ``algo`` is rebuilt by the ``CLI`` of ``train.<algo>``
(:func:`train.algorithms`).

The env, the trainer and the state's structure come from ``config.json`` by the path ``--resume`` takes
(:meth:`~train.cli.AlgorithmCLI.args_from_saved`, :meth:`~train.cli.AlgorithmCLI.build`,
:class:`~train.seeds.SeedProgram`), on one device of this machine whatever ``--devices`` the run used; the
state's structure is traced (``jax.eval_shape``), not computed.  The checkpoint is restored by
:class:`~jaxrl_robot.checkpoint.Checkpointer`: its checksums verified, falling back to the newest good one;
nothing in the run directory is written or moved.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import os
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp

from jaxrl_robot import parallel
from jaxrl_robot.checkpoint import Checkpointer, CheckpointMismatchError, Restored
from jaxrl_robot.runs import LoadedRun, RunLoadError, run_seeds
from train import algorithms
from train.cli import AlgorithmCLI
from train.rundir import mismatch_error
from train.seeds import SeedProgram, resolve_seed_map

__all__ = ["cli_of", "load_run", "rebuild"]


def cli_of(algo: str) -> AlgorithmCLI:
    """The :class:`~train.cli.AlgorithmCLI` of ``algo``: the ``CLI`` of ``train.<algo>`` (imported on demand).

    Raises:
      RunLoadError: ``algo`` is not one of :func:`train.algorithms`.
    """
    valid = algorithms()
    if algo not in valid:
        raise RunLoadError(f"unknown algorithm {algo!r} in config.json; valid: {', '.join(valid)}")
    return importlib.import_module(f"train.{algo}").CLI


def rebuild(run_dir: str, config: dict[str, Any]) -> tuple[Any, Any, Any, dict[str, Any]]:
    """``(args, env, trainer, config dict)`` of the run in ``run_dir`` as ``--resume`` rebuilds them, on one device.

    Raises:
      RunLoadError: ``config.json`` does not rebuild a run (the message names the field).
    """
    cli = cli_of(str(config.get("algo")))
    try:
        args = dataclasses.replace(cli.args_from_saved(run_dir, cli.args()), devices=1)
        env, trainer, built = cli.build(args)
    except (ValueError, FileNotFoundError) as e:  # ConfigError is a ValueError
        text = str(e)
        for prefix in (f"--resume {run_dir!r}: ", f"--resume {run_dir}: "):
            text = text.removeprefix(prefix)
        raise RunLoadError(f"{run_dir}: {text}") from None
    return args, env, trainer, built


def _abstract(tree: Any) -> Any:
    """A restore target of ``jax.eval_shape``'s output: shapes and dtypes on this process's first device
    (zero-size leaves as arrays: checkpoints do not store them)."""
    device = parallel.local_sharding()

    def leaf(x: jax.ShapeDtypeStruct) -> Any:
        if math.prod(x.shape) == 0:
            return jnp.zeros(x.shape, x.dtype)
        return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=device)

    return jax.tree.map(leaf, tree)


def _restore(ckpt: Checkpointer, step: int | None, target: Any) -> Restored:
    """The checkpoint ``step`` (None: the newest good one, nothing set aside) restored into ``target``."""
    if step is None:
        restored = ckpt.restore_latest(target, set_aside=False)
        assert restored is not None  # load_run checked that there are checkpoints
        return restored
    state, record = ckpt.restore(step, target)
    return Restored(step, state, record, None)


def load_run(
    run_dir: str, config: dict[str, Any], step: int | None = None, seeds: Sequence[int] | None = None
) -> LoadedRun:
    """The run of ``run_dir`` (whose ``config.json`` is ``config``) with the trained states of ``seeds``
    (default: every seed) from checkpoint ``step`` (None: the newest good one).

    Raises:
      RunLoadError: ``config.json`` does not rebuild a run, the run has no checkpoint yet or no ``step``.
      CheckpointDamagedError: every checkpoint (or ``step``) is damaged.
      CheckpointMismatchError: ``config.json`` no longer builds the saved state (the message names the arrays).
    """
    args, env, trainer, _ = rebuild(run_dir, config)
    trained = run_seeds(config)
    seeds = trained if seeds is None else tuple(seeds)
    folder = os.path.join(run_dir, "checkpoints")
    ckpt = Checkpointer(folder) if os.path.isdir(folder) else None  # a Checkpointer would create the folder
    steps = [] if ckpt is None else ckpt.all_steps()
    if not steps:
        raise RunLoadError(f"{run_dir}: no checkpoint yet (the run stopped before its first one)")
    if step is not None and step not in steps:
        raise RunLoadError(f"{run_dir}: no checkpoint {step}; saved: {', '.join(map(str, steps))}")
    # the seeds' states are one stacked state (vmap) or a tuple (loop): the mapping of the machine that
    # trained them, which 'auto' resolved there; the other one is tried if this machine resolves it otherwise
    first = resolve_seed_map(args.seed_map)
    mappings = [first] if len(trained) == 1 else [first, "loop" if first == "vmap" else "vmap"]
    mismatches: list[CheckpointMismatchError] = []
    try:
        for mapping in mappings:
            program = SeedProgram.of(trainer, len(trained), mapping)
            target = _abstract(jax.eval_shape(lambda p=program: p.init(trained)))
            try:
                restored = _restore(ckpt, step, target)
                break
            except CheckpointMismatchError as e:
                mismatches.append(e)
        else:  # told as this machine's mapping sees it
            raise mismatch_error(ckpt, mismatches[0], run_dir, config) from None
    finally:
        ckpt.close()
    states = {k: program.view(restored.state, trained.index(k)) for k in seeds}
    record = dict(restored.record)
    env_steps = int(record.get("env_steps", restored.step * trainer.env_steps_per_update))
    return LoadedRun(run_dir, config, env, trainer, states, restored.step, env_steps, record, restored.note)
