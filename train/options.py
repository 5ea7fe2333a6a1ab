"""The options every ``python -m train.<algo>`` shares and what a run is handed.

* :class:`RunSettings` — how a run is driven, saved and evaluated (what :func:`train.run.run` reads);
* :class:`RunSpec` — the settings with what the run is made of (env, trainer, ``config.json``);
* :class:`RunOptions` — the settings with the options of the command line (env, preset, resume, chunks,
  devices, processes, compile cache), the base of every algorithm's ``Args``;
* :func:`check_options` / :func:`check_command_line` — their counts in range, checked before anything is
  built, each error one line naming the flag and the allowed range.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar

from brax.envs.base import Env

from jaxrl_robot.compilation import ProgramCache
from jaxrl_robot.types import Trainer

__all__ = [
    "COMMAND_LINE_FIELDS",
    "MACHINE_FIELDS",
    "MAX_SEED",
    "PROCESS_FIELDS",
    "RUN_ONLY_FIELDS",
    "RunOptions",
    "RunSettings",
    "RunSpec",
    "check_command_line",
    "check_options",
    "flag",
    "none_or",
    "settings_of",
]

MAX_SEED = 2**32 - 1
"""The largest ``--seed`` (``+ --seeds - 1``): JAX's keys take 32-bit seeds (larger ones alias smaller ones)."""


@dataclasses.dataclass
class RunSettings:
    """How a run is driven, saved and evaluated: the part of :class:`RunOptions` that
    :func:`train.run.run` reads (through :class:`RunSpec`)."""

    seed: int = 0
    """Random seed of the run (training), 0 to 2**32 - 1; evaluation uses a separate stream derived from it."""
    seeds: int = 1
    """Train this many seeds (seed, seed + 1, …; at least 1) in one run on one device; each writes its metrics,
    figures and ``eval.json`` to ``<run dir>/seed<k>/`` as the run of ``--seed k`` would, with the
    ``config.json`` of that run. 1: one run, written to the run directory itself."""
    seed_map: str = "auto"
    """With --seeds > 1: vmap (one program over the seeds), loop (the same compiled program once per
    seed each chunk) or auto (loop on the CPU, where XLA:CPU hangs on some vmapped-seed programs; else vmap)."""
    out: str = "runs"
    """Parent folder of the run directory runs/<algo>-<env>-<time>/."""
    checkpoint_every: int = 10
    """Chunks between checkpoints, at least 1 (the last chunk is always saved)."""
    eval_episodes: int = 100
    """Test episodes of the final evaluation (reaching envs; racecar: laps per road), at least 1. A run
    that finishes is always evaluated; one stopped early by --stop-after-steps is not."""
    precision: bool = True
    """Reaching envs with a goal threshold (arm7): also report success at 5, 2 and 1 cm."""
    evals: int = 0
    """Evaluations during training, 0 or more, spread evenly over the run's chunks (after chunk ceil(i·C/N) of C
    for i = 1…N, at most one per chunk; the last is the final evaluation), each the final evaluation's program on
    --eval-episodes episodes, one row each in <run dir>/evals.csv (train/periodic.py). 0: the final one alone."""
    stop_after_steps: int = 0
    """Stop early, resumably, once this many env steps are done (0: run to the end)."""
    progress: bool | None = None
    """Show a progress bar (default: only on a terminal and not under CI)."""

    ranges: ClassVar[dict[str, tuple[int, int | None]]] = {
        "seed": (0, MAX_SEED), "seeds": (1, None), "checkpoint_every": (1, None), "eval_episodes": (1, None),
        "stop_after_steps": (0, None), "evals": (0, None),
    }  # fmt: skip
    """The allowed ``[low, high]`` (None: no upper bound) of every count among the options, checked by
    :func:`check_options` before anything is built; a subclass extends it with its own counts."""


def settings_of(options: Any) -> dict[str, Any]:
    """The :class:`RunSettings` fields of ``options`` (a :class:`RunOptions`), as keywords."""
    return {f.name: getattr(options, f.name) for f in dataclasses.fields(RunSettings)}


@dataclasses.dataclass(kw_only=True)
class RunSpec(RunSettings):
    """What an algorithm's CLI hands to :func:`train.run.run`: the :class:`RunSettings` (``seed``, ``out``,
    ``checkpoint_every``, ``eval_episodes``, ``precision``, ``stop_after_steps``, ``progress``;
    ``progress=None`` decides by :func:`train.run.use_progress_bar`) and what the run is made of.

    Attributes:
      algo: algorithm name for the run directory (``"ppo"``).
      env_name: environment name for the run directory and reports.
      env: the unbatched environment (used for evaluation).
      trainer: the algorithm's :class:`~jaxrl_robot.types.Trainer`.
      config: JSON-able dict that rebuilds the run (saved as ``config.json``).
      run_dir: an existing run directory to resume (``None``: start a new run).
      episode_length: step limit of a test episode (0: ``env.episode_length``).
      compile_mark: :meth:`~jaxrl_robot.compilation.CompileLog.mark` taken when the command began:
        ``eval.json``'s ``compile`` counts the compilations since (None: since the process began).
      program_cache: where the run's programs (initialisation, chunk, evaluation) are kept between
        processes (:class:`~jaxrl_robot.compilation.ProgramCache`, keyed by ``config``); None: built here.
    """

    algo: str
    env_name: str
    env: Env
    trainer: Trainer
    config: dict[str, Any]
    run_dir: str | None = None
    episode_length: int = 0
    compile_mark: tuple | None = None
    program_cache: ProgramCache | None = None


@dataclasses.dataclass
class RunOptions(RunSettings):
    """The options of a run that every ``python -m train.<algo>`` shares (its ``Args`` extends this):
    the :class:`RunSettings` and the ones below."""

    env: str = "arm7"
    """Environment: a registered name (envs_mjx.names()), brax:<name> for brax's own envs or playground:<Name> for
    MuJoCo Playground's (pip install -e ".[playground]"; --env-config KEY=VALUE are its config_overrides, impl
    jax unless impl=warp)."""
    preset: str = "auto"
    """Hyper-parameter preset: auto (fast on a GPU, else cpu; brax on brax's tasks of PPO, DDPG and TD3, playground
    on MuJoCo Playground's dm_control_suite), thesis, cpu, fast, brax or playground (PPO, DDPG, TD3). PPO, A2C and
    A3C presets run arm7 in kinematic mode under thesis and cpu (--env-config overrides)."""
    reward: str | None = None
    """Reward function of the env (arm7: sparse, shaped, ordinary, path); None keeps the env's default."""
    env_config: tuple[str, ...] = ()
    """Further env settings as KEY=VALUE (e.g. mode=kinematic, trajectory=ellipse, obs=no_goal; playground:<Name>:
    Playground's config_overrides, e.g. impl=warp, episode_length=500)."""
    resume: str | None = None
    """Continue the run in this directory (its config.json is used; other flags are ignored).
    --stop-after-steps, --progress and the process options apply as given."""
    chunks: int = 50
    """Reporting chunks per run, at least 1: metrics, progress and checkpoints happen between chunks."""
    devices: int = 0
    """Devices to spread the lanes over, 0 to the device count (0: all devices, of every process in a run
    over several). Not given: 0, except PPO's fast main job on arm7 in one process, which runs fastest on 1."""
    coordinator: str | None = None
    """HOST:PORT of process 0 in a run over several processes (jax.distributed).
    None: $JAX_COORDINATOR_ADDRESS, else a detected SLURM / Open MPI / Kubernetes launch, else one process."""
    num_processes: int | None = None
    """Processes of a run over several processes (None: from the launcher's environment)."""
    process_id: int | None = None
    """This process's index, 0 to num_processes - 1 (None: from the launcher's environment)."""
    compile_cache: str = "auto"
    """Folder of JAX's persistent compilation cache, so that a second run skips compiling: auto
    ($JAXRL_ROBOT_COMPILE_CACHE, else $JAX_COMPILATION_CACHE_DIR, else ~/.cache/jaxrl-robot/xla), a
    folder, or off (also --no-compile-cache). Not saved in config.json."""

    ranges: ClassVar[dict[str, tuple[int, int | None]]] = {
        **RunSettings.ranges, "chunks": (1, None), "devices": (0, None), "num_processes": (1, None),
        "process_id": (0, None),
    }  # fmt: skip


PROCESS_FIELDS = ("coordinator", "num_processes", "process_id")
"""Where the run's processes are: always from the command line, never saved in ``config.json``."""

MACHINE_FIELDS = ("compile_cache",)
"""Options of this machine rather than of the run: taken from the command line, never saved in ``config.json``."""

COMMAND_LINE_FIELDS = ("stop_after_steps", "progress", *PROCESS_FIELDS, *MACHINE_FIELDS)
"""Options a resumed run takes from its command line instead of its ``config.json``."""

RUN_ONLY_FIELDS = ("seed", "out", "resume", "checkpoint_every", "stop_after_steps", "progress", "evals")
"""Options of ``config.json``'s ``args`` that never change a compiled program (the seed enters as an argument)."""


def flag(name: str) -> str:
    """The command-line flag of an option or a config field: ``eval_episodes`` -> ``--eval-episodes``."""
    return "--" + name.replace("_", "-")


def none_or(text: str | None, convert: Callable[[str], Any] = str) -> Any:
    """A pre-parsed value: tyro's ``None`` spelling as None; a value ``convert`` rejects as None (tyro reports it)."""
    if text is None or text == "None":
        return None
    try:
        return convert(text)
    except ValueError:
        return None


def check_options(options: Any, ranges: Mapping[str, tuple[int, int | None]] | None = None) -> None:
    """Check the counts of ``options`` (a :class:`RunOptions`, or any object with some of its attributes;
    None: not given) against ``ranges`` (default ``options.ranges``, :attr:`RunSettings.ranges`), and that
    ``--process-id`` is below ``--num-processes`` and ``--seed + --seeds - 1`` at most :data:`MAX_SEED`.

    Raises:
      ValueError: the first value out of range, naming its flag and the allowed range
        (``--eval-episodes -5 is out of range; allowed >= 1``).
    """
    ranges = type(options).ranges if ranges is None else ranges
    for name, (low, high) in ranges.items():
        value = getattr(options, name, None)
        if value is not None and (value < low or (high is not None and value > high)):
            allowed = f">= {low}" if high is None else f"[{low}, {high}]"
            raise ValueError(f"{flag(name)} {value} is out of range; allowed {allowed}")
    count, index = getattr(options, "num_processes", None), getattr(options, "process_id", None)
    if count is not None and index is not None and index >= count:
        raise ValueError(f"--process-id {index} is out of range; allowed [0, {count - 1}] (--num-processes {count})")
    seed, seeds = getattr(options, "seed", None), getattr(options, "seeds", None)
    if seed is not None and seeds is not None and seed + seeds - 1 > MAX_SEED:
        raise ValueError(f"--seed {seed} with --seeds {seeds} is out of range; allowed seed + seeds - 1 <= {MAX_SEED}")


def check_command_line(argv: Sequence[str], ranges: Mapping[str, tuple[int, int | None]]) -> None:
    """:func:`check_options` on the counts of ``ranges`` as ``argv`` gives them (``--name VALUE`` or
    ``--name=VALUE``, with ``-`` or ``_``), before anything is built; values that are no integers and
    flags without a value are left to tyro, which reports them.

    Raises:
      ValueError: as :func:`check_options`.
    """
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False, exit_on_error=False)
    for name in ranges:
        pre.add_argument(*dict.fromkeys((flag(name), "--" + name)), dest=name, default=None)
    try:
        known, _ = pre.parse_known_args(list(argv))
    except argparse.ArgumentError:
        return
    check_options(argparse.Namespace(**{k: none_or(v, int) for k, v in vars(known).items()}), ranges)
