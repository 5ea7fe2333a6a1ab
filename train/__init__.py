"""Command-line entry points: ``python -m train.<algo>``.

The algorithms are the modules of this package that define a module-level ``CLI`` (an
:class:`~train.cli.AlgorithmCLI`), found by :func:`algorithms` from their source without importing them.

A training command that does not ask for MuJoCo Warp (no ``impl=warp`` among its arguments, no
``playground:`` env, no ``--resume`` of a run that used either) imports MJX without it, which saves
seconds of start-up (``envs_mjx.xla.WARP_ENV``; a value already set is kept).

``MUJOCO_GL`` (MuJoCo's choice of OpenGL back end for drawing videos) is checked first when it is set: a
value MuJoCo does not know, or a back end whose library this machine lacks (``egl`` without libEGL,
``osmesa`` without libOSMesa), ends the command with one line naming the variable and the choices,
instead of the traceback ``import mujoco`` raises.
"""

import json
import os
import pkgutil
import re
import sys

_DEFINES_CLI = re.compile(r"^CLI\b[^=\n]*=", re.MULTILINE)


def algorithms() -> tuple[str, ...]:
    """The algorithms of ``python -m train.<algo>``, sorted: the modules of this package whose source assigns
    a module-level ``CLI`` (read, not imported, so that nothing heavy is loaded)."""
    found = []
    for module in pkgutil.iter_modules(__path__):
        try:
            with open(os.path.join(__path__[0], f"{module.name}.py"), encoding="utf-8") as f:
                if _DEFINES_CLI.search(f.read()):
                    found.append(module.name)
        except OSError:  # a sub-package or a module that is not a source file defines no command
            continue
    return tuple(sorted(found))


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


GL_BACKENDS = ("egl", "osmesa", "glfw")
"""The values of ``MUJOCO_GL`` MuJoCo knows: EGL (a GPU, headless), OSMesa (software) and GLFW (a display)."""


def renderer_problem() -> str | None:
    """Why MuJoCo cannot be imported with this process's ``MUJOCO_GL`` (which ``import mujoco`` reads): one
    line, or None where the variable is unset or ``import mujoco`` succeeds."""
    value = os.environ.get("MUJOCO_GL")
    if not value:
        return None
    try:
        import mujoco  # noqa: F401  (it loads the chosen OpenGL back end at import)
    except Exception as e:  # RuntimeError for an unknown value; AttributeError/ImportError/OSError: no library
        known = value.lower() in GL_BACKENDS
        why = "its library is missing on this machine" if known else "MuJoCo does not know that value"
        first = str(e).splitlines()[0] if str(e) else ""
        return (f"MUJOCO_GL={value!r}: MuJoCo cannot load that renderer ({why}; {type(e).__name__}: {first}); "
                f"valid: egl (libEGL, package libegl1), osmesa (libOSMesa, package libosmesa6), glfw (a display), "
                f"or MUJOCO_GL unset")  # fmt: skip
    return None


def _check_renderer() -> None:
    argv = list(getattr(sys, "orig_argv", []))
    if "-m" in argv and argv.index("-m") + 1 < len(argv) and argv[argv.index("-m") + 1].startswith(f"{__name__}."):
        problem = renderer_problem()
        if problem:
            print(f"error: {problem}", file=sys.stderr)
            sys.exit(2)


def _leave_out_warp() -> None:
    argv = list(getattr(sys, "orig_argv", []))
    if "-m" in argv and argv.index("-m") + 1 < len(argv):
        i = argv.index("-m")
        package, _, name = argv[i + 1].partition(".")
        if package == __name__ and name in algorithms() and not _asks_for_warp(argv[i + 2 :]):
            os.environ.setdefault("JAXRL_ROBOT_WARP", "off")


_check_renderer()
_leave_out_warp()
