"""benchmarks.brax_tasks without training: brax's step count by hand, and one report merged from an
invocation that ran our side alone and one that ran brax's alone."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks import brax_tasks, provenance
from tests.subproc import cache_every_program
from train.presets import BRAX_PPO, BRAX_SAC


def test_our_ppo_trains_brax_s_count_of_env_steps_by_hand():
    """inverted_pendulum: a training step is 1024 · 32 · 5 = 163 840 env steps; 2 M over 9 epochs is
    1.36 → 2 steps per epoch, so brax trains 9 · 2 · 163 840 = 2 949 120 (as its run reported)."""
    assert brax_tasks.brax_ppo_steps(BRAX_PPO["inverted_pendulum"], 2_000_000) == 2_949_120
    assert brax_tasks.brax_ppo_steps(BRAX_PPO["inverted_pendulum"], 9 * 163_840) == 9 * 163_840  # exact: unchanged
    # halfcheetah: 512 · 32 · 20 = 327 680 per step; 50 M / (9 · 327 680) = 16.95 → 17
    assert brax_tasks.brax_ppo_steps(BRAX_PPO["halfcheetah"], 50_000_000) == 9 * 17 * 327_680
    # reacher with the notebook's action_repeat=4: 256 · 32 · 50 · 4 = 1 638 400 env steps per training step
    reacher = {**BRAX_PPO["reacher"], "action_repeat": 4}
    assert brax_tasks.brax_ppo_steps(reacher, 5_000_000) == 9 * 1_638_400


def test_brax_sac_steps_are_the_counts_brax_reported_and_our_calls_run_them_exactly():
    """brax's SAC reported 200 192 env steps on hopper and 100 352 on walker2d for budgets of 200 000 and
    100 000 with 4 evaluations (results files of --algo td3): a prefill of 8192 / 128 = 64 actor steps of
    128, then 3 epochs of ceil(191 808 / 384) = 500 and ceil(91 808 / 384) = 240. Ours then runs
    1564 = 23 × 68 and 784 = 16 × 49 iterations of 128 lanes, exactly; 1563 iterations (prime factors 3
    and 521) take 23 calls of 68, one over."""
    assert brax_tasks.brax_sac_steps(BRAX_SAC["hopper"], 200_000, 4) == 200_192
    assert brax_tasks.brax_sac_steps(BRAX_SAC["walker2d"], 100_000, 4) == 100_352
    assert brax_tasks.brax_sac_steps(BRAX_SAC["hopper"], 200_000, 10) == 8192 + 9 * 167 * 128  # ceil(191 808 / 1152)
    assert brax_tasks.update_chunk(1564) == 68 and brax_tasks.update_chunk(784) == 49
    assert brax_tasks.update_chunk(1563) == 68
    assert brax_tasks.update_chunk(20) == 1 and brax_tasks.update_chunk(7) == 1
    for iterations in range(1, 3000):
        chunk = brax_tasks.update_chunk(iterations)
        calls = -(-iterations // chunk)
        assert 0 <= calls * chunk - iterations < 20 and (calls >= 10 or chunk == 1), iterations


def _part(tmp_path, name, side, returns, wall, **fields):
    """A results file of one invocation that ran only ``side`` on inverted_pendulum (``fields``: more of the
    side's record, e.g. ``eval_mode``; without it, a record as written before the mode was recorded)."""
    run = {"returns": returns, "wall_s": wall * len(returns), "wall_per_seed_s": wall, "env_steps": 300,
           "env_steps_per_s": 300 * len(returns) / (wall * len(returns)), "curve_steps": [100, 200, 300],
           "curves": [[1.0, 2.0, r] for r in returns], **fields}  # fmt: skip
    prov = provenance.record("benchmarks.brax_tasks", [name], device_info={"name": "X", "platform": "gpu"},
                             allow_dirty=True)  # fmt: skip
    part = {"benchmark": "brax_tasks", "algo": "ppo", "provenance": prov, "device": "gpu-x", "backend": "mjx",
            "seeds": len(returns), "seed_map": "vmap", "brax_seeds": len(returns), "eval_episodes": 8,
            "figures": str(tmp_path / name), "tasks": [{"task": "inverted_pendulum", "settings": {}, "sides": [side],
                                                         side: run}]}  # fmt: skip
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(part))
    return str(path)


def test_merge_takes_each_side_from_the_invocation_that_ran_it(tmp_path):
    sampled = dict(eval_mode="stochastic")
    ours = _part(tmp_path, "ours", "ours", [1000.0, 990.0, 980.0], 10.0, returns_deterministic=[1000.0] * 3, **sampled)
    brax = _part(tmp_path, "brax", "brax", [900.0, 1000.0, 950.0], 50.0, **sampled)
    out = tmp_path / "out"
    result = brax_tasks.main(["--merge", ours, brax, "--out", str(out)])
    (row,) = result["tasks"]
    assert row["sides"] == ["ours", "brax"] and row["ours"]["returns"] == [1000.0, 990.0, 980.0]
    assert row["brax"]["returns"] == [900.0, 1000.0, 950.0]
    md = (out / "gpu-x-brax_tasks.md").read_text()
    # both sampled: ours 990.0 ± 8.2 ≥ brax 950.0 ± 40.8 (bold: at the goal), our mean action's 1000 beside,
    # wall per seed 10 ≤ 50 (bold), ratio 990 / 950
    assert ("| inverted_pendulum | 300 | 950.0 ± 40.8 (sampled) | 990.0 ± 8.2 | 1000.0 ± 0.0 | level: +40 (95 % CI "
            "−78 … +158; Welch), Mann–Whitney p 0.51, 3 vs 3 seeds | 50 | **10** | — / — | 6 | 30 | 1.04 |") in md
    assert "Invocation 3 of 3" in md and "Merged from 2 invocations" in md
    assert (out / "gpu-x-brax_tasks-figures" / "inverted_pendulum.png").exists()
    saved = json.loads((out / "gpu-x-brax_tasks.json").read_text())
    assert [s["command"].split()[-1] for s in saved["sources"]] == ["ours", "brax"]


def test_an_invocation_of_one_side_reports_the_other_as_not_run(tmp_path):
    ours = _part(tmp_path, "ours", "ours", [1000.0], 10.0)
    result = brax_tasks.main(["--merge", ours, "--out", str(tmp_path / "out")])
    assert "brax" not in result["tasks"][0]
    md = (tmp_path / "out" / "gpu-x-brax_tasks.md").read_text()
    assert ("| inverted_pendulum | 300 | nan ± nan | not measured | 1000.0 ± 0.0 | not compared (a side has no "
            "results) | nan | 10 |") in md


def test_returns_are_compared_in_one_evaluation_mode(tmp_path):
    # Records without a mode: ours is its mean action, brax's its sampled actions (brax's default), so the
    # same-mode cell is not measured and nothing is bold for the return.
    ours = _part(tmp_path, "ours", "ours", [1000.0], 10.0)
    brax = _part(tmp_path, "brax", "brax", [900.0], 50.0)
    brax_tasks.main(["--merge", ours, brax, "--out", str(tmp_path / "old")])
    md = (tmp_path / "old" / "gpu-x-brax_tasks.md").read_text()
    assert ("| 900.0 ± 0.0 (sampled) | not measured | 1000.0 ± 0.0 | not compared (a side has no results) | 50 "
            "| **10** | — / — | 6 | 30 | nan |") in md
    # brax evaluated with its mean action (--eval-mode deterministic): compared with our mean action's returns.
    ours = _part(tmp_path, "ours2", "ours", [800.0], 10.0, eval_mode="stochastic", returns_deterministic=[950.0])
    brax = _part(tmp_path, "brax2", "brax", [900.0], 50.0, eval_mode="deterministic")
    brax_tasks.main(["--merge", ours, brax, "--out", str(tmp_path / "new")])
    md = (tmp_path / "new" / "gpu-x-brax_tasks.md").read_text()
    assert ("| 900.0 ± 0.0 (mean action) | 950.0 ± 0.0 | 950.0 ± 0.0 | not tested (1 vs 1 seeds; 2 a side needed) "
            "| 50 | **10** | — / — | 6 | 30 | 1.06 |") in md  # one seed a side: no verdict, so no bold


def test_merge_joins_brax_s_seeds_run_by_different_invocations(tmp_path):
    """Seed 0 written before seeds were recorded (so seed 0) and seeds 1-2 of another invocation: three seeds,
    wall per seed over all three; a file that ran seed 1 again replaces the record (the later file wins)."""
    sampled = dict(eval_mode="stochastic")
    first = _part(tmp_path, "b0", "brax", [900.0], 50.0)  # no mode recorded: brax's sampled
    rest = _part(tmp_path, "b12", "brax", [1000.0, 950.0], 20.0, seed_ids=[1, 2], **sampled)
    result = brax_tasks.main(["--merge", first, rest, "--out", str(tmp_path / "out")])
    brax = result["tasks"][0]["brax"]
    assert brax["returns"] == [900.0, 1000.0, 950.0] and brax["seed_ids"] == [0, 1, 2]
    assert brax["wall_s"] == 90.0 and brax["wall_per_seed_s"] == 30.0 and brax["env_steps_per_s"] == 900 / 90.0
    assert len(brax["curves"]) == 3 and result["brax_seeds"] == 3
    assert "| 950.0 ± 40.8 (sampled) |" in (tmp_path / "out" / "gpu-x-brax_tasks.md").read_text()
    # a merged file merged again: its invocations' records come along; --label names the file, --note is read
    brax_tasks.main(["--merge", str(tmp_path / "out" / "gpu-x-brax_tasks.json"), "--out", str(tmp_path / "re"),
                     "--label", "5M", "--note", "How to read it."])
    md = (tmp_path / "re" / "gpu-x-brax_tasks-5M.md").read_text()
    assert "Merged from 3 invocations" in md and "Invocation 4 of 4" in md and "\nHow to read it.\n" in md
    again = _part(tmp_path, "b1", "brax", [800.0], 40.0, seed_ids=[1], **sampled)
    result = brax_tasks.main(["--merge", rest, again, "--out", str(tmp_path / "out2")])
    assert result["tasks"][0]["brax"]["returns"] == [800.0]
    mean_action = _part(tmp_path, "bd", "brax", [700.0], 40.0, seed_ids=[3], eval_mode="deterministic")
    result = brax_tasks.main(["--merge", rest, mean_action, "--out", str(tmp_path / "out3")])
    assert result["tasks"][0]["brax"]["returns"] == [700.0]  # another mode: not joined


def test_brax_from_takes_brax_s_side_alone_of_another_algorithm_s_file(tmp_path):
    """A TD3 file with brax's SAC beside it lends brax's side to a SAC file of ours; TD3's side of ours is left
    out; a PPO file cannot lend its brax side (brax's PPO is not SAC's peer); --brax-from needs --merge."""
    sampled = dict(eval_mode="stochastic")
    td3 = json.loads(open(_part(tmp_path, "td3", "ours", [500.0, 600.0], 10.0, **sampled)).read())
    brax = json.loads(open(_part(tmp_path, "b", "brax", [300.0, 400.0], 90.0, **sampled)).read())
    td3["algo"] = "td3"
    td3["tasks"][0].update(sides=["ours", "brax"], brax=brax["tasks"][0]["brax"])
    (tmp_path / "td3.json").write_text(json.dumps(td3))
    sac = json.loads(open(_part(tmp_path, "sac", "ours", [700.0, 800.0, 900.0], 5.0, **sampled)).read())
    sac["algo"] = "sac"
    (tmp_path / "sac.json").write_text(json.dumps(sac))
    result = brax_tasks.main(["--merge", str(tmp_path / "sac.json"), "--brax-from", str(tmp_path / "td3.json"),
                              "--out", str(tmp_path / "out")])
    (row,) = result["tasks"]
    assert result["algo"] == "sac" and row["ours"]["returns"] == [700.0, 800.0, 900.0]
    assert row["brax"]["returns"] == [300.0, 400.0] and (result["seeds"], result["brax_seeds"]) == (3, 2)
    assert "| 350.0 ± 50.0 (sampled) | **800.0 ± 81.6** |" in (tmp_path / "out" / "gpu-x-brax_tasks-sac.md").read_text()
    ppo = _part(tmp_path, "ppo", "brax", [1.0], 1.0)
    with pytest.raises(SystemExit, match="brax's PPO, not the SAC"):
        brax_tasks.main(["--merge", str(tmp_path / "sac.json"), "--brax-from", ppo, "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit):
        brax_tasks.main(["--brax-from", ppo, "--out", str(tmp_path / "x")])


def test_a_killed_brax_run_keeps_the_seeds_it_finished(tmp_path):
    """brax's side is written after each seed: a file with 1 of 3 seeds says so in the table."""
    brax = _part(tmp_path, "brax", "brax", [900.0], 50.0)
    result = brax_tasks.main(["--merge", brax, "--out", str(tmp_path / "out")])
    assert result["brax_seeds"] == 1
    part = json.loads(open(brax).read())
    part["brax_seeds"] = 3
    open(brax, "w").write(json.dumps(part))
    brax_tasks.main(["--merge", brax, "--out", str(tmp_path / "out")])
    assert "| 900.0 ± 0.0 (sampled) (1 of 3 seeds) |" in (tmp_path / "out" / "gpu-x-brax_tasks.md").read_text()
    # a file of ours alone (its brax_seeds: --seeds, 16) does not count for brax's side, nor brax's for ours
    ours = json.loads(open(_part(tmp_path, "ours16", "ours", [1000.0] * 16, 10.0)).read())
    part["seeds"], part["brax_seeds"] = 20, 1  # brax's run with --seeds 20 --brax-seeds 1
    open(brax, "w").write(json.dumps(part))
    result = brax_tasks.main(["--merge", brax, str(tmp_path / "ours16.json"), "--out", str(tmp_path / "out")])
    assert (result["seeds"], result["brax_seeds"], ours["brax_seeds"]) == (16, 1, 16)
    # merged rows of different seed counts: a row is short only against what its own invocations asked for
    three = json.loads(open(_part(tmp_path, "b3", "brax", [1.0, 2.0, 3.0], 5.0, seed_ids=[0, 1, 2])).read())
    one = json.loads(open(_part(tmp_path, "b1", "brax", [4.0], 5.0, seed_ids=[3])).read())
    one["tasks"][0]["task"] = "reacher"
    for name, part in (("b3", three), ("b1", one)):
        (tmp_path / f"{name}.json").write_text(json.dumps(part))
    result = brax_tasks.main(["--merge", *(str(tmp_path / f"{n}.json") for n in ("b3", "b1")),
                              "--out", str(tmp_path / "rows")])  # fmt: skip
    md = (tmp_path / "rows" / "gpu-x-brax_tasks.md").read_text()
    assert result["brax_seeds"] == 3 and "of 3 seeds" not in md and "1–3 (the row's comparison says how many)" in md


def test_a_side_cut_short_shows_its_steps_and_is_not_compared(tmp_path):
    """Records left by runs cut by a time limit (``cut``): each side's cell names where it stopped, and
    neither the return nor the wall is marked as at the goal, even where ours is ahead."""
    sampled = dict(eval_mode="stochastic")
    ours = _part(tmp_path, "ours", "ours", [1000.0], 10.0, returns_deterministic=[1000.0], cut=True, **sampled)
    brax = _part(tmp_path, "brax", "brax", [900.0], 50.0, **sampled)
    brax_tasks.main(["--merge", ours, brax, "--out", str(tmp_path / "a")])
    md = (tmp_path / "a" / "gpu-x-brax_tasks.md").read_text()
    cut = "1000.0 ± 0.0 (cut at 300 steps)"
    assert f"| 900.0 ± 0.0 (sampled) | {cut} | {cut} | not compared (a side cut short) | 50 | 10 |" in md
    brax_tasks.main(["--merge", ours, "--out", str(tmp_path / "alone")])  # brax's side not run: not "cut"
    md = (tmp_path / "alone" / "gpu-x-brax_tasks.md").read_text()
    assert "| nan ± nan | 1000.0 ± 0.0 (cut at 300 steps) |" in md
    ours = _part(tmp_path, "ours2", "ours", [1000.0], 10.0, returns_deterministic=[1000.0], **sampled)
    brax = _part(tmp_path, "brax2", "brax", [900.0], 50.0, cut=True, **sampled)
    brax_tasks.main(["--merge", ours, brax, "--out", str(tmp_path / "b")])
    md = (tmp_path / "b" / "gpu-x-brax_tasks.md").read_text()
    assert ("| 900.0 ± 0.0 (sampled) (cut at 300 steps) | 1000.0 ± 0.0 | 1000.0 ± 0.0 | not compared (a side cut "
            "short) | 50 | 10 |") in md


def test_brax_s_side_reports_its_first_seed_as_it_goes_then_each_seed(monkeypatch):
    """A stand-in for brax's trainer with 3 evaluations: the first seed's record after each of them (cut
    until its end), then the finished seeds'; the second seed's evaluations add nothing."""
    from benchmarks.peers import brax_ppo

    def fake(env, row, steps, seed, peer, deterministic_eval, num_evals, on_eval):
        evals = [(i * steps // (num_evals - 1), 10.0 * seed + i) for i in range(num_evals)]
        for k in range(1, num_evals + 1):
            run = {"final_return": evals[k - 1][1], "curve_steps": [s for s, _ in evals[:k]],
                   "curve": [r for _, r in evals[:k]], "wall_s": 1.0, "env_steps": evals[k - 1][0]}  # fmt: skip
            on_eval(run)
        return run

    monkeypatch.setattr(brax_ppo, "train_published", fake)
    written = []
    last = brax_tasks.theirs(None, {}, 100, seeds=2, peer="sac", done=written.append, first_seed=4, evals=3)
    assert [(w["env_steps"], w.get("cut", False), w["seed_ids"]) for w in written] == [
        (0, True, [4]), (50, True, [4]), (100, True, [4]), (100, False, [4]), (100, False, [4, 5])]
    assert last == written[-1] and last["returns"] == [42.0, 52.0] and last["curves"][1] == [50.0, 51.0, 52.0]


def test_our_side_killed_after_an_evaluation_is_merged_as_cut(monkeypatch, tmp_path):
    """The file our side leaves when a time limit kills it after its first evaluation names our side, so a
    merge of it beside brax's shows the evaluations so far (cut), not a side that never ran."""

    def killed(env, task, row, steps, seeds, *args):
        done = args[6]
        assert args[3] == "deterministic"  # TD3 acts deterministically: both sides in that mode unless given
        done({"returns": [5.0], "eval_mode": "deterministic", "returns_deterministic": [5.0], "wall_s": 2.0,
              "wall_per_seed_s": 2.0, "env_steps": 64, "env_steps_per_s": 32.0, "curve_steps": [0, 64],
              "curves": [[1.0, 5.0]], "overrides": {}, "cut": True})  # fmt: skip
        raise KeyboardInterrupt  # the time limit

    monkeypatch.setattr(brax_tasks, "ours", killed)
    assert brax_tasks.default_eval_mode("ppo") == "stochastic"  # brax's default for its PPO
    assert brax_tasks.default_eval_mode("td3") == brax_tasks.default_eval_mode("ddpg") == "deterministic"
    out = tmp_path / "ours"
    try:
        brax_tasks.main(["--algo", "td3", "--tasks", "walker2d", "--no-brax", "--steps", "128", "--seeds", "1",
                         "--out", str(out), "--label", "x", "--allow-dirty"])  # fmt: skip
    except KeyboardInterrupt:
        pass
    part = str(out / f"{brax_tasks.device_label()}-brax_tasks-td3-x.json")
    with open(part) as f:
        assert json.load(f)["tasks"][0]["sides"] == ["ours"]
    result = brax_tasks.main(["--merge", part, "--out", str(tmp_path / "merged")])
    assert result["tasks"][0]["ours"]["curves"] == [[1.0, 5.0]]
    with open(tmp_path / "merged" / f"{brax_tasks.device_label()}-brax_tasks-td3.md") as f:
        assert "5.0 ± 0.0 (cut at 64 steps)" in f.read()


def test_too_few_evaluations_is_a_one_line_error(capsys):
    try:
        brax_tasks.main(["--tasks", "inverted_pendulum", "--evals", "1"])
    except SystemExit as e:
        assert e.code == 2
    else:
        raise AssertionError("--evals 1 must stop the benchmark")
    assert "argument --evals: 1 is out of range; allowed >= 2" in capsys.readouterr().err.strip().splitlines()[-1]


def test_devices_beyond_the_machine_s_and_vmapped_seeds_on_the_cpu_are_one_line_errors(capsys):
    import jax

    n = jax.device_count()
    cases = [(["--devices", str(n + 1)], f"--devices {n + 1}: this machine has {n}"),
             (["--devices", "-1"], "argument --devices: -1 is out of range; allowed >= 0")]  # fmt: skip
    if jax.default_backend() == "cpu":  # vmapped seeds of MJX envs stop XLA:CPU's compiler
        cases.append((["--seed-map", "vmap", "--no-brax"], "--seed-map vmap: on the CPU, XLA stops"))
    for argv, message in cases:
        try:
            brax_tasks.main(["--tasks", "inverted_pendulum", *argv])
        except SystemExit as e:
            assert e.code == 2
        else:
            raise AssertionError(f"{argv} must stop the benchmark")
        assert message in capsys.readouterr().err.strip().splitlines()[-1]


def test_action_wrappers_hand_the_env_the_clipped_or_squashed_action_and_brax_s_preset_squashes():
    import jax.numpy as jnp

    from envs_mjx.base import ClipActionWrapper, State, TanhActionWrapper
    from train.presets import brax_ppo_config

    class Echo:  # an env whose observation is the action it was given
        def reset(self, rng):
            return State(None, jnp.zeros(3), jnp.zeros(()), jnp.zeros(()), {}, {})

        def step(self, state, action):
            return state.replace(obs=action)

    env = ClipActionWrapper(Echo())
    out = env.step(env.reset(None), jnp.array([-3.0, 0.25, 7.0]))
    assert out.obs.tolist() == [-1.0, 0.25, 1.0]
    preset = brax_ppo_config("halfcheetah", 6)
    assert preset.tanh_actions and not preset.clip_actions
    squash = TanhActionWrapper(Echo())
    out = squash.step(squash.reset(None), jnp.array([-3.0, 0.25, 0.0]))
    np.testing.assert_allclose(out.obs, [-0.99505475, 0.24491866, 0.0], rtol=1e-6)  # tanh by hand


@pytest.fixture
def every_program_cached():
    """Runs of the same trainer load its programs from the persistent compilation cache."""
    with cache_every_program():
        yield


def test_ours_evaluates_along_training_without_changing_it(every_program_cached):
    """Training in segments with evaluations between them ends where one uninterrupted run ends: the
    final mean-action return equals that of the same trainer run in one go (same keys)."""
    import jax

    from jaxrl_robot.evaluation import run_test_episodes
    from tests.agents.test_ppo import Line

    env, row = Line(), brax_tasks.brax_row("inverted_pendulum", 8)
    given = {"activation": "swish"}
    written = []  # what a run cut short leaves: the first seed's record after each evaluation, then the seed's
    out = brax_tasks.ours(env, "inverted_pendulum", row, 1920, seeds=1, eval_episodes=4, overrides=given,
                          done=written.append)  # fmt: skip
    assert [w["env_steps"] for w in written] == [0, 640, 1280, 1920] and written[-1] == {**out, "wall_s":
           written[-1]["wall_s"], "wall_per_seed_s": written[-1]["wall_per_seed_s"],
           "env_steps_per_s": written[-1]["env_steps_per_s"]}  # fmt: skip
    assert [w.get("cut", False) for w in written] == [True, True, True, False]
    walls = out["curve_wall_s"]  # one seed alone: one program's seconds at each of its 4 evaluations
    assert len(walls) == 1 and len(walls[0]) == 4 and walls[0] == sorted(walls[0]) and out["seeds_per_program"] == 1
    assert written[1]["curve_steps"] == [0, 640] and written[1]["curves"] == [out["curves"][0][:2]]
    assert np.shape(written[1]["training_curves"]) == (1, 1) and written[1]["returns"] == [out["curves"][0][1]]
    trainer, length = brax_tasks.our_trainer("ppo", "inverted_pendulum", env, row, 1920, given)
    assert trainer.num_updates == 3 and out["curve_steps"] == [0, 640, 1280, 1920]
    assert out["curve_kind"] == "evaluation" and out["eval_mode"] == "stochastic"
    assert np.shape(out["curves"]) == (1, 4) and out["returns"] == [out["curves"][0][-1]]
    assert np.isfinite(out["curves_deterministic"]).all() and np.shape(out["training_curves"]) == (1, 3)
    # brax's starting σ at the first update (σ(s) starts at 0.7 up to its output layer's small initial weights)
    np.testing.assert_allclose(out["training_policy_std"][0][0], 0.7, rtol=1e-3)
    assert out["overrides"] == given
    # each decision held for 2 env steps: 640 decisions (one iteration) are brax's 1280 env steps
    held = brax_tasks.ours(env, "inverted_pendulum", {**row, "action_repeat": 2}, 1280, seeds=1, eval_episodes=4)
    assert held["curve_steps"] == [0, 1280] and held["env_steps"] == 1280 and np.isfinite(held["returns"]).all()
    # two evaluations (--evals 2): before training and at its end
    two = brax_tasks.ours(env, "inverted_pendulum", row, 1920, seeds=1, eval_episodes=4, overrides=given, evals=2)
    assert two["curve_steps"] == [0, 1920]
    np.testing.assert_allclose(two["returns_deterministic"], out["returns_deterministic"], rtol=1e-5)

    from jaxrl_robot.evaluation import EVAL_KEY_OFFSET

    # one uninterrupted run: init, then the updates one after another (one compiled update; a scan of the 3
    # compiles to a program several times its size). Seed 0: train.ppo --seed 0's keys (benchmarks.seeds)
    state, update = jax.jit(trainer.init)(jax.random.PRNGKey(0)), jax.jit(trainer.update)
    for _ in range(trainer.num_updates):
        state, _ = update(state)
    key = jax.random.fold_in(jax.random.PRNGKey(0), EVAL_KEY_OFFSET)
    # the mean action's episodes are the second half of one batch of 8 (the sampled ones the first)
    returns = jax.jit(lambda k, s: run_test_episodes(k, env, trainer.policy(s), 8, length)["return"])(key, state)
    expect = float(np.mean(returns[4:]))
    np.testing.assert_allclose(out["returns_deterministic"][0], expect, rtol=1e-5)


def test_our_config_takes_overrides_and_a_bad_one_is_a_one_line_error(capsys):
    config = brax_tasks.our_config("ppo", "halfcheetah", 6, BRAX_PPO["halfcheetah"], 1000, {"tanh_actions": True,
                                   "clip_actions": False, "activation": "swish"})  # fmt: skip
    assert config.tanh_actions and not config.clip_actions and config.activation == "swish"
    # brax's own update: 512 unrolls of 20 steps per mini-batch, 8 passes x 32 mini-batches, the critic beside
    brax = brax_tasks.our_config("ppo", "halfcheetah", 6, BRAX_PPO["halfcheetah"], 1000, {"segments": True})
    got = (brax.advantage_segment, brax.minibatch_size, brax.actor_updates, brax.critic_updates)
    assert got == (20, 10240, 256, 256)
    assert not brax.critic_first and brax.unroll_length == 160  # 16 384 unrolls over 2 048 lanes: 8 each
    hopper = brax_tasks.our_config("ppo", "hopper", 3, BRAX_PPO["hopper"], 1000, {"segments": True})
    assert (hopper.advantage_segment, hopper.minibatch_size, hopper.num_envs) == (5, 10240, 4096)  # 2 048 unrolls
    reacher = {t: brax_tasks.our_config("ppo", "reacher", 2, BRAX_PPO["reacher"], 1000, o)
               for t, o in (("tuned", {}), ("row", {"tuned": False}))}  # fmt: skip
    assert (reacher["tuned"].actor_lr, reacher["tuned"].max_grad_norm) == (1e-3, 1.0)
    row = reacher["row"]
    assert (row.actor_lr, row.max_grad_norm, row.lr_schedule) == (3e-4, 0.0, "constant")
    walker = {t: brax_tasks.our_config("td3", "walker2d", 6, BRAX_SAC["walker2d"], 1000, o)
              for t, o in (("tuned", {}), ("td3", {"tuned": False}))}  # fmt: skip
    assert (walker["tuned"].updates_per_iteration, walker["td3"].updates_per_iteration) == (256, 128)  # 128 lanes
    for bad, message in (("nope=1", "unknown setting 'nope'"), ("clip_actions=true", "exclude each other")):
        try:
            brax_tasks.main(["--tasks", "halfcheetah", "--ours", bad])
        except SystemExit as e:
            assert e.code == 2
        else:
            raise AssertionError("a bad --ours must stop the benchmark")
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert "error: --ours:" in err
        assert message in err
