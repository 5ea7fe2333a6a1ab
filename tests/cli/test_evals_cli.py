"""``--evals N``: evaluations during training, one row each in ``evals.csv``, of the states after the chunks
:mod:`train.periodic` names with the keys it derives; their time kept off the training clock; a resumed run
repeats no row; tracking envs compile their program once.

The runs are ``train.run.run`` of the CLI's own env, trainer and config with ``tests.run_dirs.shift_by``
as the update (no learning step compiled): the state after ``c`` chunks is known without a checkpoint
(:func:`tests.run_dirs.state_after`), an oracle for each row.
"""

import json
import os
import time
import types

import jax
import numpy as np
import pytest

from envs_mjx import tracking
from jaxrl_robot.checkpoint import Checkpointer
from jaxrl_robot.evaluation import evaluation_key
from jaxrl_robot.types import as_recurrent
from tests.run_dirs import shift_by, state_after
from tests.subproc import cache_every_program
from train import evaluations, periodic
from train import ppo as ppo_cli
from train import run as run_module
from train.envs import make_env
from train.evaluations import compile_evaluation_async, compiled_program
from train.options import RunSpec, settings_of

RUN = ["--env", "arm7", "--episode-length", "4", "--total-steps", "256", "--chunks", "4", "--eval-episodes", "4",
       "--no-precision", "--seed", "5", "--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16",
       "--actor-hidden", "8", "--critic-hidden", "8", "--no-batch-norm", "--evals", "3"]  # fmt: skip
OFFSET = 0.3  # each chunk moves the parameters this far: the policy pushes the arm hard in one direction
FIGURES = ("episodes", "mean_return", "mean_length", "successes", "mean_final_distance")
EVAL_COST = 1000.0  # seconds each evaluation seems to take on the run's clock (test_evaluation_time_...)


def shifted_run(argv=None, resume=None, policy_calls=None, **settings):
    """``train.run.run`` of ``python -m train.ppo argv`` (or ``--resume resume``) with :func:`shift_by`'s update;
    ``policy_calls``: a list that gets one entry per call of the trainer's ``policy``. Returns
    ``(result, trainer)`` (the trainer as the CLI built it). The runs of the same env compile the same programs:
    the later ones load them from the persistent compilation cache."""
    args = ppo_cli.parse(["--resume", resume] if resume else argv)
    env, trainer, config = ppo_cli.build(args)
    run_trainer = trainer._replace(update=shift_by(OFFSET))
    if policy_calls is not None:
        run_trainer = run_trainer._replace(policy=lambda s: policy_calls.append(1) or trainer.policy(s))
    spec = RunSpec(
        algo="ppo", env_name=args.env, env=env, trainer=run_trainer, config=config, run_dir=resume,
        episode_length=int(config["ppo"]["episode_length"]), **{**settings_of(args), "progress": False,
                                                                **settings},
    )  # fmt: skip
    with cache_every_program():
        return run_module.run(spec), trainer


def rows_of(run_dir):
    return periodic.read_evals(os.path.join(run_dir, periodic.EVALS_FILE))


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """An arm7 run of 4 chunks with ``--evals 3`` (evaluations after chunks 2, 3 and 4), stopped after chunk 2 and
    resumed, each evaluation made to seem ``EVAL_COST`` s long on the run's clock; before the resume a row of
    chunk 3 is added to ``evals.csv`` as if that chunk had been evaluated and the process had stopped before its
    checkpoint. Returns ``(run dir, result of the resumed process, trainer, env, evals.csv as first written)``."""
    extra = [0.0]
    fake_time = types.SimpleNamespace(perf_counter=lambda: time.perf_counter() + extra[0], strftime=time.strftime)
    real_evaluate_state = evaluations.evaluate_state

    def slow_evaluate_state(*args, **kwargs):
        out = real_evaluate_state(*args, **kwargs)
        extra[0] += EVAL_COST
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(run_module, "time", fake_time)
        mp.setattr(evaluations, "evaluate_state", slow_evaluate_state)
        out = str(tmp_path_factory.mktemp("runs"))
        first, trainer = shifted_run([*RUN, "--out", out], checkpoint_every=1, stop_after_steps=128)
        path = os.path.join(first["run_dir"], periodic.EVALS_FILE)
        assert not first["finished"] and [r["chunk"] for r in periodic.read_evals(path)] == ["2"]
        with open(path) as f:
            written = f.read()
        with open(path, "a") as f:  # evaluated after the last checkpoint, then stopped
            f.write("3,192,9.0,9.0,0.1,1.0,1.0,4.0,-99.0,4.0,0.0,9.0\n")
        result, _ = shifted_run(resume=first["run_dir"])
    env = make_env("arm7", ppo_cli.env_settings(ppo_cli.parse(RUN)))
    return first["run_dir"], result, trainer, env, written


def test_rows_are_the_evaluations_of_the_states_after_their_chunks_with_the_derived_keys(evaluated):
    """The oracle of each row: the final evaluation's program (``tests/cli/test_eval_cli.py`` checks it against
    ``run_test_episodes``) on the state after the row's chunk, with the key ``fold_in(evaluation key, chunk)``;
    the last row is the final evaluation itself."""
    run_dir, result, trainer, env, _ = evaluated
    rows = rows_of(run_dir)
    assert result["finished"] and [int(r["chunk"]) for r in rows] == [2, 3, 4]  # ceil(i * 4 / 3), i = 1, 2, 3
    assert [int(r["env_steps"]) for r in rows] == [128, 192, 256]
    with open(os.path.join(run_dir, "eval.json")) as f:
        final = json.load(f)
    for key in FIGURES:
        assert float(rows[-1][key]) == final[key], key
    config = {"args": {}}
    spec = RunSpec(algo="ppo", env_name="arm7", env=env, trainer=trainer, config=config, episode_length=4,
                          eval_episodes=4, precision=False)  # fmt: skip
    states = {c: state_after(trainer, 5, c, OFFSET) for c in (2, 3)}
    compiled = compiled_program(compile_evaluation_async(spec, evaluation_key(5), states[2]))
    for row in rows[:-1]:
        c = int(row["chunk"])
        want = evaluations.evaluate_state(spec, jax.random.fold_in(evaluation_key(5), c), states[c], None, compiled)
        np.testing.assert_allclose([float(row[k]) for k in FIGURES], [want[k] for k in FIGURES], rtol=1e-5)
    assert len({r["mean_final_distance"] for r in rows}) == 3  # three states and keys: not one evaluation repeated


def test_resume_keeps_the_rows_before_its_checkpoint_and_repeats_none(evaluated):
    run_dir, _, _, _, written = evaluated
    assert [r["chunk"] for r in rows_of(run_dir)] == ["2", "3", "4"]  # the added row of chunk 3 evaluated again
    with open(os.path.join(run_dir, periodic.EVALS_FILE)) as f:
        assert f.read().startswith(written)  # row 2 as the first process wrote it
    assert float(rows_of(run_dir)[1]["mean_return"]) != -99.0


def test_evaluation_time_stays_off_the_training_clock(evaluated):
    """Every evaluation seems to take EVAL_COST s: the training clock, the checkpoints' and the rows'
    ``train_wall_s`` (carried over the resume) and the gap between the resumed process's rows' ``process_s``
    stay below it; that process's ``periodic_eval_s`` holds its one evaluation before the final one."""
    run_dir, result, _, _, _ = evaluated
    rows = rows_of(run_dir)
    assert result["train_s"] < EVAL_COST and EVAL_COST <= result["periodic_eval_s"] < EVAL_COST + 60
    assert result["eval_s"] >= EVAL_COST
    with open(os.path.join(run_dir, "eval.json")) as f:
        assert json.load(f)["periodic_eval_s"] == result["periodic_eval_s"]
    clock = [float(r["train_wall_s"]) for r in rows]
    assert clock == sorted(clock) and clock[-1] < EVAL_COST, clock
    assert all(float(r["eval_s"]) >= EVAL_COST for r in rows)
    assert 0 <= float(rows[2]["process_s"]) - float(rows[1]["process_s"]) < EVAL_COST
    assert rows[1]["startup_s"] == rows[2]["startup_s"] and float(rows[2]["first_chunk_s"]) > 0
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    (_, before), (_, last) = ckpt.restore(2), ckpt.restore(4)
    ckpt.close()
    # row 2 is written before checkpoint 2, the final row after checkpoint 4 (rows: 3 decimals)
    assert float(rows[0]["train_wall_s"]) <= before["train_wall_s"] + 1e-3 <= last["train_wall_s"] + 1e-3
    assert last["train_wall_s"] <= float(rows[2]["train_wall_s"]) + 1e-3 < EVAL_COST


def test_tracking_env_evaluates_during_training_with_one_program(tmp_path):
    """The unicycle's evaluations during training run one program compiled once (the trainer's ``policy`` is
    called once to trace it, once by the final evaluation) and agree with the final evaluation's own."""
    argv = ["--env", "unicycle", "--env-config", "mode=kinematic", "max_steps=6", "--total-steps", "192",
            "--chunks", "3", "--evals", "3", "--seed", "3", "--num-envs", "4", "--unroll-length", "16",
            "--minibatch-size", "16", "--actor-hidden", "8", "--critic-hidden", "8",
            "--out", str(tmp_path)]  # fmt: skip
    calls = []
    result, trainer = shifted_run(argv, policy_calls=calls)
    rows = rows_of(result["run_dir"])
    assert [int(r["chunk"]) for r in rows] == [1, 2, 3] and len(calls) == 2
    env = make_env("unicycle", ppo_cli.env_settings(ppo_cli.parse(argv)))
    axes = ("x", "y", "theta", "steps", "episode_return")

    def episode(k, s):  # the test episode from t = 0 of the state after a chunk (compiled once, from the cache)
        policy = as_recurrent(trainer.policy(s))
        return tracking.rollout(env, policy.step, carry=policy.carry)

    test = jax.jit(episode)
    for row in rows:
        out = jax.device_get(test(evaluation_key(3), state_after(trainer, 3, int(row["chunk"]), OFFSET)))
        steps = int(out["steps"])
        want = [*np.abs(out["abs_error"][:steps]).sum(0), steps, out["episode_return"]]
        np.testing.assert_allclose([float(row[k]) for k in axes], want, rtol=1e-5)
    assert len({row["x"] for row in rows}) == 3
    with open(os.path.join(result["run_dir"], "eval.json")) as f:
        final = json.load(f)
    assert [float(rows[-1][k]) for k in axes] == [final[k] for k in axes]
    assert shifted_run(resume=result["run_dir"])[0]["finished"]  # a finished run resumed evaluates again
    again = rows_of(result["run_dir"])
    assert [r["chunk"] for r in again] == ["1", "2", "3"] and [r[k] for r in again for k in axes] == [
        r[k] for r in rows for k in axes]  # the final row written anew, none repeated


def test_eval_chunks_keys_and_kept_rows_by_hand(tmp_path, capsys):
    assert periodic.eval_chunks(0, 50) == ()
    assert periodic.eval_chunks(3, 50) == (17, 34, 50)
    assert periodic.eval_chunks(4, 4) == (1, 2, 3, 4)
    assert periodic.eval_chunks(10, 3) == (1, 2, 3)  # at most one per chunk
    assert periodic.eval_chunks(1, 7) == (7,)  # the final evaluation alone
    key = evaluation_key(0)
    np.testing.assert_array_equal(periodic.key_at(key, 7, 7), key)
    np.testing.assert_array_equal(periodic.key_at(key, 3, 7), jax.random.fold_in(key, 3))
    assert periodic.kept_chunk(2, 4) == 2 and periodic.kept_chunk(4, 4) == 3
    log = periodic.EvalLog(str(tmp_path))
    clocks = {"train_wall_s": 1.5, "process_s": None, "eval_s": 0.25, "startup_s": 3.0, "first_chunk_s": 1.0}
    log.add(periodic.row_of(1, 10, clocks, {"kind": "episodes", "success_rate": 0.5}))
    log.add(periodic.row_of(2, 20, {**clocks, "train_wall_s": 2.5, "process_s": 7.0}, {"success_rate": 0.75, "x": 1.0}))
    assert open(tmp_path / "evals.csv").read().splitlines() == [
        "chunk,env_steps,train_wall_s,process_s,eval_s,startup_s,first_chunk_s,success_rate,x",
        "1,10,1.5,,0.25,3.0,1.0,0.5,", "2,20,2.5,7.0,0.25,3.0,1.0,0.75,1.0",
    ]
    assert [r["chunk"] for r in periodic.EvalLog(str(tmp_path), keep_through=1).rows] == ["1"]
    assert open(tmp_path / "evals.csv").read().splitlines()[1:] == ["1,10,1.5,,0.25,3.0,1.0,0.5,"]
    (tmp_path / "evals.csv").write_text("chunk,env_steps\nnot a number,3\n")  # damaged: kept aside, begun anew
    assert periodic.EvalLog(str(tmp_path), keep_through=5).rows == []
    assert (tmp_path / "evals.csv.unreadable").read_text() == "chunk,env_steps\nnot a number,3\n"
    assert "evals.csv: unreadable (ValueError" in capsys.readouterr().out


def test_evals_out_of_range_is_a_one_line_error(capsys):
    assert ppo_cli.main(["--env", "brax:fast", "--evals", "-1"]) == 2
    assert capsys.readouterr().err == "error: --evals -1 is out of range; allowed >= 0\n"
