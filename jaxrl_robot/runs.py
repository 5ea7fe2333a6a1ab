"""Use a trained policy: :func:`load_policy` rebuilds the policy and the env of a run directory.

A run directory (``runs/<algo>-<env>-<time>/``, written by ``python -m train.<algo>``) holds
``config.json`` — the algorithm, the env and every hyper-parameter, enough to rebuild the run — and
``checkpoints/<chunk>/``, the whole train state every few chunks.  A run of ``--seeds n`` trains the seeds
``seed … seed + n − 1`` together; its ``seed<k>/`` folders hold each seed's metrics and ``config.json``.

>>> import jax, jaxrl_robot
>>> policy, env = jaxrl_robot.load_policy("runs/ppo-arm7-20260101-120000")
>>> state = env.reset(jax.random.PRNGKey(0))
>>> state = env.step(state, policy(state.obs))          # obs [D] or [..., D] -> action [A] or [..., A]

A recurrent policy (PPO ``--policy lstm``) is a :class:`~jaxrl_robot.types.RecurrentPolicy`:
``policy.carry`` is the memory an episode starts from and ``carry, action = policy.step(carry, obs)``
advances it (for ``B`` episodes at once, broadcast the carry's leaves to ``[B, ...]`` first).

Who rebuilds a run: the package that wrote it, whose *run loader* is registered per algorithm name
under the entry-point group :data:`ENTRY_POINTS` (this project's ``pyproject.toml`` registers ``train``'s
for each of its algorithms), so this module never imports the layer above it.
A loader is ``loader(run_dir, config, step=None, seeds=(...)) -> LoadedRun``; ``train``'s rebuilds the
env and the trainer exactly as ``--resume`` does and restores the checkpoint into the trainer's state.

Every error a user can cause (not a run directory, a seed or step the run does not have, no usable
checkpoint) is one line: :class:`RunLoadError` or a :class:`~jaxrl_robot.checkpoint.CheckpointError`.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
from brax.envs.base import Env

from jaxrl_robot.types import Policy, RecurrentPolicy, Trainer

__all__ = [
    "ENTRY_POINTS",
    "LoadedRun",
    "RunLoadError",
    "jit_policy",
    "load_policy",
    "load_run",
    "read_run",
    "run_loader",
    "run_seeds",
]

ENTRY_POINTS = "jaxrl_robot.runs"
"""Entry-point group of the run loaders, one per algorithm name (the ``algo`` of ``config.json``)."""

_SEED_DIR = re.compile(r"seed(\d+)")


class RunLoadError(ValueError):
    """A run directory that cannot be loaded as asked; the message is one line naming it and what is wrong."""


class LoadedRun(NamedTuple):
    """A run rebuilt from its directory by a run loader.

    Attributes:
      run_dir: the run directory (the one holding ``checkpoints/``).
      config: its ``config.json``.
      env: the unbatched env the run trained on, built from ``config.json``.
      trainer: the run's :class:`~jaxrl_robot.types.Trainer` (``trainer.policy(state)`` is the deterministic policy).
      states: trained seed → that seed's train state, for the seeds asked for.
      step: the checkpoint restored (chunks done).
      env_steps: env steps done at that checkpoint (per seed).
      record: the record saved with the checkpoint (``chunk``, ``env_steps``, ``wall_s``, ``config``).
      note: one line worth telling the user (damaged newer checkpoints skipped, no checksums), else None.
    """

    run_dir: str
    config: dict[str, Any]
    env: Env
    trainer: Trainer
    states: dict[int, Any]
    step: int
    env_steps: int
    record: dict[str, Any]
    note: str | None = None


RunLoader = Callable[..., LoadedRun]
"""``(run_dir, config, step=None, seeds=(...)) -> LoadedRun``: what a :data:`ENTRY_POINTS` entry point names."""


def run_seeds(config: dict[str, Any]) -> tuple[int, ...]:
    """The seeds a run trained: ``seed … seed + seeds − 1`` of ``config.json``'s options."""
    options = config.get("args", {})
    first, count = int(options.get("seed", 0)), int(options.get("seeds", 1))
    return tuple(range(first, first + count))


def _read_config(run_dir: str) -> dict[str, Any] | None:
    """``run_dir/config.json`` (None: there is none).

    Raises:
      RunLoadError: it cannot be read or is not a JSON object with an ``algo``.
    """
    path = os.path.join(run_dir, "config.json")
    if not os.path.isfile(path):
        return None
    try:
        with open(path) as f:
            config = json.load(f)
    except (OSError, ValueError) as e:
        raise RunLoadError(f"{run_dir}: config.json cannot be read ({str(e).splitlines()[0]})") from None
    if not isinstance(config, dict) or "algo" not in config:
        raise RunLoadError(f"{run_dir}: config.json has no 'algo' (not written by a training run)")
    return config


def read_run(run_dir: str, seed: int | None = None) -> tuple[str, dict[str, Any], tuple[int, ...]]:
    """``(run directory, config.json, seeds asked for)`` of ``run_dir``, a run directory or a ``seed<k>/``
    folder of a run of several seeds (which stands for that run and seed ``k``).

    Args:
      run_dir: the directory.
      seed: one trained seed (None: the seed of the ``seed<k>/`` folder, else every seed of the run).
    Raises:
      RunLoadError: ``run_dir`` is no run directory, or ``seed`` is not one the run trained (the message
        names the valid seeds).
    """
    path = os.path.normpath(run_dir)
    if not os.path.isdir(path):
        raise RunLoadError(f"{run_dir}: no such directory")
    config = _read_config(path)
    if config is None:
        raise RunLoadError(f"{run_dir}: not a run directory (no config.json)")
    named = _SEED_DIR.fullmatch(os.path.basename(path))
    parent = _read_config(os.path.dirname(path)) if named else None
    if parent is not None and len(run_seeds(parent)) > 1:  # seed<k>/ of a run of several seeds
        k = int(named[1])
        if seed is not None and seed != k:
            raise RunLoadError(f"{run_dir}: the folder of seed {k}, but seed={seed} was asked for")
        path, config, seed = os.path.dirname(path), parent, k
    trained = run_seeds(config)
    if seed is None:
        return path, config, trained
    if seed not in trained:
        raise RunLoadError(f"{run_dir}: seed {seed} was not trained; valid: {', '.join(map(str, trained))}")
    return path, config, (seed,)


def run_loader(algo: str) -> RunLoader:
    """The run loader registered for ``algo`` under :data:`ENTRY_POINTS`.

    Raises:
      RunLoadError: no installed package registers one (the message names those that are registered).
    """
    found = importlib.metadata.entry_points(group=ENTRY_POINTS, name=algo)
    if not found:
        known = sorted({ep.name for ep in importlib.metadata.entry_points(group=ENTRY_POINTS)})
        have = f"registered: {', '.join(known)}" if known else "none registered: install jaxrl-robot (pip install -e .)"
        raise RunLoadError(f"no run loader for algorithm {algo!r} ({ENTRY_POINTS} entry points; {have})")
    return next(iter(found)).load()


def load_run(run_dir: str, step: int | None = None, seed: int | None = None) -> LoadedRun:
    """Rebuild the run of ``run_dir`` (see :func:`read_run`) and restore its checkpoint.

    Args:
      run_dir: a run directory or a ``seed<k>/`` folder of one.
      step: the checkpoint (chunk) to restore; None: the newest good one (damaged newer ones are skipped,
        named in ``note``, and left where they are).
      seed: the trained seed to load (None: as :func:`read_run`).
    Raises:
      RunLoadError: as :func:`read_run` and :func:`run_loader`; no checkpoint yet, or no ``step``.
      CheckpointError: no usable checkpoint (every one damaged), or ``config.json`` no longer fits it.
    """
    path, config, seeds = read_run(run_dir, seed)
    return run_loader(str(config["algo"]))(path, config, step=step, seeds=seeds)


def jit_policy(policy: Policy | RecurrentPolicy) -> Policy | RecurrentPolicy:
    """``policy`` jitted: a :class:`~jaxrl_robot.types.RecurrentPolicy` gets a jitted ``step``."""
    if isinstance(policy, RecurrentPolicy):
        return RecurrentPolicy(policy.carry, jax.jit(policy.step))
    return jax.jit(policy)


def load_policy(
    run_dir: str, step: int | None = None, seed: int | None = None
) -> tuple[Policy | RecurrentPolicy, Env]:
    """The trained deterministic policy and the env of a run directory, for any algorithm of ``train``.

    Args:
      run_dir: a run directory (``config.json`` and ``checkpoints/``), or the ``seed<k>/`` folder of a run of
        several seeds.
      step: the checkpoint (chunk) to load; None: the newest good one.
      seed: which seed of a run of several seeds (required there, unless ``run_dir`` is a ``seed<k>/`` folder).
    Returns:
      ``(policy, env)``: ``policy`` is jitted, ``obs [D] or [..., D] -> action [A] or [..., A]`` in the env's
      action space ``[-1, 1]`` (the mean action, as the run's evaluation takes it); for a recurrent policy
      a :class:`~jaxrl_robot.types.RecurrentPolicy` (module docstring).  ``env`` is the unbatched env the run
      trained on, built from ``config.json``.
    Raises:
      RunLoadError: not a run directory, a seed or step it does not have, several seeds and none chosen
        (naming the valid ones), no checkpoint yet; ``CheckpointError``: no usable checkpoint.
    """
    path, config, seeds = read_run(run_dir, seed)
    if len(seeds) > 1:
        raise RunLoadError(
            f"{run_dir}: a run of seeds {', '.join(map(str, seeds))}; choose one with seed= "
            f"(or load {os.path.join(path, f'seed{seeds[0]}')})"
        )
    run = run_loader(str(config["algo"]))(path, config, step=step, seeds=seeds)
    if run.note:
        warnings.warn(run.note, stacklevel=2)
    (state,) = run.states.values()
    return jit_policy(run.trainer.policy(state)), run.env
