"""``python -m train.ppo``: a tiny run by subprocess, resume = uninterrupted, bad input, the NaN guard."""

import dataclasses
import glob
import json
import os
import signal
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks import brax_tasks
from jaxrl_robot.checkpoint import Checkpointer
from jaxrl_robot.logging import MetricsLogger, read_csv
from jaxrl_robot.types import Trainer
from tests.subproc import ROOT, cache_every_program, cpu_env
from train import a2c as a2c_cli
from train import ddpg as ddpg_cli
from train import ppo as ppo_cli
from train import presets
from train import run as run_module
from train import td3 as td3_cli
from train.options import RunSpec
from train.run import NonFiniteLossError, run, stop_on_signals

TINY = [
    "--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16", "--actor-updates", "2",
    "--critic-updates", "2", "--actor-hidden", "16", "--critic-hidden", "16",
]  # fmt: skip


def test_cli_learns_arm7_on_a_small_budget_and_writes_the_run_directory(tmp_path):
    """The default command on a small budget: the run directory, the printed evaluation, and learning."""
    cmd = [sys.executable, "-m", "train.ppo", "--env", "arm7", "--total-steps", "90000", "--chunks", "3",
           "--eval-episodes", "50", "--out", str(tmp_path)]  # fmt: skip
    env = cpu_env()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (run_dir,) = glob.glob(str(tmp_path / "ppo-arm7-*"))
    for name in ("config.json", "metrics.csv", "eval.json", "episode_reward.png", "success_rate.png"):
        assert os.path.isfile(os.path.join(run_dir, name)), name
    assert glob.glob(os.path.join(run_dir, "tb", "events.*"))
    assert Checkpointer(os.path.join(run_dir, "checkpoints")).latest_step() == 3
    with open(os.path.join(run_dir, "metrics.csv")) as f:
        assert len(f.read().strip().splitlines()) == 4  # header + 3 chunks
    assert "success_rate" in proc.stdout and "mean_extra_distance" in proc.stdout  # the printed table
    assert "Failed to import" not in proc.stdout + proc.stderr  # MJX's optional Warp probe is silenced
    config = json.load(open(os.path.join(run_dir, "config.json")))
    assert config["args"]["env"] == "arm7" and config["args"]["preset"] in ("cpu", "fast")
    result = json.load(open(os.path.join(run_dir, "eval.json")))
    assert result["episodes"] == 50
    # what was compiled and how long the process took to start, into the session's cache folder
    assert result["compile"]["cache_dir"] == os.environ["JAX_COMPILATION_CACHE_DIR"]
    assert result["compile"]["programs"] >= 3 and result["compile"]["cache_requests"] == result["compile"]["programs"]
    assert {s["name"] for s in result["compile"]["slowest"]} >= {"jit(chunk)", "jit(evaluation)"}
    assert result["startup_s"] > 0
    # learning: a random policy reaches almost no goal; 90 k steps of the default preset reach most (seeds 0-2: 94 %)
    assert result["success_rate"] >= 0.8, result


RUN = ["--env", "brax:fast", "--episode-length", "16", "--total-steps", "256", "--chunks", "4",
       "--checkpoint-every", "1", "--eval-episodes", "2", *TINY]  # fmt: skip


def final_checkpoint(run_dir, target=None):
    """``(state, record)`` of the run's latest checkpoint, restored into ``target``'s structure if given."""
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    state, record = ckpt.restore(ckpt.latest_step(), target)
    ckpt.close()
    return state, record


def assert_same_learnt_state(state, reference, atol=None):
    """Networks, optimisers, observation statistics, key and iteration of two PPO training states
    agree: to the bit, or within ``atol``."""
    keys = ("actor_params", "critic_params", "actor_opt", "critic_opt", "obs_stats", "key", "iteration")
    leaves = jax.tree.leaves({k: state[k] for k in keys})
    ref_leaves = jax.tree.leaves({k: reference[k] for k in keys})
    assert len(leaves) == len(ref_leaves) > 10
    for x, y in zip(leaves, ref_leaves, strict=True):
        if atol is None:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
        else:
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), atol=atol)


def test_resume_equals_uninterrupted(tmp_path, capsys):
    """A run stopped half-way and resumed ends where an uninterrupted one does, to the bit; the uninterrupted
    run's programs are jitted here (no program cache), the resumed run's are the kept ones
    (``jaxrl_robot.compilation.ProgramCache``: built by the stopped run or an earlier test, loaded without
    tracing), so the kept programs compute what jax.jit's do."""
    args = [*RUN, "--seed", "7"]
    with cache_every_program():
        assert ppo_cli.main([*args, "--out", str(tmp_path / "a"), "--no-compile-cache"]) == 0  # uninterrupted
        assert ppo_cli.main([*args, "--out", str(tmp_path / "b"), "--stop-after-steps", "128"]) == 0  # stopped half-way
        (run_b,) = glob.glob(str(tmp_path / "b" / "*"))
        assert not os.path.exists(os.path.join(run_b, "eval.json"))
        assert ppo_cli.main(["--resume", run_b]) == 0  # continued
    assert "resumed at chunk 2 (128 env steps)" in capsys.readouterr().out
    kept = json.load(open(os.path.join(run_b, "eval.json")))["compile"]["program_cache"]
    assert kept["loaded"] >= 2 and kept["loaded"] + kept["built"] == 3  # initialisation, chunk (and evaluation)
    (run_a,) = glob.glob(str(tmp_path / "a" / "*"))
    assert json.load(open(os.path.join(run_a, "eval.json")))["compile"]["program_cache"]["loaded"] == 0
    sa, ra = final_checkpoint(run_a)
    sb, rb = final_checkpoint(run_b)
    assert ra["chunk"] == rb["chunk"] == 4
    assert_same_learnt_state(sa, sb)
    rows_b = open(os.path.join(run_b, "metrics.csv")).read().strip().splitlines()
    assert len(rows_b) == 5  # header + 4 chunks, none repeated after the resume


def test_seeds_train_together_each_as_its_own_seed_would(tmp_path, capsys):
    """``--seeds 2 --seed 7``: seeds 7 and 8 in one run, each with its own ``seed<k>/`` (metrics, eval.json);
    seed 8 of the loop equals a ``--seed 8`` run to the bit, of the vmapped run (stopped half-way and
    resumed) to float rounding, and seeds 7 and 8 learn different states."""
    with cache_every_program():
        assert ppo_cli.main([*RUN, "--seed", "8", "--out", str(tmp_path / "single")]) == 0
        loop = ["--seed", "7", "--seeds", "2", "--seed-map", "loop", "--out", str(tmp_path / "loop")]
        assert ppo_cli.main([*RUN, *loop]) == 0
        vmap = ["--seed", "7", "--seeds", "2", "--seed-map", "vmap", "--out", str(tmp_path / "vmap")]
        assert ppo_cli.main([*RUN, *vmap, "--stop-after-steps", "128"]) == 0  # vmapped, stopped half-way
        (run,) = glob.glob(str(tmp_path / "vmap" / "*"))
        assert ppo_cli.main(["--resume", run]) == 0  # and continued
    assert "resumed at chunk 2 (128 env steps)" in capsys.readouterr().out
    (single,) = glob.glob(str(tmp_path / "single" / "*"))
    ref, _ = final_checkpoint(single)
    for mode in ("loop", "vmap"):
        (run,) = glob.glob(str(tmp_path / mode / "*"))
        for seed in (7, 8):
            ev = json.load(open(os.path.join(run, f"seed{seed}", "eval.json")))
            assert ev["seed"] == seed and ev["env_steps"] == 256 and ev["episodes"] == 2
            alone = json.load(open(os.path.join(run, f"seed{seed}", "config.json")))["args"]
            assert (alone["seed"], alone["seeds"]) == (seed, 1)  # the config of --seed k alone
            rows = open(os.path.join(run, f"seed{seed}", "metrics.csv")).read().strip().splitlines()
            assert len(rows) == 5  # header + 4 chunks (the vmapped run's resume repeats none)
        assert not os.path.exists(os.path.join(run, "eval.json"))
        state, record = final_checkpoint(run)
        assert record["chunk"] == 4
        if mode == "loop":  # a tuple of the seeds' states
            seed7, seed8 = state[0], state[1]
        else:  # one state with a leading seed axis
            seed7, seed8 = jax.tree.map(lambda x: x[0], state), jax.tree.map(lambda x: x[1], state)
        assert_same_learnt_state(seed8, ref, atol=None if mode == "loop" else 1e-5)
        a7, a8 = (np.asarray(jax.tree.leaves(s["actor_params"])[0]) for s in (seed7, seed8))
        assert np.abs(a7 - a8).max() > 1e-3  # the seeds differ


def test_seeds_bad_input(capsys):
    assert ppo_cli.main(["--env", "brax:fast", "--seeds", "0"]) == 2
    assert "--seeds 0 is out of range; allowed >= 1" in capsys.readouterr().err
    assert ppo_cli.main(["--env", "brax:fast", "--seeds", "2", "--seed-map", "pmap"]) == 2
    assert "--seed-map 'pmap' is not a seed map; valid: auto, vmap, loop" in capsys.readouterr().err


def test_bad_input_names_the_valid_choices(capsys):
    assert ppo_cli.main(["--env", "nope"]) == 2
    assert "unknown environment 'nope'; valid names: arm7" in capsys.readouterr().err
    assert ppo_cli.main(["--env", "arm7", "--preset", "huge"]) == 2
    assert "unknown preset 'huge'; valid presets: auto, thesis, cpu, fast, brax, playground" in capsys.readouterr().err
    assert ppo_cli.main(["--env", "arm7", "--clip-eps", "2"]) == 2
    assert "clip_eps=2.0 is out of range; allowed (0, 1)" in capsys.readouterr().err
    assert ppo_cli.main(["--env", "arm7", "--reward", "fast"]) == 2
    assert "reward='fast' is not valid" in capsys.readouterr().err
    assert ppo_cli.main(["--resume", "/nonexistent/run"]) == 2
    assert "not a run directory" in capsys.readouterr().err


def _nan_trainer(bad_chunk: int) -> Trainer:
    """A stand-in algorithm whose loss turns NaN in chunk ``bad_chunk`` (1-based)."""

    def update(state):
        count = state["count"] + 1
        loss = jnp.where(count == bad_chunk, jnp.nan, 1.0 / count)
        return {"count": count, "w": state["w"] + 1.0}, {"critic_loss": loss, "episode_return": jnp.nan}

    return Trainer(
        init=lambda key: {"count": jnp.zeros((), jnp.int32), "w": jnp.zeros(3)},
        update=update,
        policy=lambda state: (lambda obs: obs),
        num_updates=10,
        env_steps_per_update=100,
    )


def test_nan_guard_stops_naming_the_step_and_keeps_the_last_good_checkpoint(tmp_path):
    spec = RunSpec(
        algo="fake", env_name="none", env=None, trainer=_nan_trainer(bad_chunk=4), config={}, out=str(tmp_path),
        checkpoint_every=100, progress=False,
    )  # fmt: skip
    with pytest.raises(NonFiniteLossError, match=r"critic_loss is nan after env step 400 \(chunk 4\)"):
        run(spec)
    (run_dir,) = glob.glob(str(tmp_path / "fake-none-*"))
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    assert ckpt.latest_step() == 3
    state, record = ckpt.restore(3, {"count": jnp.zeros((), jnp.int32), "w": jnp.zeros(3)})
    assert int(state["count"]) == 3 and record["env_steps"] == 300
    np.testing.assert_array_equal(state["w"], 3.0)


def test_checkpoint_round_trip_keeps_structure_with_empty_arrays(tmp_path):
    """MJX's Data holds zero-size arrays and a no-BN actor an empty dict; both survive save/restore."""
    from jaxrl_robot.types import RunningStats

    state = {
        "params": {"w": jnp.arange(4.0).reshape(2, 2)},
        "stats": {},
        "empty": jnp.zeros((3, 0)),
        "rs": RunningStats(count=jnp.asarray(2.0), mean=jnp.ones(2), var=jnp.full(2, 3.0)),
        "key": jax.random.PRNGKey(5),
    }
    ckpt = Checkpointer(str(tmp_path / "ck"))
    ckpt.save(7, state, {"chunk": 7})
    template = jax.tree.map(jnp.zeros_like, state)
    restored, record = ckpt.restore(7, template)
    assert record == {"chunk": 7} and ckpt.latest_step() == 7
    assert jax.tree.structure(restored) == jax.tree.structure(state)
    for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(state), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)


def test_out_that_cannot_be_created_is_a_one_line_error(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    argv = ["--env", "brax:fast", "--episode-length", "16", "--total-steps", "256", *TINY]
    assert ppo_cli.main([*argv, "--out", str(blocker / "runs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: --out '{blocker / 'runs'}': cannot create the run directory")


def test_resume_before_the_first_checkpoint_starts_that_run_over(tmp_path, capsys):
    run_dir = tmp_path / "fake-none-killed"
    run_dir.mkdir()
    (run_dir / "config.json").write_text("{}")
    (run_dir / "metrics.csv").write_text("env_steps,critic_loss\n100,0.5\n")  # written before it was killed
    spec = RunSpec(
        algo="fake", env_name="none", env=None, trainer=_nan_trainer(bad_chunk=99), config={}, run_dir=str(run_dir),
        checkpoint_every=1, stop_after_steps=300, progress=False,
    )  # fmt: skip
    result = run(spec)
    assert "no checkpoint yet; starting this run from the beginning with its saved config" in capsys.readouterr().out
    assert result["env_steps"] == 300 and not result["finished"]
    state, record = Checkpointer(str(run_dir / "checkpoints")).restore(3, _nan_trainer(99).init(None))
    assert int(state["count"]) == 3 and record["env_steps"] == 300
    rows = read_csv(str(run_dir / "metrics.csv"))
    assert [int(float(r["env_steps"])) for r in rows] == [100, 200, 300]  # the killed run's row replaced


def test_sigterm_stops_after_the_chunk_with_a_checkpoint_and_resume_continues(tmp_path, monkeypatch, capsys):
    """A SIGTERM that arrives while chunk 3 is logged stops the run after that chunk: its state is saved
    although the checkpoint interval (100) is far, the handlers in place before come back, and
    ``--resume`` continues from chunk 3 (to 6, with ``stop_after_steps``)."""

    class SignalledLogger(MetricsLogger):
        def write(self, step, metrics):
            super().write(step, metrics)
            if step == 300:
                signal.raise_signal(signal.SIGTERM)

    monkeypatch.setattr(run_module, "MetricsLogger", SignalledLogger)
    before = signal.getsignal(signal.SIGTERM)
    spec = RunSpec(
        algo="fake", env_name="none", env=None, trainer=_nan_trainer(bad_chunk=99), config={}, out=str(tmp_path),
        checkpoint_every=100, progress=False,
    )  # fmt: skip
    result = run(spec)
    assert result["interrupted"] == signal.SIGTERM and not result["finished"] and result["env_steps"] == 300
    assert "SIGTERM: stopped after chunk 3, checkpoint saved" in capsys.readouterr().out
    assert signal.getsignal(signal.SIGTERM) is before
    ckpt = Checkpointer(os.path.join(result["run_dir"], "checkpoints"))
    assert ckpt.latest_step() == 3
    ckpt.close()
    monkeypatch.undo()
    again = run(dataclasses.replace(spec, run_dir=result["run_dir"], stop_after_steps=600))
    assert again["env_steps"] == 600 and "interrupted" not in again
    state, _ = Checkpointer(os.path.join(result["run_dir"], "checkpoints")).restore(6, _nan_trainer(99).init(None))
    assert int(state["count"]) == 6


def test_a_second_ctrl_c_interrupts_at_once():
    before = signal.getsignal(signal.SIGINT)
    with stop_on_signals() as got:
        signal.raise_signal(signal.SIGINT)
        assert got["signal"] == signal.SIGINT
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is before
    with stop_on_signals(enabled=False) as got:  # several processes: the handlers stay as they were
        assert signal.getsignal(signal.SIGINT) is before and got["signal"] == 0


def test_brax_preset_converts_brax_settings_and_auto_picks_it(capsys):
    """brax's inverted_pendulum row (2048 envs, batch 1024 × 32 mini-batches of unrolls of 5, 4 passes):
    80 steps per lane, mini-batches of 4096 (5120 rounded down to the 2048 lanes), 4 · 163840 / 4096 = 160
    steps of actor and critic; halfcheetah (batch 512, unroll 20, 8 passes): 160 steps, 10240, 256."""
    ip = ppo_cli.parse(["--env", "brax:inverted_pendulum"])
    assert ip.preset == "brax" and "preset: brax (brax's published PPO settings" in capsys.readouterr().err
    c = ip.ppo
    shape = (c.num_envs, c.unroll_length, c.minibatch_size, c.actor_updates, c.critic_updates)
    assert shape == (2048, 80, 4096, 160, 160)
    assert (c.gamma, c.entropy_coef, c.reward_scale, c.clip_eps, c.total_steps) == (0.97, 0.01, 10.0, 0.3, 2_000_000)
    assert c.normalize_obs and c.learn_std and not c.batch_norm and c.actor_lr == c.critic_lr == 3e-4
    assert c.state_std and c.tanh_actions and c.activation == "swish" and c.critic_first  # brax's policy
    assert c.advantage_segment == 0  # the thesis's update on inverted_pendulum, brax's on halfcheetah
    hc = presets.brax_ppo_config("halfcheetah", 6)
    assert (hc.unroll_length, hc.minibatch_size, hc.actor_updates, hc.gamma) == (160, 10240, 256, 0.95)
    assert (hc.advantage_segment, hc.critic_first) == (20, False)
    thesis = presets.brax_ppo_config("halfcheetah", 6, segments=False)
    assert (thesis.advantage_segment, thesis.critic_first, thesis.minibatch_size) == (0, True, 10240)
    # reacher's tuned fields over its row (Adam at 1e-3 annealed to 0, gradients clipped at norm 1),
    # winning over the row's learning rate; tuned=False gives the row alone (brax's 3e-4, constant)
    re = ppo_cli.parse(["--env", "brax:reacher"]).ppo
    assert "settings with our tuned fields over them for brax:reacher; train.presets BRAX_PPO, BRAX_PPO_TUNED)" \
        in capsys.readouterr().err
    assert (re.actor_lr, re.critic_lr, re.lr_schedule, re.max_grad_norm) == (1e-3, 1e-3, "linear", 1.0)
    assert (re.gamma, re.entropy_coef, re.advantage_segment) == (0.95, 1e-3, 50)  # the row's and brax's update
    row = presets.brax_ppo_config("reacher", 2, tuned=False, learning_rate=5e-4)
    assert (row.actor_lr, row.lr_schedule, row.max_grad_norm) == (5e-4, "constant", 0.0)
    assert presets.brax_ppo_config("reacher", 2, learning_rate=5e-4).actor_lr == 1e-3
    # the recurrent policy: the thesis's update over brax's lanes, whole sequences of 10 in each unroll
    lstm = ppo_cli.parse(["--env", "brax:halfcheetah", "--policy", "lstm"]).ppo.validate()
    assert (lstm.policy, lstm.advantage_segment, lstm.num_envs, lstm.unroll_length) == ("lstm", 0, 2048, 160)
    assert lstm.minibatch_size == 2048 * 10 * 4 and not lstm.tanh_actions and lstm.activation == "relu"
    # benchmarks.brax_tasks --num-envs 64: the batch scales with the envs, the per-lane structure stays
    small = presets.brax_ppo_config("inverted_pendulum", 1, **brax_tasks.brax_row("inverted_pendulum", 64))
    assert (small.num_envs, small.unroll_length, small.minibatch_size, small.actor_updates) == (64, 80, 128, 160)
    # a flag still wins; envs without a row keep the generic presets; A2C and A3C have no brax preset
    assert ppo_cli.parse(["--env", "brax:inverted_pendulum", "--gamma", "0.9"]).ppo.gamma == 0.9
    assert ppo_cli.parse(["--env", "brax:fast"]).preset in ("cpu", "fast")
    assert a2c_cli.main(["--env", "arm7", "--preset", "brax"]) == 2
    assert "unknown preset 'brax'; valid presets: auto, thesis, cpu, fast" in capsys.readouterr().err


def test_td3_and_ddpg_brax_preset_is_the_sac_row_with_td3_s_own_settings_and_auto_picks_it(capsys):
    """``python -m train.td3 --env brax:hopper``: brax's hopper SAC lanes and memory (128 lanes, 2^20 rows
    filled to 8192 first, 6 553 600 steps, 2 × 256 nets) with TD3's own settings (on 256 rows at 3e-4,
    γ 0.99, reward × 1, σ 0.1, random start) and hopper's tuned two updates per env step (256 per iteration
    of 128 env steps; ``tuned=False``: TD3's 128) and TD3's critics; distributed: 8 + 8 workers of 16
    lanes, the batch split; DDPG on an env without a row: hopper's with the env's own episode length; an
    unknown brax task keeps the generic presets."""
    hop = td3_cli.parse(["--env", "brax:hopper"])
    err = capsys.readouterr().err
    assert hop.preset == "brax" and "preset: brax (brax's SAC lanes and memory with TD3's own update settings " \
        "and our tuned entries over them for brax:hopper; train.presets BRAX_SAC, TD3_OWN, BRAX_SAC_TUNED)" in err
    c = hop.td3
    assert (c.num_envs, c.unroll_length, c.updates_per_iteration, c.batch_size) == (128, 1, 256, 256)
    assert presets.brax_sac_ddpg_config("hopper", tuned=False).updates_per_iteration == 128
    assert presets.brax_sac_ddpg_config("walker2d", num_envs=16).updates_per_iteration == 32
    assert (c.buffer_size, c.learning_starts, c.total_steps, c.actor_hidden) == (1_048_576, 8192, 6_553_600, (256, 256))
    assert (c.gamma, c.reward_scale, c.noise_scale, c.actor_lr, c.episode_length) == (0.99, 1.0, (0.1,), 3e-4, 1000)
    assert c.random_start and c.twin_critics and c.policy_delay == 2 and c.normalize_obs
    d = ddpg_cli.parse(["--env", "brax:walker2d", "--distributed"]).ddpg
    assert (d.sync_workers, d.collect_workers, d.collect_lanes, d.batch_size, d.twin_critics) == (8, 8, 16, 32, False)
    arm = ddpg_cli.parse(["--env", "arm7", "--preset", "brax"]).ddpg
    assert (arm.num_envs, arm.schedule, arm.episode_length, arm.gamma) == (128, "steps", 0, 0.99)
    assert ddpg_cli.parse(["--env", "brax:ant"]).preset in ("cpu", "fast")


def test_brax_sac_settings_convert_to_ddpg_by_hand():
    """brax's hopper SAC row (128 envs stepped once, then 64 updates on 512 transitions, memory 2^20 filled to
    8192 first, γ 0.997, reward × 30, lr 6e-4): the same schedule in DDPG's terms with ``own_settings=False``;
    with ``tuned=False`` TD3's own (128 updates on 256 at 3e-4, random actions first, γ 0.99, reward × 1, σ 0.1);
    --num-envs keeps the batch."""
    c = presets.brax_sac_ddpg_config("hopper", own_settings=False)
    schedule = (c.schedule, c.num_envs, c.unroll_length, c.updates_per_iteration, c.batch_size)
    assert schedule == ("steps", 128, 1, 64, 512) and c.total_steps == 6_553_600
    assert (c.buffer_size, c.learning_starts, c.gamma, c.reward_scale) == (1_048_576, 8192, 0.997, 30.0)
    assert c.actor_lr == c.critic_lr == 6e-4 and c.actor_hidden == c.critic_hidden == (256, 256) and c.normalize_obs
    assert c.iterations == 6_553_600 // 128 and not c.random_start and c.noise_scale == (0.1,)
    own = presets.brax_sac_ddpg_config("hopper", tuned=False, num_envs=16)
    assert (own.num_envs, own.updates_per_iteration, own.batch_size) == (16, 16, 256)
    assert own.actor_lr == own.critic_lr == 3e-4
    assert own.random_start and (own.learning_starts, own.gamma, own.reward_scale) == (8192, 0.99, 1.0)
    assert own.noise_scale == (0.1,) and own.buffer_size == 1_048_576
    cfg = brax_tasks.our_config("td3", "walker2d", 6, brax_tasks.brax_row("walker2d", 0, "td3"), 1000,
                                {"own_settings": False})
    assert (cfg.updates_per_iteration, cfg.batch_size, cfg.twin_critics) == (32, 128, True)
    row = brax_tasks.brax_row("walker2d", 16, "td3")
    assert (row["num_envs"], row["batch_size"], row["grad_updates_per_step"]) == (16, 128, 32)
    with pytest.raises(KeyError, match="hopper, walker2d"):
        presets.brax_sac_ddpg_config("halfcheetah")


