"""``jaxrl_robot.load_policy``: the trained policy of every algorithm's run directory (recurrent and batch-norm
included) against an oracle — the trainer's own ``policy(state)`` of the state the run reached, computed
without any checkpoint (``tests/run_dirs.py``) — and one-line errors for what a user can get wrong."""

import json
import os
import shutil

import jax
import numpy as np
import pytest

from jaxrl_robot import runs
from jaxrl_robot.checkpoint import CheckpointDamagedError, CheckpointMismatchError
from jaxrl_robot.types import RecurrentPolicy
from tests.run_dirs import make_run, state_after
from train import a2c as a2c_cli
from train import algorithms
from train import ddpg as ddpg_cli
from train import ppo as ppo_cli
from train import sac as sac_cli
from train import td3 as td3_cli
from train.runs import cli_of

BRAX_FAST = ["--env", "brax:fast", "--episode-length", "8", "--total-steps", "256", "--chunks", "2"]
PPO = [*BRAX_FAST, "--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16", "--actor-hidden", "8",
       "--critic-hidden", "8"]  # fmt: skip
OFF_POLICY = [*BRAX_FAST, "--num-envs", "4", "--batch-size", "16", "--actor-hidden", "8", "--critic-hidden", "8"]
A2C = [*BRAX_FAST, "--num-envs", "4", "--unroll-length", "8", "--actor-hidden", "8", "--critic-hidden", "8"]

VARIANTS = {  # PPO with an MLP and no batch-norm: ppo_run
    "ppo-batch-norm": (ppo_cli.CLI, [*PPO, "--batch-norm"]),
    "ppo-lstm": (ppo_cli.CLI, [*PPO, "--policy", "lstm", "--lstm-size", "8", "--seq-length", "4", "--no-batch-norm"]),
    "a2c": (a2c_cli.CLIS["a2c"], A2C),
    "a3c": (a2c_cli.CLIS["a3c"], A2C),
    "ddpg": (ddpg_cli.CLI, OFF_POLICY),
    "td3": (td3_cli.CLI, OFF_POLICY),
    "sac": (sac_cli.CLI, OFF_POLICY),
}

OBS = np.random.default_rng(0).normal(size=(5, 2)).astype(np.float32)  # brax:fast observes [2]


def actions(policy, obs):
    """Actions of a policy over ``obs [T, D]``: one batch for a memoryless one, step by step (one episode)
    carrying the memory for a recurrent one."""
    if not isinstance(policy, RecurrentPolicy):
        return np.asarray(policy(obs))
    carry, out, step = policy.carry, [], jax.jit(policy.step)
    for o in obs:
        carry, a = step(carry, o)
        out.append(np.asarray(a))
    return np.stack(out)


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    """A PPO run of seeds 4 and 5, two chunks with a checkpoint after each: ``(run dir, trainer)``."""
    argv = [*PPO, "--no-batch-norm", "--seed", "4", "--seeds", "2"]
    run_dir, _, _, trainer = make_run(str(tmp_path_factory.mktemp("runs")), ppo_cli.CLI, argv, checkpoint_every=1)
    return run_dir, trainer


def assert_acts_as(policy, expected):
    """``policy`` (loaded) takes ``expected``'s actions on :data:`OBS` (a batch, and one observation alone)."""
    want = actions(expected, OBS)
    np.testing.assert_allclose(actions(policy, OBS), want, rtol=1e-5, atol=1e-6)
    if not isinstance(policy, RecurrentPolicy):  # one observation [D] -> one action [A]
        np.testing.assert_allclose(np.asarray(policy(OBS[0])), want[0], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("variant", ["ppo", *VARIANTS])
def test_load_policy_acts_as_the_trainers_policy_of_the_checkpointed_state(tmp_path, variant, ppo_run):
    if variant == "ppo":
        (run_dir, trainer), seed, chunks = ppo_run, 4, 2
    else:
        cli, argv = VARIANTS[variant]
        run_dir, _, _, trainer = make_run(str(tmp_path), cli, [*argv, "--seed", "3"], stop_after_steps=1)
        seed, chunks = 3, 1
    policy, env = runs.load_policy(run_dir, seed=seed)
    assert isinstance(policy, RecurrentPolicy) == (variant == "ppo-lstm")
    assert env.observation_size == OBS.shape[1] and env.action_size == 1
    expected = trainer.policy(state_after(trainer, seed, chunks))
    assert_acts_as(policy, expected)
    # the checkpoint's state, not a fresh one: the untrained policy acts otherwise
    fresh = trainer.policy(state_after(trainer, seed, 0))
    assert not np.allclose(actions(fresh, OBS), actions(expected, OBS), atol=1e-4)


def test_step_chooses_the_checkpoint_and_a_damaged_newest_one_falls_back_leaving_it_in_place(tmp_path, ppo_run):
    run_dir, trainer = ppo_run
    first = trainer.policy(state_after(trainer, 5, 1))
    assert_acts_as(runs.load_policy(run_dir, step=1, seed=5)[0], first)
    copy = str(tmp_path / "copy")
    shutil.copytree(run_dir, copy)
    damaged = _damage(os.path.join(copy, "checkpoints", "2"))
    with pytest.warns(UserWarning, match=r"checkpoint 2 is damaged .*; resuming from 1"):
        policy, _ = runs.load_policy(copy, seed=5)
    assert_acts_as(policy, first)
    assert os.path.isfile(damaged) and not os.path.exists(os.path.join(copy, "checkpoints.damaged"))
    with pytest.raises(CheckpointDamagedError, match=r"^checkpoint 2 is damaged"):
        runs.load_policy(copy, step=2, seed=5)
    _damage(os.path.join(copy, "checkpoints", "1"))
    with pytest.raises(CheckpointDamagedError, match=r"^no usable checkpoint in .*checkpoints: checkpoint 2 is"):
        runs.load_policy(copy, seed=5)


def _damage(step_dir: str) -> str:
    """Flip the last byte of the largest file of a checkpoint; returns its path."""
    files = [os.path.join(r, n) for r, _, names in os.walk(step_dir) for n in names if n != "checksums.json"]
    path = max(files, key=os.path.getsize)
    with open(path, "r+b") as f:
        f.seek(-1, os.SEEK_END)
        last = f.read(1)
        f.seek(-1, os.SEEK_END)
        f.write(bytes([last[0] ^ 0xFF]))
    return path


def test_a_run_of_several_seeds_needs_one_chosen(ppo_run):
    run_dir, trainer = ppo_run
    with pytest.raises(runs.RunLoadError, match=r"a run of seeds 4, 5; choose one with seed= \(or load .*seed4\)$"):
        runs.load_policy(run_dir)
    with pytest.raises(runs.RunLoadError, match=r"seed 7 was not trained; valid: 4, 5$"):
        runs.load_policy(run_dir, seed=7)
    for k in (4, 5):  # seed k's state is the one a run of --seed k reaches; its folder stands for it
        policy, _ = runs.load_policy(os.path.join(run_dir, f"seed{k}"))
        assert_acts_as(policy, trainer.policy(state_after(trainer, k, 2)))
    with pytest.raises(runs.RunLoadError, match=r"the folder of seed 5, but seed=4 was asked for$"):
        runs.load_policy(os.path.join(run_dir, "seed5"), seed=4)
    run = runs.load_run(run_dir)
    assert sorted(run.states) == [4, 5] and run.step == 2 and run.env_steps == 256


def test_a_runs_algorithm_is_a_train_module_with_a_cli():
    """The algorithms are found, not listed: the ``train`` modules that define ``CLI`` (not ``train.eval``,
    ``train.cli``, …); a run's is rebuilt by that ``CLI``; an unknown one is a one-line error naming them."""
    assert algorithms() == ("a2c", "a3c", "ddpg", "ppo", "sac", "td3")
    assert [cli_of(a).name for a in algorithms()] == list(algorithms())
    assert cli_of("sac") is sac_cli.CLI and cli_of("a3c") is a2c_cli.CLIS["a3c"]
    with pytest.raises(runs.RunLoadError, match=r"^unknown algorithm 'dqn' in config.json; valid: a2c, a3c, ddpg, "
                                                r"ppo, sac, td3$"):  # fmt: skip
        cli_of("dqn")


def test_what_is_no_loadable_run_is_a_one_line_error(tmp_path, ppo_run):
    run_dir, _ = ppo_run
    cases = [(str(tmp_path / "nowhere"), r"nowhere: no such directory$"),
             (str(tmp_path), r": not a run directory \(no config.json\)$")]  # fmt: skip
    stopped = tmp_path / "stopped"  # the config of a run stopped before its first checkpoint
    stopped.mkdir()
    shutil.copy(os.path.join(run_dir, "config.json"), stopped)
    cases.append((str(stopped / "seed4"), r"seed4: no such directory$"))
    cases.append((str(stopped), r"stopped: no checkpoint yet \(the run stopped before its first one\)$"))
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text(json.dumps({"algo": "dqn", "args": {}}))
    cases.append((str(other), r"^no run loader for algorithm 'dqn' \(jaxrl_robot.runs entry points; registered: "
                              r"a2c, a3c, ddpg, ppo, sac, td3\)$"))  # fmt: skip
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "config.json").write_text("{")
    cases.append((str(broken), r"broken: config.json cannot be read \("))
    for path, message in cases:
        with pytest.raises(runs.RunLoadError, match=message) as info:
            runs.load_policy(path, seed=4 if path == str(stopped) else None)
        assert "\n" not in str(info.value)
    with pytest.raises(runs.RunLoadError, match=r": no checkpoint 9; saved: 1, 2$"):
        runs.load_policy(run_dir, step=9, seed=4)
    edited = tmp_path / "edited"  # config.json changed after the checkpoints were written
    shutil.copytree(run_dir, edited)
    config = json.loads((edited / "config.json").read_text())
    config["ppo"]["num_envs"] = 8
    (edited / "config.json").write_text(json.dumps(config))
    message = (r"edited: config.json does not match checkpoint 2: 0\.env_state\..* has shape \(4, 1\) saved, \(8, 1\) "
               r"now;.* \(config.json changed since: ppo.num_envs 4 then, 8 now\)$")
    with pytest.raises(CheckpointMismatchError, match=message):
        runs.load_policy(str(edited), seed=4)
    assert not os.path.exists(stopped / "checkpoints")  # looking did not make the folder
