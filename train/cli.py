"""The command line of every ``python -m train.<algo>``: what an algorithm declares (:class:`AlgorithmCLI`) and
what every one does with it (:func:`cli_main`).

The algorithm's command line is an :class:`AlgorithmCLI`: an ``Args`` dataclass that extends
:class:`~train.options.RunOptions` (the options every algorithm shares) with the algorithm's
hyper-parameters, the preset that gives their defaults and how the trainer is built. :func:`cli_main` joins
the processes of a run over several hosts, parses (the preset's defaults for ``--env`` first, from the env
built once for the run; ``--resume DIR`` reloads the run's ``config.json``), builds and calls
:func:`train.run.run` with a :class:`~train.options.RunSpec`.

Several processes
-----------------
With ``--coordinator``/``--num-processes``/``--process-id``, ``$JAX_COORDINATOR_ADDRESS`` or a
cluster launch that JAX detects (SLURM, Open MPI, Kubernetes), :func:`cli_main` calls
``jaxrl_robot.parallel.initialize_multihost`` before any JAX computation; the lane mesh then
spans the devices of every process and every process runs the same program (:mod:`train.run` says
which process writes what).
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
from collections.abc import Callable, Sequence
from typing import Any

import jax
import tyro
from brax.envs.base import Env
from jax.sharding import Mesh

from jaxrl_robot import parallel
from jaxrl_robot.agents.core import lane_map_of
from jaxrl_robot.checkpoint import CheckpointError, CheckpointWriteError
from jaxrl_robot.compilation import ProgramCache, compile_log, enable_persistent_cache, resolve_cache_dir
from jaxrl_robot.types import Trainer
from train.envs import BuiltEnv, check_backend_devices, env_overrides, env_record, episode_length, make_env
from train.hosts import is_main_process
from train.options import (
    COMMAND_LINE_FIELDS,
    MACHINE_FIELDS,
    PROCESS_FIELDS,
    RUN_ONLY_FIELDS,
    RunSpec,
    check_command_line,
    check_options,
    flag,
    none_or,
    settings_of,
)
from train.presets import BRAX_PPO_TUNED, BRAX_SAC_TUNED, brax_sac_task, brax_task, resolve_preset
from train.progress import NonFiniteLossError, PeerLostError, exit_process
from train.run import run
from train.rundir import RunDirError, jsonable, load_config
from train.seeds import resolve_seed_map

__all__ = [
    "AlgorithmCLI",
    "cache_flags",
    "cli_main",
    "exit_process",
    "iterations_per_chunk",
    "lane_mesh",
    "preparse",
    "program_context",
]


def iterations_per_chunk(total_iterations: int, chunks: int) -> int:
    """Iterations per reporting chunk so that ``chunks`` (>= 1) chunks cover ``total_iterations`` (at least 1)."""
    if chunks < 1:
        raise ValueError(f"--chunks {chunks} is out of range; allowed >= 1")
    return max(1, -(-total_iterations // chunks))


def lane_mesh(devices: int) -> Mesh:
    """The lane mesh of ``--devices`` (0: every device); a run over several processes uses all of them."""
    if not 0 <= devices <= jax.device_count():
        raise ValueError(f"--devices {devices} is out of range; allowed [0, {jax.device_count()}] (0: every device)")
    if jax.process_count() > 1 and devices not in (0, jax.device_count()):
        raise ValueError(
            f"--devices {devices}: a run over {jax.process_count()} processes spreads its lanes over all "
            f"{jax.device_count()} devices (--devices 0)"
        )
    return parallel.lane_mesh(devices or None)


def preparse(argv: Sequence[str], extra: Sequence[str] = ()) -> argparse.Namespace:
    """The options read ahead of the full parse, which the defaults and the processes depend on.

    ``env``, ``preset``, ``resume``, ``reward``, ``env_config``, ``devices`` (None: not given), the process
    options (:data:`~train.options.PROCESS_FIELDS`) and the ``str | None`` options named in ``extra``; other
    flags are left to tyro (which also checks these).
    """
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--env", default="arm7")
    pre.add_argument("--preset", default="auto")
    pre.add_argument("--env-config", dest="env_config", nargs="*", default=())
    for name in ("resume", "reward", "devices", *PROCESS_FIELDS, *extra):
        pre.add_argument("--" + name.replace("_", "-"), dest=name, default=None)
    known, _ = pre.parse_known_args(list(argv))
    known.env_config = tuple(known.env_config)
    for name in ("resume", "reward", "coordinator", *extra):
        setattr(known, name, none_or(getattr(known, name)))
    for name in ("devices", "num_processes", "process_id"):
        setattr(known, name, none_or(getattr(known, name), int))
    return known


def _tuples(x: Any) -> Any:
    """JSON lists back to tuples (the configs' sequence fields are tuples), recursively."""
    if isinstance(x, dict):
        return {k: _tuples(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return tuple(_tuples(v) for v in x)
    return x


def _asks_for_help(argv: Sequence[str]) -> bool:
    return "-h" in argv or "--help" in argv


def cache_flags(argv: Sequence[str]) -> list[str]:
    """``argv`` with ``--no-compile-cache`` spelled ``--compile-cache off`` (the field tyro parses)."""
    return [x for a in argv for x in (("--compile-cache", "off") if a == "--no-compile-cache" else (a,))]


@dataclasses.dataclass(frozen=True)
class AlgorithmCLI:
    """The command line ``python -m train.<name>`` of one algorithm: what the algorithm declares.

    :meth:`parse`, :meth:`build` and :meth:`main` (= :func:`cli_main`) do the rest the same way for
    every algorithm.

    Attributes:
      name: the algorithm (``"ppo"``): run-directory prefix, the ``config.json`` section of its
        hyper-parameters and the field of ``args_type`` that holds them.
      args_type: a :class:`~train.options.RunOptions` subclass adding the field ``name`` (``config_type``,
        ``Annotated[..., tyro.conf.OmitArgPrefixes]``, with a default) and any options of its own.
      config_type: the hyper-parameter dataclass (with ``replace``, ``validate`` and ``episode_length``).
      preset: ``(args, env) -> config``: the defaults of the (resolved) ``args.preset`` for ``env``,
        the env as the run builds it from ``args`` (``args`` holds the options read ahead: ``env``,
        ``reward``, ``env_config``, ``devices``, ``env_fields`` and ``preset_fields``).
      make_trainer: ``(args, env, config, mesh) -> (trainer, iterations per chunk)``; ``config`` is
        validated, its ``episode_length`` set; ``mesh`` is :func:`lane_mesh` of ``--devices``, over
        which the trainer spreads its lanes.
      env_settings: ``args -> env overrides`` for :func:`~train.envs.make_env` (default
        :func:`~train.envs.env_overrides`).
      env_fields: options of ``args_type`` beyond ``RunOptions`` that ``env_settings`` reads.
      preset_fields: ``str`` choice fields of ``config_type`` that select a variant of the preset
        (e.g. PPO's ``policy``): read ahead and set in the config of the ``args`` the preset gets.
      after: called on process 0 with :func:`train.run.run`'s result (e.g. extra figures).
      default_devices: ``args -> --devices`` where the command line gives none (``args`` as ``preset`` gets
        them; None: 0, every device).
      presets: the algorithm whose preset names ``--preset`` takes (:func:`~train.presets.resolve_preset`'s
        ``algo``; ``""``: ``name``); the off-policy members take DDPG's.
    """

    name: str
    args_type: type
    config_type: type
    preset: Callable[[Any, Env], Any]
    make_trainer: Callable[[Any, Env, Any, Mesh], tuple[Trainer, int]]
    env_settings: Callable[[Any], dict[str, Any]] = env_overrides
    env_fields: tuple[str, ...] = ()
    preset_fields: tuple[str, ...] = ()
    after: Callable[[dict[str, Any]], Any] | None = None
    presets: str = ""
    default_devices: Callable[[Any], int] | None = None

    def args(self, config: Any = None, **options: Any) -> Any:
        """An ``args_type`` with ``config`` (default: ``config_type()``) and ``options``."""
        return self.args_type(**{self.name: self.config_type() if config is None else config}, **options)

    def parse(self, argv: Sequence[str] | None = None) -> Any:
        """Parse the command line: the preset's defaults for ``--env`` (and its env settings) first,
        then every flag; with ``--resume DIR`` the arguments saved in that run (:meth:`args_from_saved`)."""
        return self.parse_with_env(argv)[0]

    def parse_with_env(self, argv: Sequence[str] | None = None) -> tuple[Any, BuiltEnv | None]:
        """:meth:`parse`, and the env built for the preset's defaults (None for ``--resume``, which builds
        none), which :meth:`build` takes where the run's env settings are the same."""
        argv = cache_flags(sys.argv[1:] if argv is None else argv)
        if not _asks_for_help(argv):
            check_command_line(argv, self.args_type.ranges)  # before the preset's env is built
        known = preparse(argv, (*self.env_fields, *self.preset_fields))
        built = None
        if known.resume:
            preset, config = known.preset, self.config_type()
        else:
            preset = resolve_preset(known.preset, known.env, self.presets or self.name)
            if known.preset == "auto" and not _asks_for_help(argv):
                self._announce(preset, known.env)
            fields = ("env", "reward", "env_config", *self.env_fields)
            variant = {k: getattr(known, k) for k in self.preset_fields if getattr(known, k) is not None}
            options = {k: getattr(known, k) for k in fields}
            ahead = self.args(self.config_type(**variant), preset=preset, devices=known.devices or 0, **options)
            if known.devices is None and self.default_devices is not None:
                ahead = dataclasses.replace(ahead, devices=self.default_devices(ahead))
            overrides = self.env_settings(ahead)
            built = BuiltEnv(known.env, overrides, make_env(known.env, overrides))
            config = self.preset(ahead, built.env)
        devices = {} if known.resume else {"devices": ahead.devices}
        default = self.args(config, env=known.env, preset=preset, **devices)
        args = tyro.cli(self.args_type, args=argv, default=default, prog=f"python -m train.{self.name}")
        args = dataclasses.replace(args, preset=resolve_preset(args.preset, args.env, self.presets or self.name))
        return self.check(self.args_from_saved(args.resume, args) if args.resume else args), built

    def _announce(self, preset: str, env: str) -> None:
        """Say on stderr where the defaults come from when ``--preset auto`` chose brax's or Playground's."""
        if preset == "playground":
            fn = "brax_ppo_config" if self.name == "ppo" else "brax_sac_config"
            print(f"preset: playground (MuJoCo Playground's {fn} for {env}; train.presets "
                  f"playground_{'ppo' if self.name == 'ppo' else 'sac_ddpg'}_config)", file=sys.stderr)  # fmt: skip
        elif preset == "brax":
            if self.name == "ppo":
                source = ("brax's published PPO settings", "BRAX_PPO")
                if brax_task(env) in BRAX_PPO_TUNED:
                    source = (f"{source[0]} with our tuned fields over them", f"{source[1]}, BRAX_PPO_TUNED")
            else:
                source = ("brax's SAC lanes and memory with TD3's own update settings", "BRAX_SAC, TD3_OWN")
                if brax_sac_task(env) in BRAX_SAC_TUNED:
                    source = (f"{source[0]} and our tuned entries over them", f"{source[1]}, BRAX_SAC_TUNED")
            print(f"preset: brax ({source[0]} for {env}; train.presets {source[1]})", file=sys.stderr)

    def check(self, args: Any) -> Any:
        """``args``, once its counts (:func:`~train.options.check_options`) and its hyper-parameters
        (:meth:`validate`) are found in range.

        Raises:
          ValueError: as :func:`~train.options.check_options`, or ``ConfigError`` as :meth:`validate`; for a
            resumed run the message begins ``--resume DIR: config.json:``.
        """
        try:
            check_options(args)
        except ValueError as e:
            raise ValueError(f"--resume {args.resume}: config.json: {e}" if args.resume else str(e)) from None
        self.validate(args)
        return args

    def validate(self, args: Any, config: Any = None) -> None:
        """``config.validate()`` (default: ``args``'s config), before the env is built.

        Raises:
          ConfigError: the first invalid field, its flag in front (``--clip-eps: clip_eps=2.0 is out of
            range; allowed (0, 1)``); for a resumed run ``--resume DIR: config.json: clip_eps=2.0 …``.
        """
        from envs_mjx.config import ConfigError

        config = getattr(args, self.name) if config is None else config
        try:
            config.validate()
        except ConfigError as e:
            if args.resume:
                raise ConfigError(f"--resume {args.resume}: config.json: {e}") from None
            name = re.match(r"[a-z_][a-z0-9_]*", str(e))
            fields = {f.name for f in dataclasses.fields(config)}
            raise ConfigError(f"{flag(name[0])}: {e}" if name and name[0] in fields else str(e)) from None

    def args_from_saved(self, run_dir: str, current: Any) -> Any:
        """The arguments saved in ``run_dir/config.json``, resuming that run; the options of
        :data:`~train.options.COMMAND_LINE_FIELDS` come from ``current`` (this command line)."""
        saved = load_config(run_dir)
        if saved.get("algo", self.name) != self.name or self.name not in saved:
            raise ValueError(f"--resume {run_dir!r}: a {saved.get('algo')!r} run, not {self.name!r}")
        options = dict(_tuples(saved.get("args", {})))
        options.update({k: getattr(current, k) for k in COMMAND_LINE_FIELDS}, resume=run_dir)
        unknown = set(options) - {f.name for f in dataclasses.fields(self.args_type)} - {self.name}
        if unknown:
            raise ValueError(f"--resume {run_dir!r}: config.json has unknown options {', '.join(sorted(unknown))}")
        return self.args(self.config_type(**_tuples(saved[self.name])), **options)

    def build(self, args: Any, built: BuiltEnv | None = None) -> tuple[Env, Trainer, dict[str, Any]]:
        """``(env, trainer, config dict)`` for ``args`` (a fresh run or a resumed one), checked (:meth:`check`)
        before the env is built; the env is ``built``'s (:meth:`parse_with_env`) where it has the run's settings."""
        cfg = getattr(self.check(args), self.name)
        mesh = lane_mesh(args.devices)
        if resolve_seed_map(args.seed_map) == "vmap" and args.seeds > 1 and mesh.devices.size > 1:
            raise ValueError(f"--seeds {args.seeds} vmapped runs on one device; add --devices 1 (the lanes would "
                             f"be spread over {mesh.devices.size}) or --seed-map loop")  # fmt: skip
        overrides = self.env_settings(args)
        check_backend_devices(overrides, mesh.devices.size)
        env = built.env if built is not None and built.fits(args.env, overrides) else make_env(args.env, overrides)
        if not cfg.episode_length:
            cfg = cfg.replace(episode_length=episode_length(env))
            self.validate(args, cfg)
        trainer, per_chunk = self.make_trainer(args, env, cfg, mesh)
        options = dataclasses.asdict(args)
        config = {
            "algo": self.name,
            "args": {
                k: v for k, v in options.items() if k != self.name and k not in (*PROCESS_FIELDS, *MACHINE_FIELDS)
            },
            self.name: dataclasses.asdict(cfg),
            "iterations_per_chunk": per_chunk,
            "devices": mesh.shape[parallel.LANES],
            "lane_map": lane_map_of(env, mesh),
            "processes": jax.process_count(),
            "env": env_record(args.env, env),
        }
        return env, trainer, config

    def main(self, argv: Sequence[str] | None = None) -> int:
        """Entry point of ``python -m train.<name>``; the exit code (:func:`cli_main`)."""
        return cli_main(self, argv)


def program_context(config: dict[str, Any]) -> dict[str, Any]:
    """What of a run's ``config`` keys its :class:`~jaxrl_robot.compilation.ProgramCache`: all of it but
    :data:`~train.options.RUN_ONLY_FIELDS`, so that runs with other seeds or folders share programs."""
    args = {k: v for k, v in config.get("args", {}).items() if k not in RUN_ONLY_FIELDS}
    return jsonable({**config, "args": args})


def cli_main(cli: AlgorithmCLI, argv: Sequence[str] | None = None) -> int:
    """The body of every ``python -m train.<algo>``: join the processes, parse, build, :func:`train.run.run`.

    The process options (``--coordinator``, ``--num-processes``, ``--process-id``, or the
    launcher's environment) go to ``parallel.initialize_multihost`` before any JAX computation.

    Returns:
      0 on a finished run (or one stopped on purpose), 1 after a non-finite loss, an unfinished run
      or a checkpoint that could not be written (disk full; the earlier ones are kept), 2 on bad input
      (the message names the field and the valid values; the options' counts are checked before any env
      is built, the config before the run's env and before anything is compiled), a run directory another
      process writes, or a ``--resume`` with no usable checkpoint or a ``config.json`` that no longer fits
      the checkpoint, 128 + the signal's number after SIGINT / SIGTERM stopped it (checkpointed;
      ``--resume`` continues).
      In a run over several processes whose peer stopped responding, the process ends at once with 1
      after one line on stderr (:func:`jaxrl_robot.parallel.exit_at_once`: a normal exit would wait
      for the lost peer in ``jax.distributed.shutdown`` and then abort).
    """
    from envs_mjx.config import ConfigError

    argv = cache_flags(sys.argv[1:] if argv is None else argv)
    mark = compile_log().mark()
    try:
        spec, args = _spec(cli, argv, mark)
    except (ConfigError, ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    try:
        result = run(spec)
    except RunDirError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (NonFiniteLossError, CheckpointWriteError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except CheckpointError as e:  # the run directory is in use, or no checkpoint of it can be resumed
        print(f"error: {e}", file=sys.stderr)
        return 2
    except PeerLostError as e:
        parallel.exit_at_once(1, f"error: {e}")
    except Exception as e:
        lost = parallel.lost_peer(e)  # before the run directory was chosen
        if lost is None:
            raise
        parallel.exit_at_once(1, f"error: {lost} as the run began; start it again")
    if cli.after is not None and is_main_process():
        for one in result.get("seeds", [result]):
            cli.after({**result, **one})
    if result.get("interrupted"):
        return 128 + result["interrupted"]  # the shell's code for a run ended by that signal
    return 0 if result.get("finished") or args.stop_after_steps else 1


def _spec(cli: AlgorithmCLI, argv: list[str], mark: tuple) -> tuple[RunSpec, Any]:
    """``(the RunSpec, the parsed args)`` of ``argv``: the processes joined and the compilation cache set up
    first (unless it asks for help), then parsed and built.

    Raises:
      ValueError, ConfigError, FileNotFoundError: bad input, as :func:`cli_main` reports it.
    """
    cache_dir = None
    if not _asks_for_help(argv):
        check_command_line(argv, cli.args_type.ranges)
        known = preparse(argv, ("compile_cache",))
        cache_dir = enable_persistent_cache(resolve_cache_dir(known.compile_cache))
        parallel.initialize_multihost(known.coordinator, known.num_processes, known.process_id)
    args, built = cli.parse_with_env(argv)
    env, trainer, config = cli.build(args, built)
    programs = None if _asks_for_help(argv) else ProgramCache.under(cache_dir, program_context(config))
    spec = RunSpec(
        algo=cli.name, env_name=args.env, env=env, trainer=trainer, config=config, run_dir=args.resume,
        episode_length=int(config[cli.name]["episode_length"]), compile_mark=mark, program_cache=programs,
        **settings_of(args),
    )  # fmt: skip
    return spec, args
