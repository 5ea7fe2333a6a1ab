"""Command-line entry points: ``python -m train.<algo>``.

A training command that does not ask for MuJoCo Warp (no ``impl=warp`` among its arguments, no
``playground:`` env, no ``--resume`` of a run that used either) imports MJX without it, which saves
seconds of start-up (``envs_mjx.xla.WARP_ENV``; a value already set is kept).
"""

import json
import os
import sys

TRAINING = ("train.ppo", "train.a2c", "train.a3c", "train.ddpg", "train.td3", "train.sac")
"""The modules whose ``python -m`` commands leave Warp out unless asked for it."""


def _asks_for_warp(args: list[str]) -> bool:
    """Whether a command's arguments (or the ``config.json`` of the run it resumes) ask for Warp."""
    text = " ".join(args)
    if "impl=warp" in text or "playground:" in text:
        return True
    if "--resume" in args and args.index("--resume") + 1 < len(args):
        try:
            with open(os.path.join(args[args.index("--resume") + 1], "config.json")) as f:
                saved = json.dumps(json.load(f).get("args", {}))
        except (OSError, ValueError):
            return True  # unreadable: the command reports it; Warp stays available meanwhile
        return "impl=warp" in saved or "playground:" in saved
    return False


def _leave_out_warp() -> None:
    argv = list(getattr(sys, "orig_argv", []))
    if "-m" in argv and argv.index("-m") + 1 < len(argv):
        i = argv.index("-m")
        if argv[i + 1] in TRAINING and not _asks_for_warp(argv[i + 2 :]):
            os.environ.setdefault("JAXRL_ROBOT_WARP", "off")


_leave_out_warp()
