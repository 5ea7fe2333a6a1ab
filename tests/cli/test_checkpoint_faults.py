"""``python -m train.<algo> --resume`` under faults: a damaged newest checkpoint, no good checkpoint, a second
writer, an edited ``config.json`` and a full disk. Each is one line on stderr with its exit code, and nothing
good is lost.

The command is :func:`train.cli.cli_main` of a stand-in algorithm (``count``: a trainer of a few jitted
array operations, its state shaped by ``num_envs``) in this process: the parsing, ``config.json``, run
directory, checkpoints and resume are those of every algorithm, without compiling one (a tiny PPO run
compiles for half a minute on two cores). One run is made per module and copied for each test.
"""

import dataclasses
import errno
import glob
import json
import os
import re
import shutil
from typing import Annotated

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import pytest
import tyro

from jaxrl_robot.checkpoint import CHECKSUMS, Checkpointer, DirectoryLock
from jaxrl_robot.types import Trainer
from tests.test_checkpoint import array_file, flip_bytes, truncate
from train.cli import AlgorithmCLI, cli_main
from train.options import RunOptions


@dataclasses.dataclass(frozen=True)
class CountConfig:
    """The stand-in algorithm's hyper-parameters: ``num_envs`` lanes, ``updates`` chunks of 10 steps a lane."""

    num_envs: int = 4
    updates: int = 4
    episode_length: int = 0

    def replace(self, **changes):
        return dataclasses.replace(self, **changes)

    def validate(self):
        if self.num_envs < 1:
            raise ValueError(f"num_envs={self.num_envs} is out of range; allowed >= 1")
        return self


@dataclasses.dataclass
class CountArgs(RunOptions):
    count: Annotated[CountConfig, tyro.conf.OmitArgPrefixes] = dataclasses.field(default_factory=CountConfig)


def make_count_trainer(args, env, cfg, mesh):
    """State ``{"env_state": {"obs": [num_envs, 3]}, "params": {"w": [3, 3]}, "key", "count"}``; each chunk
    a random step of the observations and a matrix product."""

    def init(key):
        k1, k2 = jax.random.split(key)
        return {"env_state": {"obs": jax.random.normal(k1, (cfg.num_envs, 3))},
                "params": {"w": jax.random.normal(k2, (3, 3))}, "key": key, "count": jnp.int32(0)}  # fmt: skip

    def update(state):
        key, sub = jax.random.split(state["key"])
        obs = jnp.tanh(state["env_state"]["obs"] @ state["params"]["w"]) + jax.random.normal(sub, (cfg.num_envs, 3))
        w = state["params"]["w"] - 0.01 * obs.T @ obs / cfg.num_envs
        new = {"env_state": {"obs": obs}, "params": {"w": w}, "key": key, "count": state["count"] + 1}
        return new, {"critic_loss": jnp.mean(obs**2)}

    trainer = Trainer(init=init, update=update, policy=lambda state: (lambda obs: obs), num_updates=cfg.updates,
                      env_steps_per_update=10 * cfg.num_envs)  # fmt: skip
    return trainer, 1


COUNT = AlgorithmCLI(name="count", args_type=CountArgs, config_type=CountConfig,
                     preset=lambda args, env: CountConfig(), make_trainer=make_count_trainer)  # fmt: skip


def main(argv):
    return cli_main(COUNT, argv)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A run of 4 chunks of 40 env steps stopped after chunk 2: checkpoints 1 and 2."""
    out = tmp_path_factory.mktemp("runs")
    assert main(["--env", "brax:fast", "--checkpoint-every", "1", "--out", str(out), "--stop-after-steps", "80"]) == 0
    (run,) = glob.glob(str(out / "count-*"))
    assert sorted(os.listdir(os.path.join(run, "checkpoints"))) == ["1", "2"]
    return run


@pytest.fixture
def run_dir(tiny_run, tmp_path):
    """A copy of the tiny run, to damage."""
    return shutil.copytree(tiny_run, str(tmp_path / "run"))


def resume(run, capfd, *more):
    """``(exit code, stdout, stderr lines)`` of ``--resume run``."""
    capfd.readouterr()
    code = main(["--resume", run, *more])
    out, err = capfd.readouterr()
    return code, out, err.strip().splitlines()


def snapshot(run):
    """The bytes of every file under ``run/checkpoints`` (to show that nothing was touched)."""
    root = os.path.join(run, "checkpoints")
    return {os.path.relpath(os.path.join(r, n), root): open(os.path.join(r, n), "rb").read()
            for r, _, names in os.walk(root) for n in names}  # fmt: skip


def assert_unlocked(run):
    DirectoryLock(run).acquire().release()


def test_damaged_newest_checkpoint_resumes_from_the_previous_one(tiny_run, run_dir, capfd):
    path = array_file(os.path.join(run_dir, "checkpoints"), 2)
    size = os.path.getsize(path)
    truncate(path)
    name = os.path.relpath(path, os.path.join(run_dir, "checkpoints", "2"))
    code, out, err = resume(run_dir, capfd, "--stop-after-steps", "80")
    assert code == 0
    assert err == [f"checkpoint 2 is damaged ({name} has {size // 2} bytes, {size} were written); resuming from 1"]
    assert "resumed at chunk 1 (40 env steps)" in out
    assert os.path.isfile(os.path.join(run_dir, "checkpoints.damaged", "2", name))  # kept aside
    # chunk 2 again from checkpoint 1: the checkpoint of the undamaged run, to the bit
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    assert ckpt.all_steps() == [1, 2] and ckpt.verify(2)
    again, record = ckpt.restore(2)
    reference, _ = Checkpointer(os.path.join(tiny_run, "checkpoints")).restore(2)
    assert record["chunk"] == 2
    assert jax.tree.structure(again) == jax.tree.structure(reference)
    for a, b in zip(jax.tree.leaves(again), jax.tree.leaves(reference), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert_unlocked(run_dir)


def test_no_good_checkpoint_is_one_line_and_exit_2(run_dir, capfd):
    for step in (1, 2):
        flip_bytes(array_file(os.path.join(run_dir, "checkpoints"), step))
    before = snapshot(run_dir)
    code, _, err = resume(run_dir, capfd)
    assert code == 2 and len(err) == 1
    assert err[0].startswith(f"error: no usable checkpoint in {run_dir}/checkpoints: checkpoint 2 is damaged (state/")
    assert err[0].endswith(" does not match its SHA-256)") and err[0].count("does not match its SHA-256") == 2
    assert snapshot(run_dir) == before and not os.path.exists(os.path.join(run_dir, "checkpoints.damaged"))
    assert_unlocked(run_dir)


def test_a_second_writer_of_the_run_directory_stops_at_once(run_dir, capfd):
    before = snapshot(run_dir)
    metrics = open(os.path.join(run_dir, "metrics.csv")).read()
    with DirectoryLock(run_dir):  # another process's run, as far as the command can tell
        code, _, err = resume(run_dir, capfd)
    assert code == 2
    assert err == [f"error: run directory {run_dir} is in use by another process (pid {os.getpid()})"]
    assert snapshot(run_dir) == before and open(os.path.join(run_dir, "metrics.csv")).read() == metrics


def test_config_json_that_no_longer_builds_the_saved_state_names_the_arrays_and_fields(run_dir, capfd):
    path = os.path.join(run_dir, "config.json")
    config = json.load(open(path))
    assert config["count"]["num_envs"] == 4
    config["count"]["num_envs"] = 8
    json.dump(config, open(path, "w"))
    before = snapshot(run_dir)
    code, _, err = resume(run_dir, capfd)
    assert code == 2 and len(err) == 1
    assert err == [f"error: --resume {run_dir}: config.json does not match checkpoint 2: env_state.obs has shape "
                   "(4, 3) saved, (8, 3) now (config.json changed since: count.num_envs 4 then, 8 now)"]
    assert snapshot(run_dir) == before
    assert_unlocked(run_dir)


def test_disk_full_while_checkpointing_keeps_the_earlier_checkpoints(run_dir, capfd, monkeypatch):
    async def no_space(*args, **kwargs):  # orbax writing the record of the checkpoint: the disk is full
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(ocp.JsonCheckpointHandler, "_save_fn", no_space)
    root = os.path.join(run_dir, "checkpoints")
    before = snapshot(run_dir)
    code, out, err = resume(run_dir, capfd, "--stop-after-steps", "120")
    assert code == 1 and "resumed at chunk 2" in out and len(err) == 1
    expected = (rf"error: cannot write checkpoint 3 to {re.escape(root)}: No space left on device \(checkpoint 2 took "
                r"[\d.]+ kB, [\d.]+ [kM]B free\); the partial checkpoint is removed, earlier ones are intact")
    assert re.fullmatch(expected, err[0]), err[0]
    assert snapshot(run_dir) == before  # checkpoint 3 left nothing; 1 and 2 as they were
    assert all(Checkpointer(root).verify(step) for step in (1, 2))
    assert all(os.path.isfile(os.path.join(root, str(step), CHECKSUMS)) for step in (1, 2))
    assert_unlocked(run_dir)
