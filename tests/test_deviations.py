"""``benchmarks.deviations`` and the reports' columns beside each number: the thesis's setting of a row, a run's
differences from it, and the thesis report's faithful column, test steps and error per step."""

from __future__ import annotations

import dataclasses
import json

import pytest

from benchmarks import deviations, thesis


def test_differences_and_words_by_hand():
    thesis_cfg = {"gamma": 0.9, "batch_size": 32, "noise_scale": [0.2], "per_tree": "auto", "absent": 1}
    ours = {"gamma": 0.99, "batch_size": 32, "noise_scale": (0.1,), "per_tree": "block"}
    diffs = deviations.differences(ours, thesis_cfg)  # per_tree ignored, absent not in ours
    assert diffs == [("gamma", 0.9, 0.99), ("noise_scale", [0.2], (0.1,))]
    env = deviations.differences({"a_p": 300.0, "trajectory": "ellipse"}, {"a_p": 1.0, "trajectory": "sine"},
                                 deviations.IGNORED | deviations.ROW_FIELDS)  # fmt: skip
    assert deviations.words(env, diffs) == "env a_p 1 → 300; gamma 0.9 → 0.99, noise_scale (0.2) → (0.1)"
    assert deviations.words([], [("total_steps", 314000, 6280000)]) == "total_steps 314 000 → 6 280 000"
    assert deviations.words([], []) == "none"


@pytest.fixture(scope="module")
def sine_ddpg():
    """The thesis's setting of Table 4.4's DDPG row."""
    row = next(r for r in thesis.ROWS if r.id == "4.4/sine-ddpg")
    return row, *deviations.thesis_setting(row.algo, row.argv, row.kind)


def test_the_thesis_setting_is_table_3_3_and_eq_3_23_on_the_kinematic_plant(sine_ddpg):
    _, algo, env = sine_ddpg
    assert (algo["gamma"], algo["batch_size"], algo["buffer_size"], algo["tau"]) == (0.9, 32, 50_000, 0.01)
    assert (algo["twin_critics"], algo["policy_delay"], algo["actor_output"]) == (False, 1, "sigmoid")
    assert (env["mode"], env["a_p"], env["a_v"], env["observation"], env["trajectory"]) == (
        "kinematic", 1.0, 2.0, "thesis", "sine")


def test_a_run_s_config_json_lists_exactly_what_it_changed(sine_ddpg):
    """A config.json whose only changes from the thesis's setting are γ and a_p (and the env recorded)."""
    row, algo, env = sine_ddpg
    config = {"algo": "ddpg", "args": {}, "ddpg": {**algo, "gamma": 0.99},
              "env": {"name": "unicycle", "config": {**env, "a_p": 300.0}}}  # fmt: skip
    got = deviations.row_deviations(row.algo, row.argv, row.kind, json.loads(json.dumps(config)), "fast")
    assert got["text"] == "env a_p 1 → 300; gamma 0.9 → 0.99" and got["source"] == "the run's config.json"


def test_the_faithful_variant_runs_the_thesis_s_plant():
    rows = {r.id: r for r in thesis.select(None, None, "faithful")}
    assert "mode=kinematic" in rows["4.4/sine-ddpg"].argv and "mode=kinematic" in rows["5.4-5.7/ellipse-lstm"].argv
    assert rows["4.3/scara-ddpg"].argv == next(r for r in thesis.ROWS if r.id == "4.3/scara-ddpg").argv
    assert rows["3.1/sparse-final"].argv.count("mode=kinematic") == 1  # the arm rows ran kinematic already


def test_tracking_table_has_the_faithful_column_steps_per_step_errors_and_deviations(tmp_path):
    row = next(r for r in thesis.ROWS if r.id == "4.4/sine-ddpg")
    seeds = [{"x": 0.6, "y": 0.3, "theta": 0.9, "steps": 300, "wall_s": 1.0, "run_dir": str(tmp_path / "s0")},
             {"x": 0.9, "y": 0.6, "theta": 0.3, "steps": 300, "wall_s": 1.0, "run_dir": str(tmp_path / "s1")}]
    fig = thesis.row_figure(row, seeds)
    assert fig["steps"] == [300.0, 300.0] and fig["per_step"] == pytest.approx([0.0025, 0.0015, 0.002])
    result = {"row": dataclasses.asdict(row), "command": list(row.argv), "seeds": seeds, "figure": fig,
              "deviations": {"text": "env a_p 1 → 300", "source": "the run's config.json"}}  # fmt: skip
    faithful = {"sine-ddpg": {"figure": {**fig, "mean": [6.0, 3.0, 1.5], "seeds_done": 3},
                              "deviations": {"text": "actor_output sigmoid → tanh"}}}  # fmt: skip
    lines = thesis.table_markdown("4.4", [result], str(tmp_path), "figs", faithful)
    (line,) = [x for x in lines if x.startswith("| DDPG + PER, sine")]
    cells = line.split(" | ")
    assert cells[2:4] == ["6.00 / 3.00 / 1.50 (3 seeds)", "**0.75 ± 0.15**"]
    assert cells[6:8] == ["0.0025 / 0.0015 / 0.0020", "300"]
    assert "- DDPG + PER, sine: env a_p 1 → 300" in lines and "- DDPG + PER, sine: actor_output sigmoid → tanh" in lines
    header = next(x for x in lines if x.startswith("| row"))
    assert line.count(" | ") == header.count(" | ")


def test_the_faithful_column_reads_rows_from_several_faithful_reports(tmp_path):
    """Each faithful report holds some rows; the column takes every row of every one, the header names them all,
    and a report written when one path could be named (a string) still reads."""
    paths = []
    for name, rows in (("a", ["sine-ppo", "a3c-path"]), ("b", ["sine-ddpg"])):
        paths.append(str(tmp_path / f"thesis-cpu-thesis-faithful-{name}.json"))
        with open(paths[-1], "w") as f:
            json.dump({"rows": [{"row": {"name": r}, "figure": {"mean": [float(len(r))]}} for r in rows]}, f)
    rows = thesis.load_faithful(paths)
    assert sorted(rows) == ["a3c-path", "sine-ddpg", "sine-ppo"] and rows["sine-ddpg"]["figure"]["mean"] == [9.0]
    assert sorted(thesis.load_faithful(paths[1])) == ["sine-ddpg"]
    assert thesis.load_faithful([str(tmp_path / "absent.json")]) == {}
    meta = {"device": "cpu", "preset": "cpu", "command": "c", "commit": "0", "jax": "0", "date": "d", "seeds": 1,
            "runs_wall_s": 1.0, "wall_s": 1.0, "smoke": False, "faithful": paths}  # fmt: skip
    text = " ".join(thesis.header(meta))
    assert "(`thesis-cpu-thesis-faithful-a.json`, `thesis-cpu-thesis-faithful-b.json`)" in text


def test_config_json_records_the_env_s_whole_config():
    import envs_mjx
    from train.envs import env_record

    got = env_record("unicycle", envs_mjx.make("unicycle", mode="kinematic", a_p=300.0))
    assert got["name"] == "unicycle" and (got["config"]["a_p"], got["config"]["mode"]) == (300.0, "kinematic")
    assert got["config"]["a_v"] == 2.0 and set(got["config"]) >= {"omega_p", "observation", "trajectory"}
    assert env_record("brax:hopper", object()) == {"name": "brax:hopper", "config": None}
