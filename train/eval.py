"""Re-evaluate a finished or stopped run: ``python -m train.eval RUN_DIR``.

Rebuilds the run's env and policy from ``config.json`` and its newest good checkpoint (``--step``: another
one) as ``jaxrl_robot.load_policy`` does, runs the final evaluation of ``python -m train.<algo>`` — the
same program on the same test episodes: with the run's seed and ``--eval-episodes`` the figures are those
of its ``eval.json`` — and prints the same table.  A run of several seeds is evaluated seed by seed
(``RUN_DIR/seed<k>``: that seed alone).  Nothing is written into the run directory; ``--out FILE`` writes
the results as JSON, ``--video FILE`` a GIF or an MP4 of test episodes (``jaxrl_robot.video``: MuJoCo's
offscreen renderer, EGL or OSMesa by ``$MUJOCO_GL``; racecar's chase view).

Examples::

    python -m train.eval runs/ppo-arm7-20260101-120000
    python -m train.eval runs/ppo-arm7-20260101-120000 --episodes 1000 --seed 5 --out eval-1000.json
    python -m train.eval runs/ppo-arm7-20260101-120000 --video arm7.gif --video-episodes 3
    python -m train.eval runs/ddpg-racecar-20260101-120000 --video lap.mp4      # pip install 'jaxrl-robot[video]'

Exit codes: 0 done; 2 bad input (one line on stderr: an option out of range, not a run directory, a seed
or checkpoint the run does not have, no usable checkpoint, a video that cannot be made here).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from typing import Any, NoReturn

__all__ = ["main", "parser"]


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line (``error: …``) and exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"error: {message} (python -m train.eval --help)\n")


def _count(low: int, high: int | None = None) -> Any:
    """An argparse type: an integer in ``[low, high]`` (None: no upper bound)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < low or (high is not None and value > high):
            allowed = f">= {low}" if high is None else f"[{low}, {high}]"
            raise argparse.ArgumentTypeError(f"{value} is out of range; allowed {allowed}")
        return value

    return parse


def parser() -> argparse.ArgumentParser:
    """The command line of ``python -m train.eval``."""
    from train.options import MAX_SEED

    p = _Parser(prog="python -m train.eval", description=__doc__.splitlines()[0],
                formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run directory (or the seed<k>/ folder of a run of several)")
    p.add_argument("--episodes", type=_count(1), default=None,
                   help="test episodes (racecar: laps per road); default: the run's --eval-episodes")
    p.add_argument("--seed", type=_count(0, MAX_SEED), default=None,
                   help="evaluation seed: the test episodes of a run trained with --seed S; default: each seed's own")
    p.add_argument("--step", type=_count(0), default=None,
                   help="checkpoint (chunk) to evaluate; default: the newest good one")
    p.add_argument("--precision", action=argparse.BooleanOptionalAction, default=None,
                   help="arm7: success at 5, 2 and 1 cm too; default: as the run")
    p.add_argument("--out", default=None, metavar="FILE", help="also write the results to FILE (JSON)")
    p.add_argument("--video", default=None, metavar="FILE", help="write test episodes as a video: FILE.gif or FILE.mp4")
    p.add_argument("--video-episodes", type=_count(1), default=1,
                   help="episodes in the video: the evaluation's first ones, if no more than --episodes (tracking "
                        "envs: the test episode)")
    p.add_argument("--video-size", default="320x240", metavar="WxH", help="video frame size in pixels")
    p.add_argument("--video-stride", type=_count(1), default=None,
                   help="draw every n-th step; default: the fewest that play at most 50 frames a second")
    return p  # fmt: skip


def _size(text: str) -> tuple[int, int]:
    """``"320x240"`` → ``(320, 240)``, each at least 16 pixels and even (MP4's colour planes halve them)."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--video-size {text!r}: expected WIDTHxHEIGHT, e.g. 320x240") from None
    if min(width, height) < 16 or width % 2 or height % 2:
        raise ValueError(f"--video-size {text}: each side an even number >= 16")
    return width, height


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m train.eval``; the exit code (module docstring)."""
    args = parser().parse_args(sys.argv[1:] if argv is None else list(argv))
    from jaxrl_robot.checkpoint import CheckpointError
    from jaxrl_robot.video import RenderError

    try:
        return _evaluate(args)
    except (ValueError, CheckpointError, RenderError, OSError) as e:  # RunLoadError, ConfigError: ValueErrors
        print(f"error: {e}", file=sys.stderr)
        return 2


def _evaluate(args: argparse.Namespace) -> int:
    """:func:`main` once parsed: load, evaluate each seed, print, write ``--out`` and ``--video``."""
    import jax

    from jaxrl_robot import runs, video
    from jaxrl_robot.compilation import enable_persistent_cache, resolve_cache_dir
    from jaxrl_robot.evaluation import evaluation_key
    from train.evaluations import (
        compile_evaluation_async,
        compiled_program,
        evaluate_state,
        evaluation_title,
        print_table,
    )
    from train.options import RunSpec

    size = _size(args.video_size) if args.video else None
    if args.video:
        video.check_video_path(args.video)
    for option, path in (("--out", args.out), ("--video", args.video)):
        _make_folder(option, path)  # before anything is evaluated
    enable_persistent_cache(resolve_cache_dir("auto"))  # the training's evaluation program may be cached
    run = runs.load_run(args.run_dir, step=args.step)
    if run.note:
        print(run.note, file=sys.stderr, flush=True)
    if args.video:
        video.check_rendering(run.env)
    algo, options = run.config["algo"], run.config.get("args", {})
    several = len(runs.run_seeds(run.config)) > 1
    spec = RunSpec(
        algo=algo, env_name=str(options.get("env")), env=run.env, trainer=run.trainer, config=run.config,
        run_dir=run.run_dir, episode_length=int(run.config[algo]["episode_length"]),
        eval_episodes=args.episodes or int(options.get("eval_episodes", 100)),
        precision=bool(options.get("precision", True)) if args.precision is None else args.precision,
    )  # fmt: skip
    print(f"{run.run_dir}: checkpoint {run.step} ({run.env_steps} env steps)", flush=True)
    results = []
    for k, state in run.states.items():
        eval_seed = k if args.seed is None else args.seed
        key = evaluation_key(eval_seed)
        t0 = time.perf_counter()
        compiled = compiled_program(compile_evaluation_async(spec, key, state))
        summary = evaluate_state(spec, key, state, None, compiled)
        eval_s = time.perf_counter() - t0
        rows = {**summary, "env_steps": run.env_steps, "checkpoint": run.step, "eval_s": round(eval_s, 2)}
        print_table(evaluation_title(algo, spec.env_name, k if several else None), rows)
        results.append({**summary, "seed": k, "eval_seed": eval_seed, "checkpoint": run.step,
                        "env_steps": run.env_steps, "run_dir": run.run_dir, "eval_s": eval_s})  # fmt: skip
    if args.out:
        _write_json(args.out, results[0] if len(results) == 1 else {"seeds": results})
        print(f"wrote {args.out}")
    if args.video:
        k, state = next(iter(run.states.items()))
        eval_seed = k if args.seed is None else args.seed
        episodes = max(spec.eval_episodes, args.video_episodes)  # the evaluation's first episodes: its keys
        keys = jax.random.split(evaluation_key(eval_seed), episodes)[: args.video_episodes]
        frames = video.episode_video(args.video, run.env, run.trainer.policy(state), keys, *size,
                                     stride=args.video_stride, episode_length=spec.episode_length)  # fmt: skip
        print(f"wrote {args.video} ({frames} frames" + (f", seed {k}" if several else "") + ")")
    return 0


def _make_folder(option: str, path: str | None) -> None:
    """Make the folder of ``path`` (given by ``option``; None: nothing to do).

    Raises:
      ValueError: it cannot be made (one line naming the option and the path).
    """
    if path is None:
        return
    folder = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(folder, exist_ok=True)
    except FileExistsError:
        raise ValueError(f"{option} {path!r}: cannot write it ({folder} is a file)") from None
    except OSError as e:
        raise ValueError(f"{option} {path!r}: cannot write it ({e.strerror or e})") from None


def _write_json(path: str, obj: Any) -> None:
    """``obj`` as JSON (``train.rundir.write_json``: non-finite floats as null).

    Raises:
      ValueError: the file cannot be written (one line naming it).
    """
    from train.rundir import write_json

    try:
        write_json(path, obj)
    except OSError as e:
        raise ValueError(f"--out {path!r}: cannot write it ({e.strerror or e})") from None


if __name__ == "__main__":
    sys.exit(main())
