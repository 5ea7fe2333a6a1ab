"""Time to solve: how long ``python -m train.<algo>`` takes, as a user runs it, to reach a task's target, on 1, 2
and 4 devices.

    python -m benchmarks.time_to_solve                                   # every task, devices 1 2 4, 3 tune seeds
    python -m benchmarks.time_to_solve --tasks arm7 her_arm7 --purpose report --stop-at-target --concurrent
    python -m benchmarks.time_to_solve --tasks arm7 --devices 1 2 --total-steps 2000000 -- --preset fast

Tasks (:data:`TASKS`; the command line of each is in the results):

* ``arm7``: ``train.ppo --env arm7`` (the main job), ≥ 95 % of the test goals within 5 cm;
* ``arm7_precise``: ``train.ddpg --env arm7_precise`` with the sparse reward and HER future k=2 in kinematic mode,
  ≥ 95 % within 2 cm. DDPG rather than PPO: in the thesis tables at a 1 cm goal (``benchmarks/results/
  thesis-gpu-nvidia_h100_80gb_hbm3-fast-precise.md``, ``fast`` preset) every seed of the DDPG rows that relabel
  with achieved goals met 95 % within 2 cm (6 of 6 seeds each), PPO's ordinary reward met it by 1-4 points per
  seed and its path reward missed it on a seed;
* ``unicycle_sine``: ``train.ppo --env unicycle`` on the sine, per-axis tracking errors (sums of |error| over
  the test episode) at most half the thesis's best over all its methods (:data:`benchmarks.tracking_report.GOAL`:
  x 1.30, y 0.86, θ 0.47);
* ``her_arm7``: ``train.ddpg --env arm7`` with the sparse reward and HER future k=2 in kinematic mode (the thesis
  table's rows), ≥ 95 % within 5 cm;
* ``sac_her_arm7``: the same with ``train.sac`` (DDPG's preset as SAC) and the temperature starting at 0.05
  (``--init-alpha``; the default 1 weighs the entropy as much as a whole step's sparse reward), ≥ 95 % within 5 cm.

Each (task, device count, seed) is a fresh process of the real command line with ``--evals K`` (evaluations
during training, ``train/periodic.py``), so that start-up and compilation count as a user sees them. On a GPU
host the process sees the first ``n`` GPUs (``CUDA_VISIBLE_DEVICES``; with ``--concurrent`` the processes of a
device count run side by side on disjoint sets of ``n`` GPUs, e.g. four 1-GPU runs at once on 4 GPUs); on a CPU
host it gets ``n`` fake CPU devices (``XLA_FLAGS=--xla_force_host_platform_device_count=n``,
``JAX_PLATFORMS=cpu``). Every process compiles into an empty compilation cache unless ``--compile-cache`` says
otherwise (``shared``: one folder for the whole invocation, so later processes of a program load it; a folder:
that one).

Per process, from its ``evals.csv`` (and its wall time, measured here): **process wall** (its start to its exit;
with ``--stop-at-target`` it is sent SIGTERM once an evaluation meets the target, and stops after that chunk),
**start-up** (its start to the run's: imports, devices, env and trainer), **first chunk** (compilation
included), **to target, training clock** (``train_wall_s`` of the first evaluation that met the target: training
time only, evaluations apart) and **to target, total** (``process_s`` of that evaluation: from the process's
start, evaluations before it apart). Per (task, device count): mean ± standard deviation over the seeds that met
the target (the count beside), and one figure per task of the criterion against the training clock per device
count. Results: ``benchmarks/results/<device>-time_to_solve[-<label>].{md,json}`` with the provenance of
:mod:`benchmarks.provenance` (the device is read in a child process, so this one never holds a GPU).
"""

from __future__ import annotations

import argparse
import dataclasses
import glob
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from benchmarks import provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import nonnegative, positive
from benchmarks.time_to_solve_report import to_markdown, write

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
SINE_GOAL = (1.30, 0.86, 0.47)
"""Half the thesis's best unicycle-sine tracking errors over all its methods, x / y / θ
(:data:`benchmarks.tracking_report.GOAL`, checked against it by the tests)."""
HER = ("--env-config", "mode=kinematic", "--reward", "sparse", "--her", "future", "--her-k", "2")


@dataclasses.dataclass(frozen=True)
class Task:
    """A command line and its target.

    Attributes:
      name: the task's name (``--tasks``).
      algo: ``train.<algo>``.
      env: ``--env``.
      args: the task's further flags.
      column: the ``evals.csv`` column of a success task (``success_5cm``), or ``tracking`` (the per-axis error
        sums ``x``, ``y``, ``theta`` against ``goal``).
      fallback: the column read where ``column`` is missing (arm7's ``success_rate``, its goal threshold being
        5 cm, when the run has ``--no-precision``).
      goal: a tracking task's per-axis goal.
      words: the target in words.
    """

    name: str
    algo: str
    env: str
    args: tuple[str, ...]
    column: str
    words: str
    fallback: str | None = None
    goal: tuple[float, ...] = ()

    def value(self, row: dict[str, str]) -> float:
        """The criterion of an ``evals.csv`` row: success (a fraction), or for a tracking task the worst axis's
        error over its goal (at most 1: met)."""
        if self.column == "tracking":
            return max(float(row[axis]) / g for axis, g in zip(("x", "y", "theta"), self.goal, strict=True))
        if row.get(self.column) not in (None, ""):
            return float(row[self.column])
        if self.fallback and row.get(self.fallback) not in (None, ""):
            return float(row[self.fallback])
        raise ValueError(f"{self.name}: evals.csv has no {self.column!r} column (evaluate with --precision)")

    def met(self, value: float, target: float) -> bool:
        """Whether ``value`` (:meth:`value`) meets the target (``target``: a success task's fraction)."""
        return value <= 1.0 if self.column == "tracking" else value >= target

    def command(self, seed: int, devices: int, options: argparse.Namespace, extra: Sequence[str]) -> list[str]:
        """The process's command line (``options``: this benchmark's arguments; ``extra``: flags for every task)."""
        budget = []
        if options.total_steps and self.algo == "ppo":
            budget = ["--total-steps", str(options.total_steps)]
        if options.epochs and self.algo in ("ddpg", "sac"):
            budget = ["--epochs", str(options.epochs)]
        return [sys.executable, "-m", f"train.{self.algo}", "--env", self.env, *self.args, "--preset", options.preset,
                *budget, "--seed", str(seed), "--devices", str(devices), "--evals", str(options.evals),
                "--eval-episodes", str(options.eval_episodes), "--progress", "False", *extra]  # fmt: skip


TASKS = {
    "arm7": Task("arm7", "ppo", "arm7", (), "success_5cm", "≥ 95 % of the test goals within 5 cm",
                 fallback="success_rate"),
    "arm7_precise": Task("arm7_precise", "ddpg", "arm7_precise", HER, "success_2cm",
                         "≥ 95 % of the test goals within 2 cm"),
    "unicycle_sine": Task("unicycle_sine", "ppo", "unicycle", ("--env-config", "trajectory=sine"), "tracking",
                          "tracking errors x / y / θ at most 1.30 / 0.86 / 0.47 (½ the thesis's best)",
                          goal=SINE_GOAL),
    "her_arm7": Task("her_arm7", "ddpg", "arm7", HER, "success_5cm", "≥ 95 % of the test goals within 5 cm",
                     fallback="success_rate"),
    "sac_her_arm7": Task("sac_her_arm7", "sac", "arm7", (*HER, "--init-alpha", "0.05"), "success_5cm",
                         "≥ 95 % of the test goals within 5 cm", fallback="success_rate"),
}  # fmt: skip
"""The tasks: a command line each, with its target."""


def gpu_count() -> int:
    """GPUs on this host (``nvidia-smi -L``), 0 without any or with ``JAX_PLATFORMS=cpu``."""
    if os.environ.get("JAX_PLATFORMS") == "cpu" or shutil.which("nvidia-smi") is None:
        return 0
    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return 0
    return sum(line.startswith("GPU ") for line in out.stdout.splitlines()) if out.returncode == 0 else 0


def child_env(gpus: Sequence[int] | None, devices: int, cache: str) -> dict[str, str]:
    """The environment of one process: ``gpus`` (a GPU host: ``CUDA_VISIBLE_DEVICES``), else ``devices`` fake
    CPU devices; its compilation cache folder ``cache``."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", JAXRL_ROBOT_COMPILE_CACHE=cache)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["PYTHONPATH"] = provenance.REPO + os.pathsep + env.get("PYTHONPATH", "")
    if gpus is not None:
        env["CUDA_VISIBLE_DEVICES"] = ",".join(map(str, gpus))
        return env
    flags = [f for f in env.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
    env["XLA_FLAGS"] = " ".join([*flags, f"--xla_force_host_platform_device_count={devices}"])
    env["JAX_PLATFORMS"] = "cpu"
    return env


def device_info(gpus: int, devices: Sequence[int]) -> dict[str, Any]:
    """:func:`benchmarks.provenance.device` as a child process sees this host's GPUs; on a CPU host the fake
    devices' record (``count``: the most asked for)."""
    if not gpus:
        return {"name": "cpu", "platform": "cpu", "count": max(devices), "cpu_cores": os.cpu_count(),
                "fake_devices": True}  # fmt: skip
    code = "import json; from benchmarks.provenance import device; print(json.dumps(device()))"
    out = subprocess.run([sys.executable, "-c", code], cwd=provenance.REPO, capture_output=True, text=True,
                         env=child_env(range(gpus), gpus, "off"), check=True)  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def device_label(dev: dict[str, Any]) -> str:
    """``cpu-<cores>core`` or ``gpu-<name>``, lower case, no spaces: the results files' prefix."""
    label = f"cpu-{dev['cpu_cores'] or 0}core" if dev["platform"] == "cpu" else f"gpu-{dev['name']}"
    return label.replace(" ", "_").lower()


def read_rows(run_dir: str) -> list[dict[str, str]]:
    """The rows of ``run_dir/evals.csv`` ([] while there is none)."""
    path = os.path.join(run_dir, "evals.csv")
    if not os.path.exists(path):
        return []
    from train.periodic import read_evals

    return read_evals(path)


def first_met(task: Task, rows: Sequence[dict[str, str]], target: float) -> dict[str, str] | None:
    """The first row whose criterion meets the target (None: none did)."""
    return next((r for r in rows if task.met(task.value(r), target)), None)


def _float(text: str | None) -> float | None:
    return None if text in (None, "") else float(text)


def run_one(task: Task, seed: int, devices: int, gpus: Sequence[int] | None, options: argparse.Namespace,
            extra: Sequence[str], runs: str, cache: str) -> dict[str, Any]:  # fmt: skip
    """One process of ``task`` on ``devices`` devices (``gpus``: which GPUs; None: fake CPU devices): its
    figures from its ``evals.csv`` and ``eval.json``, or ``error`` where it failed."""
    out = os.path.join(runs, f"{task.name}-d{devices}-s{seed}")
    os.makedirs(out, exist_ok=True)
    cmd = [*task.command(seed, devices, options, extra), "--out", out]
    record: dict[str, Any] = {"task": task.name, "devices": devices, "seed": seed, "gpus": None if gpus is None
                              else list(gpus), "command": " ".join(["python", *cmd[1:-2]])}  # fmt: skip
    log_path = os.path.join(out, "process.log")
    stopped = False
    with open(log_path, "w") as log:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=provenance.REPO, env=child_env(gpus, devices, cache), stdout=log,
                                stderr=subprocess.STDOUT)  # fmt: skip
        while proc.poll() is None:
            time.sleep(options.poll)
            if options.stop_at_target and not stopped:
                found = glob.glob(os.path.join(out, f"{task.algo}-*"))
                try:
                    rows = read_rows(found[0]) if found else []
                    stopped = first_met(task, rows, options.target) is not None
                except (OSError, ValueError, KeyError):  # a file being replaced, or a column missing: next time
                    rows = []
                if stopped:
                    proc.send_signal(signal.SIGTERM)  # stops after the chunk, with a checkpoint
        wall = time.perf_counter() - t0
    record.update(process_wall_s=round(wall, 2), exit_code=proc.returncode, stopped_at_target=stopped)
    found = glob.glob(os.path.join(out, f"{task.algo}-*"))
    if proc.returncode not in (0, 128 + signal.SIGTERM if stopped else 0) or len(found) != 1:
        with open(log_path) as f:
            record["error"] = f.read()[-3000:]
        return record
    rows = read_rows(found[0])
    record["run_dir"] = found[0]
    if not rows:
        record["error"] = "no evals.csv"
        return record
    met = first_met(task, rows, options.target)
    record.update(
        startup_s=_float(rows[0]["startup_s"]), first_chunk_s=_float(rows[0]["first_chunk_s"]), reached=met is not None,
        train_to_target_s=None if met is None else float(met["train_wall_s"]),
        total_to_target_s=None if met is None else _float(met["process_s"]),
        env_steps_to_target=None if met is None else int(met["env_steps"]),
        final=task.value(rows[-1]), final_env_steps=int(rows[-1]["env_steps"]),
        curve=[{"chunk": int(r["chunk"]), "env_steps": int(r["env_steps"]), "train_wall_s": float(r["train_wall_s"]),
                "process_s": _float(r["process_s"]), "eval_s": float(r["eval_s"]), "value": task.value(r)}
               for r in rows],
    )  # fmt: skip
    eval_json = os.path.join(found[0], "eval.json")
    if os.path.exists(eval_json):
        with open(eval_json) as f:
            ev = json.load(f)
        compiled = ev.get("compile", {})
        record.update(finished=True, train_s=ev.get("train_s"), eval_s=ev.get("eval_s"),
                      periodic_eval_s=ev.get("periodic_eval_s"), programs=compiled.get("programs"),
                      cache_hits=compiled.get("cache_hits"))  # fmt: skip
    else:
        record["finished"] = False
    return record


def parser() -> argparse.ArgumentParser:
    """The benchmark's command line (flags after ``--`` are the runs' and are split off before it parses)."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.time_to_solve", description=__doc__.splitlines()[0],
                                epilog="Flags after -- go to every process's command line (e.g. -- --chunks 20).")
    p.add_argument("--tasks", nargs="+", choices=list(TASKS), default=list(TASKS), help="default: every task")
    p.add_argument("--devices", nargs="+", type=positive, default=[1, 2, 4], help="device counts (default 1 2 4)")
    bench_seeds.add_args(p, seeds=3)
    p.add_argument("--evals", type=positive, default=20, help="evaluations during training (--evals of the runs)")
    p.add_argument("--eval-episodes", type=positive, default=100, help="episodes per evaluation")
    p.add_argument("--preset", default="auto", help="the runs' --preset")
    p.add_argument("--total-steps", type=nonnegative, default=0, help="PPO tasks' --total-steps (0: the preset's)")
    p.add_argument("--epochs", type=nonnegative, default=0, help="DDPG and SAC tasks' --epochs (0: the preset's)")
    p.add_argument("--target", type=_fraction, default=0.95, help="success tasks' target fraction (default 0.95)")
    p.add_argument("--stop-at-target", action="store_true",
                   help="stop each process (SIGTERM: after the chunk, checkpointed) once an evaluation met the target")
    p.add_argument("--concurrent", action="store_true",
                   help="GPU host: run the processes of a device count side by side on disjoint sets of GPUs")
    p.add_argument("--compile-cache", default="cold",
                   help="cold: an empty folder per process (default); shared: one for the invocation; or a folder")
    p.add_argument("--runs", default=None, help="keep the run directories here (default: a temporary folder)")
    p.add_argument("--poll", type=float, default=0.5, help=argparse.SUPPRESS)
    p.add_argument("--label", default="", help="suffix of the results files")
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    return p


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"{value} is out of range; allowed [0, 1]")
    return value


def main(argv: list[str] | None = None) -> dict[str, Any]:
    argv = sys.argv[1:] if argv is None else list(argv)
    ours, extra = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    p = parser()
    args = p.parse_args(ours)
    gpus = gpu_count()
    if gpus and max(args.devices) > gpus:
        p.error(f"--devices {max(args.devices)}: this host has {gpus} GPUs")
    try:
        ids = bench_seeds.seed_ids(args.purpose, args.seeds, args.first_seed)
    except ValueError as e:
        p.error(f"--seeds/--first-seed: {e}")
    dev = device_info(gpus, args.devices)
    prov = provenance.record("benchmarks.time_to_solve", argv, allow_dirty=args.allow_dirty, device_info=dev,
                             seeds=bench_seeds.record(args.purpose, ids, "train.<algo> --seed k"))  # fmt: skip
    stem = os.path.join(args.out, device_label(dev) + "-time_to_solve" + (f"-{args.label}" if args.label else ""))
    cache_words = {"cold": "an empty folder per process", "shared": "one folder shared by the invocation's processes"}
    result: dict[str, Any] = {
        "benchmark": "time_to_solve", "provenance": prov, "device": dev, "stem": stem, "device_counts": args.devices,
        "seeds": bench_seeds.record(args.purpose, ids, "train.<algo> --seed k"), "evals": args.evals,
        "eval_episodes": args.eval_episodes, "preset": args.preset, "target": args.target, "extra_args": extra,
        "compile_cache": cache_words.get(args.compile_cache, f"the folder {args.compile_cache}"),
        "concurrent": bool(args.concurrent and gpus), "stop_at_target": args.stop_at_target,
        "tasks": [{"task": name, "words": TASKS[name].words if TASKS[name].column == "tracking" or args.target == 0.95
                   else TASKS[name].words.replace("95 %", f"{100 * args.target:g} %"), "target": args.target,
                   "command": " ".join(["python", *TASKS[name].command(ids[0], args.devices[0], args, extra)[1:]]),
                   "runs": []} for name in args.tasks],
    }  # fmt: skip
    tmp = tempfile.mkdtemp(prefix="time-to-solve-")
    runs = args.runs or os.path.join(tmp, "runs")
    lock = threading.Lock()
    try:
        for n in args.devices:
            slots = max(1, gpus // n) if args.concurrent and gpus else 1
            free = list(range(slots))
            jobs = [(t, seed) for t in result["tasks"] for seed in ids]

            def job(item: tuple[dict[str, Any], int], n: int = n, free: list[int] = free) -> None:
                task, seed = item
                with lock:
                    slot = free.pop()
                try:
                    caches = {"cold": os.path.join(tmp, f"cache-{task['task']}-{n}-{seed}"),
                              "shared": os.path.join(tmp, "cache")}  # fmt: skip
                    cache = caches.get(args.compile_cache, args.compile_cache)
                    gpu_ids = list(range(slot * n, slot * n + n)) if gpus else None
                    record = run_one(TASKS[task["task"]], seed, n, gpu_ids, args, extra, runs, cache)
                finally:
                    with lock:
                        free.append(slot)
                with lock:
                    task["runs"].append(record)
                    task["runs"].sort(key=lambda r: (r["devices"], r["seed"]))
                    write(result)
                    reached = "—" if "error" in record else record.get("train_to_target_s")
                    print(f"{task['task']} devices {n} seed {seed}: process wall {record['process_wall_s']:.1f} s, "
                          f"to target (training clock) {reached}" + (" FAILED" if "error" in record else ""),
                          flush=True)  # fmt: skip

            with ThreadPoolExecutor(max_workers=slots) as pool:
                list(pool.map(job, jobs))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    provenance.write(stem, result, to_markdown(result), echo=True)
    return result


if __name__ == "__main__":
    main()
