"""``python -m train.ppo`` over two processes (jax.distributed on localhost, CPU, gloo collectives).

Two processes with two CPU devices each train the tiny PPO run of ``test_ppo_cli.py`` on 4 global
lanes, stop half-way and resume (every process restores its shards of the checkpoint); one process
with one device (on a CPU host, the test's own) trains the same lanes without a break. The final
parameters agree, the two processes share one run directory, and only process 0 writes its files
(process 1 writes only its shards of the checkpoints, as orbax does).
"""

import glob
import json
import os
import socket
import subprocess
import sys
import textwrap
import time

import jax

from tests.cli.test_ppo_cli import TINY, assert_same_learnt_state, final_checkpoint
from tests.subproc import ROOT, cpu_env
from train import ppo

ARGS = ["--env", "brax:fast", "--episode-length", "16", "--total-steps", "256", "--chunks", "2",
        "--checkpoint-every", "1", "--eval-episodes", "2", "--seed", "7", "--progress", "False", *TINY]  # fmt: skip
TIMEOUT_S = 300

# Runs ``train.ppo.main(argv)`` and records every file this process opens for writing or creates
# (Python's audit events; orbax's array shards are written by tensorstore and are not seen).
WRAPPER = textwrap.dedent(
    """
    import json, os, sys

    log_path, argv = sys.argv[1], sys.argv[2:]
    written = []
    WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND

    def audit(event, args):
        if event == "open":
            path, mode, flags = args
            writing = (isinstance(mode, str) and any(c in mode for c in "wax+")) or (
                isinstance(flags, int) and flags & WRITE_FLAGS
            )
            if writing and isinstance(path, (str, bytes, os.PathLike)):
                written.append(os.path.abspath(os.fsdecode(path)))
        elif event in ("os.mkdir", "os.rename", "os.replace"):
            written.append(os.path.abspath(os.fsdecode(args[0])))

    sys.addaudithook(audit)
    from train import ppo

    code = ppo.main(argv)
    with open(log_path, "w") as f:
        json.dump(written, f)
    sys.exit(code)
    """
)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def _start(argv: list[str], log: str, devices: int, cache: str) -> subprocess.Popen:
    """``train.ppo`` with ``argv`` on ``devices`` CPU devices, logging its writes to ``log``.

    No launcher's variables are passed on, so no cluster is detected; a persistent compilation
    cache at ``cache`` makes a second process group with the same programs cheap.
    """
    env = cpu_env(
        devices=devices,
        JAX_COMPILATION_CACHE_DIR=cache,
        JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
        JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="-1",
    )
    for k in list(env):
        if k.startswith(("SLURM_", "OMPI_", "PMI_")) or k in ("JAX_COORDINATOR_ADDRESS", "KUBERNETES_SERVICE_HOST"):
            del env[k]
    cmd = [sys.executable, "-c", WRAPPER, log, *argv]
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _start_pair(argv: list[str], logs: str, cache: str) -> dict[str, subprocess.Popen]:
    """Processes 0 and 1 of a run over two processes of two CPU devices each."""
    flags = ["--coordinator", f"localhost:{_free_port()}", "--num-processes", "2"]
    return {f"p{i}": _start([*argv, *flags, "--process-id", str(i)], f"{logs}-p{i}.json", 2, cache) for i in (0, 1)}


def _wait_all(procs: dict[str, subprocess.Popen]) -> dict[str, str]:
    """Outputs of every process; all are killed if one fails or the time runs out."""
    deadline = time.monotonic() + TIMEOUT_S
    outputs: dict[str, str] = {}
    try:
        for name, proc in procs.items():
            out, _ = proc.communicate(timeout=max(1.0, deadline - time.monotonic()))
            outputs[name] = out
            assert proc.returncode == 0, f"{name} exited with {proc.returncode}:\n{out[-4000:]}"
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return outputs


def _train_reference(out: str, procs: dict[str, subprocess.Popen], log: str, cache: str) -> None:
    """The uninterrupted run on one CPU device, while ``procs`` run: in this process on a CPU host (one start-up
    less), else in a CPU-pinned process added to ``procs``; ``procs`` are killed if it fails here."""
    if jax.default_backend() != "cpu":
        procs["single"] = _start([*ARGS, "--out", out], log, 1, cache)
        return
    try:
        assert ppo.main([*ARGS, "--out", out]) == 0
    except BaseException:
        for proc in procs.values():
            proc.kill()
            proc.communicate()
        raise


def test_two_processes_train_like_one_and_only_process_0_writes(tmp_path):
    multi, single, cache = tmp_path / "multi", tmp_path / "single", str(tmp_path / "jax_cache")
    procs = _start_pair([*ARGS, "--out", str(multi), "--stop-after-steps", "128"], str(tmp_path / "first"), cache)
    _train_reference(str(single), procs, str(tmp_path / "single.json"), cache)
    first = _wait_all(procs)
    (run_dir,) = glob.glob(str(multi / "ppo-brax_fast-*"))  # one run directory for both processes
    assert not os.path.exists(os.path.join(run_dir, "eval.json"))  # stopped after chunk 1 of 2
    second = _wait_all(_start_pair(["--resume", run_dir], str(tmp_path / "second"), cache))

    (single_dir,) = glob.glob(str(single / "ppo-brax_fast-*"))
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["processes"] == 2 and config["devices"] == 4
    assert config["lane_map"] == "vmap"  # brax's env does not say it steps no MJX physics: several devices, vmap
    assert "coordinator" not in config["args"]  # where the processes ran is not part of the run
    assert json.load(open(os.path.join(single_dir, "config.json")))["devices"] == 1
    assert json.load(open(os.path.join(single_dir, "config.json")))["lane_map"] == "shard_map"

    # only process 0 prints and writes; process 1 writes nothing outside its checkpoint shards
    assert f"run directory: {run_dir}" in first["p0"] and "run directory" not in first["p1"]
    assert "resumed at chunk 1 (128 env steps)" in second["p0"] and "resumed" not in second["p1"]
    assert "mean_return" in second["p0"] and "mean_return" not in second["p1"]  # the evaluation table
    root = os.path.realpath(run_dir)
    written: dict[str, list[str]] = {"p0": [], "p1": []}
    for half in ("first", "second"):
        for p in written:
            files = [os.path.realpath(f) for f in json.load(open(tmp_path / f"{half}-{p}.json"))]
            written[p] += [f for f in files if f.startswith(os.path.realpath(multi))]
    assert written["p1"] and all(f.startswith(os.path.join(root, "checkpoints")) for f in written["p1"]), written
    for name in ("config.json", "metrics.csv", "eval.json", "episode_reward.png"):
        assert os.path.join(root, name) in written["p0"], name
    assert len(glob.glob(os.path.join(run_dir, "tb", "events.*"))) == 2  # one per half, both by process 0
    rows = open(os.path.join(run_dir, "metrics.csv")).read().strip().splitlines()
    assert len(rows) == 3  # header + 2 chunks, none repeated after the resume

    # the same lanes trained by 2 processes x 2 devices (with a restart) and by 1 process x 1 device
    reference, record = final_checkpoint(single_dir)
    state, record_multi = final_checkpoint(run_dir, target=reference)
    assert record["chunk"] == record_multi["chunk"] == 2
    assert_same_learnt_state(state, reference, atol=1e-5)
    assert json.load(open(os.path.join(run_dir, "eval.json")))["episodes"] == 2
