"""Every ``python -m train.<algo>`` and the benchmarks check their counts as they parse, and a run over
two processes whose peer dies ends its survivor with one line.

Bad flags fail before any env is built (``train.cli.make_env`` is replaced by a function that fails the
test), with one line on stderr naming the flag and the allowed range, exit code 2 and no run
directory. The peer test runs a stand-in algorithm (one all-reduce over the lanes of both processes
per chunk) through the real command-line machinery (:func:`train.cli.cli_main`) in two processes
and kills process 1 after its first chunk.
"""

import dataclasses
import glob
import importlib
import json
import os
import queue
import re
import subprocess
import sys
import textwrap
import threading
import time
from typing import Annotated

import jax
import jax.numpy as jnp
import pytest
import tyro

from envs_mjx.config import check_range
from jaxrl_robot import parallel
from jaxrl_robot.types import Trainer
from tests.cli.test_multihost import _free_port
from tests.subproc import ROOT, cpu_env
from train import a2c, a3c, cli, ddpg, ppo, td3
from train.cli import AlgorithmCLI, iterations_per_chunk
from train.envs import BuiltEnv, check_backend_devices
from train.options import RunOptions, RunSpec
from train.run import PeerLostError, run

CLIS = {"ppo": ppo.main, "a2c": a2c.main, "a3c": a3c.main, "ddpg": ddpg.main, "td3": td3.main}
ON_POLICY = ("ppo", "a2c", "a3c")

# (flag, value, allowed) for every CLI; --chunks differs (0 is DDPG's and TD3's "one per epoch")
BAD_RUN_OPTIONS = [
    ("--eval-episodes", "-5", ">= 1"),
    ("--eval-episodes", "0", ">= 1"),
    ("--checkpoint-every", "0", ">= 1"),
    ("--seeds", "0", ">= 1"),
    ("--seed", "-1", f"[0, {2**32 - 1}]"),
    ("--devices", "-1", ">= 0"),
    ("--stop-after-steps", "-1", ">= 0"),
    ("--num-processes", "0", ">= 1"),
    ("--process-id", "-1", ">= 0"),
]
CASES = [(algo, *bad) for algo in CLIS for bad in BAD_RUN_OPTIONS]
CASES += [(algo, "--chunks", value, ">= 1") for algo in ON_POLICY for value in ("0", "-1")]
CASES += [(algo, "--chunks", "-1", ">= 0") for algo in ("ddpg", "td3")]


@pytest.fixture
def no_env(monkeypatch):
    """``train.cli.make_env`` that fails the test: nothing may be built for a command line with a bad count."""

    def fail(name, overrides):
        raise AssertionError(f"an env ({name}) was built before the bad flag was reported")

    monkeypatch.setattr(cli, "make_env", fail)


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize(("algo", "flag", "value", "allowed"), CASES)
def test_a_count_out_of_range_is_one_line_before_anything_is_built(algo, flag, value, allowed, tmp_path, capsys,
                                                                   no_env):  # fmt: skip
    out = tmp_path / "runs"
    assert CLIS[algo](["--env", "brax:fast", "--out", str(out), flag, value]) == 2
    assert one_line(capsys) == f"error: {flag} {value} is out of range; allowed {allowed}"
    assert not out.exists()


@pytest.mark.parametrize("spelling", [["--eval_episodes", "-5"], ["--eval-episodes=-5"], ["--eval_episodes=-5"]])
def test_every_spelling_that_tyro_takes_is_checked(spelling, capsys, no_env):
    assert ppo.main(["--env", "brax:fast", *spelling]) == 2
    assert one_line(capsys) == "error: --eval-episodes -5 is out of range; allowed >= 1"


def test_process_id_must_be_below_the_process_count(capsys, no_env):
    assert ppo.main(["--num-processes", "2", "--process-id", "2"]) == 2
    assert one_line(capsys) == "error: --process-id 2 is out of range; allowed [0, 1] (--num-processes 2)"
    assert td3.main(["--seed", str(2**32 - 2), "--seeds", "3"]) == 2  # seed 2**32 would be seed 0's key again
    allowed = f"allowed seed + seeds - 1 <= {2**32 - 1}"
    assert one_line(capsys) == f"error: --seed {2**32 - 2} with --seeds 3 is out of range; {allowed}"


def test_too_many_devices_names_the_flag_and_the_device_count(tmp_path, capsys):
    n = jax.device_count()
    assert ppo.main(["--env", "brax:fast", "--out", str(tmp_path / "runs"), "--devices", str(n + 1)]) == 2
    assert one_line(capsys) == f"error: --devices {n + 1} is out of range; allowed [0, {n}] (0: every device)"
    assert not (tmp_path / "runs").exists()


def test_warp_physics_over_several_devices_is_one_line_naming_devices():
    check_backend_devices({"impl": "warp"}, 1)
    check_backend_devices({"impl": "jax", "mode": "pd"}, 4)
    with pytest.raises(ValueError, match=r"^--env-config impl=warp runs its lanes on one device; add --devices 1 "
                                         r"\(the lanes would be spread over 2\)$"):  # fmt: skip
        check_backend_devices({"impl": "warp", "mode": "pd"}, 2)


@pytest.mark.parametrize(
    ("algo", "argv", "message"),
    [
        ("ppo", ["--clip-eps", "2"], "--clip-eps: clip_eps=2.0 is out of range; allowed (0, 1)"),
        ("a2c", ["--num-envs", "0"], "--num-envs: num_envs=0 is out of range; allowed [1, inf]"),
        ("a3c", ["--unroll-length", "-3"], "--unroll-length: unroll_length=-3 is out of range; allowed [1, inf]"),
        ("ddpg", ["--batch-size", "0"], "--batch-size: batch_size=0 is out of range; allowed [1, inf]"),
        ("td3", ["--policy-delay", "0"], "--policy-delay: policy_delay=0 is out of range; allowed [1, inf]"),
    ],
)
def test_a_bad_hyper_parameter_names_its_flag_before_the_run_env_is_built(algo, argv, message, tmp_path, capsys,
                                                                          monkeypatch):  # fmt: skip
    built = []
    make_env = cli.make_env
    monkeypatch.setattr(cli, "make_env", lambda name, overrides: built.append(name) or make_env(name, overrides))
    out = tmp_path / "runs"
    assert CLIS[algo](["--env", "brax:fast", "--out", str(out), *argv]) == 2
    assert one_line(capsys) == f"error: {message}"
    assert built == ["brax:fast"]  # the preset's env (its defaults), not the run's
    assert not out.exists()


def test_a_resumed_config_with_a_bad_count_names_the_file(tmp_path, capsys, no_env):
    run_dir = tmp_path / "ppo-brax_fast-old"
    run_dir.mkdir()
    saved = {"algo": "ppo", "args": {"env": "brax:fast", "chunks": 0}, "ppo": {}}
    (run_dir / "config.json").write_text(json.dumps(saved))
    assert ppo.main(["--resume", str(run_dir)]) == 2
    assert one_line(capsys) == f"error: --resume {run_dir}: config.json: --chunks 0 is out of range; allowed >= 1"
    assert sorted(os.listdir(run_dir)) == ["config.json"]


def test_run_checks_a_spec_made_by_hand(tmp_path):
    trainer = Trainer(init=lambda key: {}, update=lambda s: (s, {}), policy=lambda s: None, num_updates=1,
                      env_steps_per_update=1)  # fmt: skip
    spec = RunSpec(algo="fake", env_name="none", env=None, trainer=trainer, config={}, out=str(tmp_path / "r"),
                          checkpoint_every=0)  # fmt: skip
    with pytest.raises(ValueError, match=r"^--checkpoint-every 0 is out of range; allowed >= 1$"):
        run(spec)
    assert not (tmp_path / "r").exists()
    with pytest.raises(ValueError, match=r"^--chunks 0 is out of range; allowed >= 1$"):
        iterations_per_chunk(10, 0)
    assert iterations_per_chunk(10, 3) == 4 and iterations_per_chunk(2, 5) == 1


@pytest.mark.parametrize(
    ("module", "argv", "message"),
    [
        ("brax_tasks", ["--seeds", "0"], "argument --seeds: 0 is out of range; allowed >= 1"),
        ("brax_tasks", ["--evals", "1"], "argument --evals: 1 is out of range; allowed >= 2"),
        ("racing", ["--laps", "-2"], "argument --laps: -2 is out of range; allowed >= 1"),
        ("replay_throughput", ["--branchings", "8", "1"], "argument --branchings: 1 is out of range; allowed >= 2"),
        ("scaling", ["--lane-group", "-1"], "argument --lane-group: -1 is out of range; allowed >= 0"),
        ("thesis", ["--jobs", "0"], "argument --jobs: 0 is out of range; allowed >= 1"),
        ("ppo_tracking", ["--seeds", "0"], "argument --seeds: 0 is out of range; allowed >= 1"),
        ("train_throughput", ["--repeats", "two"], "argument --repeats: 'two' is not an integer"),
    ],
)
def test_benchmark_counts_are_checked_as_they_are_parsed(module, argv, message, capsys):
    main = importlib.import_module(f"benchmarks.{module}").main
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(f"error: {message}")


# ---- a run over two processes that loses one ----------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    """The hyper-parameters of a stand-in algorithm: ``lanes`` counters, each chunk adds 1 to each."""

    lanes: int = 4
    episode_length: int = 0

    def replace(self, **changes) -> "ToyConfig":
        return dataclasses.replace(self, **changes)

    def validate(self) -> "ToyConfig":
        check_range("lanes", self.lanes, 1)
        return self


@dataclasses.dataclass
class ToyArgs(RunOptions):
    """A stand-in algorithm."""

    toy: Annotated[ToyConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(default_factory=ToyConfig)


def toy_trainer(args, env, cfg, mesh):
    """``--chunks`` chunks; each adds 1 to every lane (split over the mesh, so over both processes) and
    reports their mean: an all-reduce across the processes."""
    split = parallel.lane_sharding(mesh)

    def init(key):
        return {"count": jnp.zeros((), jnp.int32), "w": jax.lax.with_sharding_constraint(jnp.zeros(cfg.lanes), split)}

    def update(state):
        w = jax.lax.with_sharding_constraint(state["w"] + 1.0, split)
        return {"count": state["count"] + 1, "w": w}, {"mean_w": jnp.mean(w)}

    policy = lambda state: (lambda obs: jnp.zeros(env.action_size))  # noqa: E731
    return Trainer(init=init, update=update, policy=policy, num_updates=args.chunks, env_steps_per_update=cfg.lanes), 1


TOY = AlgorithmCLI(name="toy", args_type=ToyArgs, config_type=ToyConfig, preset=lambda args, env: ToyConfig(),
                   make_trainer=toy_trainer)  # fmt: skip


def test_the_command_line_builds_its_env_once_and_again_only_for_other_settings(monkeypatch):
    """``parse`` builds the env it reads the preset's defaults from and ``build`` takes it; where the run's env
    settings differ from those (here: a field of the config the preset chose), ``build`` makes the run's own."""
    built = []
    make_env = cli.make_env
    monkeypatch.setattr(cli, "make_env", lambda name, changes: built.append(dict(changes)) or make_env(name, changes))
    args, first = ppo.CLI.parse_with_env(["--env", "brax:fast"])
    env, _, _ = ppo.CLI.build(args, first)
    assert len(built) == 1 and env is first.env
    varying = dataclasses.replace(TOY, preset=lambda args, env: ToyConfig(lanes=8),
                                  env_settings=lambda args: {"lanes": args.toy.lanes})  # fmt: skip
    built.clear()
    args, first = varying.parse_with_env(["--env", "brax:fast"])
    env, _, _ = varying.build(args, first)
    assert built == [{"lanes": 4}, {"lanes": 8}] and env is not first.env
    assert BuiltEnv("brax:fast", {"x": 1, "y": "a"}, None).fits("brax:fast", {"y": "a", "x": 1})
    assert not BuiltEnv("brax:fast", {"x": 1}, None).fits("brax:fast", {"x": True})  # 1 is not True
    assert not BuiltEnv("brax:fast", {}, None).fits("brax:hopper", {})


@pytest.mark.parametrize(("argv", "devices"), [([], 0), (["--devices", "3"], 3), (["--devices=2"], 2)])
def test_the_preset_sees_the_devices_of_the_command_line(argv, devices):
    """A preset may scale with ``--devices`` (PPO's fast preset on arm7): the options it gets hold them."""
    seen = []
    cli_ = dataclasses.replace(TOY, preset=lambda args, env: seen.append(args.devices) or ToyConfig())
    assert cli_.parse(["--env", "brax:fast", *argv]).devices == devices and seen == [devices]

# Process 1 says when its first chunk is saved, then waits to be killed.
TOY_MAIN = textwrap.dedent(
    """
    import sys, time
    from tests.cli.test_arguments import TOY
    from train import run

    class SaysWhenSaved(run.Checkpointer):
        def save(self, step, *args, **kwargs):
            super().save(step, *args, **kwargs)
            if step == 1 and sys.argv[-1] == "1":
                print("chunk 1 saved", flush=True)
                time.sleep(600)

    run.Checkpointer = SaysWhenSaved
    sys.exit(TOY.main(sys.argv[1:]))
    """
)
LIMIT_S = 240
GLOO_ERROR = ("UNKNOWN: Gloo AllGather failed: [external/gloo/gloo/transport/tcp/pair.cc:547] Connection closed by "
              "peer [127.0.0.1]:46474\nmore detail")  # fmt: skip


def test_a_collective_that_lost_its_peer_is_told_from_other_errors(monkeypatch):
    lost = jax.errors.JaxRuntimeError(GLOO_ERROR)
    assert parallel.lost_peer(lost) is None  # one process: nothing to lose
    monkeypatch.setattr(jax, "process_count", lambda: 2)
    expected = "process 1 of 2 stopped responding (Gloo AllGather failed: Connection closed by peer)"
    assert parallel.lost_peer(lost) == expected
    try:  # found also behind the error it caused
        raise RuntimeError("sync failed") from lost
    except RuntimeError as e:
        assert parallel.lost_peer(e) == expected
    assert parallel.lost_peer(jax.errors.JaxRuntimeError("RESOURCE_EXHAUSTED: Out of memory")) is None
    assert parallel.lost_peer(ValueError("Connection reset by peer")) is None  # not the runtime's
    monkeypatch.setattr(jax, "process_count", lambda: 4)
    assert parallel.lost_peer(lost).startswith("one of the 4 processes stopped responding (Gloo")


@pytest.mark.parametrize(
    ("raised", "line"),
    [
        (PeerLostError("process 1 of 2 stopped responding (x); the run can be resumed with --resume D"),
         "error: process 1 of 2 stopped responding (x); the run can be resumed with --resume D"),
        (jax.errors.JaxRuntimeError(GLOO_ERROR),
         "error: process 1 of 2 stopped responding (Gloo AllGather failed: Connection closed by peer) as the run "
         "began; start it again"),
    ],
)  # fmt: skip
def test_the_command_line_ends_at_once_on_a_lost_peer(raised, line, monkeypatch, tmp_path):
    def run(spec):
        monkeypatch.setattr(jax, "process_count", lambda: 2)
        raise raised

    def exit_at_once(code, message=""):
        raise SystemExit((code, message))

    monkeypatch.setattr(cli, "run", run)
    monkeypatch.setattr(parallel, "exit_at_once", exit_at_once)
    with pytest.raises(SystemExit) as ended:
        TOY.main(["--env", "brax:fast", "--out", str(tmp_path)])
    assert ended.value.code == (1, line)


def _lines(stream, into: queue.Queue) -> None:
    for line in stream:
        into.put(line)
    into.put(None)


def test_a_dead_peer_ends_the_survivor_with_one_line_at_once(tmp_path):
    env = cpu_env(devices=2, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cache"))
    for k in list(env):
        if k.startswith(("SLURM_", "OMPI_", "PMI_")) or k in ("JAX_COORDINATOR_ADDRESS", "KUBERNETES_SERVICE_HOST"):
            del env[k]
    out = tmp_path / "runs"
    argv = ["--env", "brax:fast", "--chunks", "20", "--checkpoint-every", "1", "--eval-episodes", "1",
            "--progress", "False", "--out", str(out), "--coordinator", f"localhost:{_free_port()}",
            "--num-processes", "2", "--process-id"]  # fmt: skip
    procs = [
        subprocess.Popen([sys.executable, "-c", TOY_MAIN, *argv, str(i)], cwd=ROOT, env=env, text=True,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
        for i in (0, 1)
    ]
    try:
        said: queue.Queue = queue.Queue()
        threading.Thread(target=_lines, args=(procs[1].stdout, said), daemon=True).start()
        deadline = time.monotonic() + LIMIT_S
        while (line := said.get(timeout=max(1.0, deadline - time.monotonic()))) != "chunk 1 saved\n":
            assert line is not None, f"process 1 ended before its first chunk:\n{procs[1].stderr.read()[-3000:]}"
        procs[1].kill()
        killed = time.monotonic()
        _, err = procs[0].communicate(timeout=120)
        after_s = time.monotonic() - killed
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
            proc.communicate()
    (run_dir,) = glob.glob(str(out / "toy-brax_fast-*"))
    assert procs[0].returncode == 1, err[-3000:]
    # one line, from the watch of the connections or from the collective that failed (gloo's words,
    # without its source location and address), whichever came first
    (line,) = err.strip().splitlines()
    assert re.fullmatch(r"error: process 1 of 2 stopped responding \((its connection closed|Gloo [^\[\]]+)\); "
                        f"the run can be resumed with --resume {re.escape(run_dir)}", line), line  # fmt: skip
    assert after_s < 20, after_s  # without the watch: ~90 s, then an abort from C++ with a long trace
    assert os.path.isdir(os.path.join(run_dir, "checkpoints", "1"))
